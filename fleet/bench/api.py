"""``drona bench api``: sustained durable mail submissions against a running service.

It starts ``drona serve`` in its own process (simulated fleet of ``--sim-drones`` drones
flying the mail meanwhile, a fresh SQLite file with ``synchronous=FULL``), then,
from this process, submits mail **open-loop** at ``--rate`` per second for
``--seconds`` over ``--connections`` keep-alive HTTP/1.1 connections. A request's
latency runs from the moment it was due, not from when a connection was free, so
a service that falls behind is not flattered (no coordinated omission). At the
end it counts the mail in the database: every 201 must be there.

Target (the service issue): at least 1,000 submissions/s with p99 <= 50 ms.
``--url URL --token T`` measures a service that is already running instead.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import random
import sqlite3
import statistics
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from urllib.parse import urlsplit

from api.validation import MailChecker
from drona_gcs.workload import random_workspace
from drona_gcs.workspace import Workspace
from fleet import runtime
from fleet.bench import BenchError
from fleet.bench import plot as bench_plot

Pair = tuple[tuple[int, int, int], tuple[int, int, int]]  #: a pickup and a drop-off
TARGET_RATE = 1000.0
TARGET_P99_MS = 50.0


@dataclass(frozen=True)
class Result:
    rate: float  #: asked, per second
    seconds: float
    connections: int
    drones: int  #: simulated drones of the service started here (0: a running service given by --url)
    sent: int
    created: int  #: 201 answers
    errors: int  #: other answers and failed connections
    achieved: float  #: 201s per second of the measured window
    p50_ms: float
    p90_ms: float
    p99_ms: float
    max_ms: float
    stored: int | None  #: mails found in the database afterwards (None: not our database)
    meets_target: bool


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, help="seconds measured (default 10; 3 with --quick)")
    parser.add_argument("--warmup", type=float, default=2.0, help="seconds at the rate before measuring (default 2)")
    parser.add_argument("--rate", type=float, default=TARGET_RATE, help="submissions per second (default 1000)")
    parser.add_argument("--connections", type=int, default=64, help="keep-alive connections (default 64)")
    parser.add_argument("--sim-drones", type=int, default=8, help="simulated drones flying the mail (default 8)")
    parser.add_argument("--url", help="measure this running service instead of starting one")
    parser.add_argument("--token", help="with --url: an operator or submitter token")


def run(args: argparse.Namespace) -> int:
    seconds = args.seconds or (3.0 if args.quick else 10.0)
    if args.rate <= 0 or seconds <= 0 or args.connections < 1:
        print("drona bench api: --rate, --seconds and --connections must be > 0", file=sys.stderr)
        return 2
    if args.url and not args.token:
        print("drona bench api: --url needs --token", file=sys.stderr)
        return 2
    try:
        return runtime.run(_main(args, seconds))
    except BenchError as exc:
        print(f"drona bench api: {exc}", file=sys.stderr)
        return 1


async def _main(args: argparse.Namespace, seconds: float) -> int:
    rng = random.Random(args.seed)
    if args.url:
        pairs: list[Pair] = [((1, 1, 0), (2, 2, 0))]  # if the workspace cannot be read
        with contextlib.suppress(OSError, KeyError, ValueError):
            pairs = await _pairs_of_remote(args.url, args.token, rng)
        result = await _load(args.url, args.token, pairs, args, seconds, rng, db=None)
    else:
        with tempfile.TemporaryDirectory(prefix="drona-bench-api-") as tmp:
            result = await _with_service(Path(tmp), args, seconds, rng)
    _print(result, args.json)
    bench_plot.write(args, "api", result)
    return 0


async def _with_service(tmp: Path, args: argparse.Namespace, seconds: float, rng: random.Random) -> Result:
    ws = random_workspace(16, 16, rng)
    stations = sorted(ws.main_region)[:: max(1, len(ws.main_region) // 4)][:4]
    ws_file = tmp / "ws.json"
    ws_file.write_text(json.dumps({"size": list(ws.size), "obstacles": [list(c) for c in sorted(ws.obstacles)],
                                   "charging_stations": [list(c) for c in stations]}))
    token = "bench-token-" + "x" * 16
    db = tmp / "bench.db"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "fleet.cli", "serve", "--workspace", str(ws_file), "--db", str(db), "--port", "0",
        "--demo", "--token", token, "--gateway", "simulated", "--sim-drones", str(args.sim_drones),
        "--sim-step", "0.1", "--log-level", "warning", stdout=asyncio.subprocess.PIPE)
    try:
        url = await _wait_listening(proc)
        built = Workspace.build(size=ws.size, obstacles=ws.obstacles, charging_stations=tuple(stations))
        return await _load(url, token, _pairs(built, rng), args, seconds, rng, db)
    finally:
        if proc.returncode is None:
            proc.terminate()
        await proc.wait()


async def _wait_listening(proc: asyncio.subprocess.Process) -> str:
    assert proc.stdout is not None
    async with asyncio.timeout(60):
        while line := (await proc.stdout.readline()).decode():
            if "listening on" in line:
                return line.rsplit(" ", 1)[-1].strip()
    raise BenchError(f"drona serve exited ({proc.returncode}) before listening")


def _pairs(ws: Workspace, rng: random.Random, count: int = 400) -> list[Pair]:
    """Pickup/drop-off pairs the service accepts (checked with its own checker)."""
    checker, cells = MailChecker(ws), sorted(ws.main_region)
    pairs: list[Pair] = []
    for _ in range(count * 20):
        if len(pairs) >= count:
            break
        a, b = rng.choice(cells), rng.choice(cells)
        if not checker.check(a, b):
            pairs.append((a, b))
    return pairs


async def _pairs_of_remote(url: str, token: str, rng: random.Random) -> list[Pair]:
    host, port = _address(url)
    reader, writer = await asyncio.open_connection(host, port)
    try:
        writer.write(f"GET /v1/workspace HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {token}\r\n\r\n".encode())
        status, body = await _response(reader)
    finally:
        writer.close()
    if status != 200:
        raise ValueError(f"GET /v1/workspace answered {status}")
    data = json.loads(body)
    ws = Workspace.build(size=tuple(data["size"]), obstacles=frozenset(tuple(c) for c in data["obstacles"]),
                         charging_stations=tuple(tuple(c) for c in data["charging_stations"]),
                         parking=tuple(tuple(c) for c in data.get("parking", ())))
    return _pairs(ws, rng)


async def _load(url: str, token: str, pairs: list[Pair],
                args: argparse.Namespace, seconds: float, rng: random.Random, db: Path | None) -> Result:
    host, port = _address(url)
    bodies = [json.dumps({"pickup": list(p), "dropoff": list(d), "priority": rng.randrange(10)}).encode()
              for p, d in pairs]
    head = (f"POST /v1/mail HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {token}\r\n"
            "Content-Type: application/json\r\nContent-Length: ").encode()
    due: asyncio.Queue[float | None] = asyncio.Queue()
    total = int((args.warmup + seconds) * args.rate)
    start = time.perf_counter() + 0.2
    measure_from = start + args.warmup
    latencies: list[float] = []
    counts = {"sent": 0, "created": 0, "errors": 0, "created_measured": 0}

    async def worker() -> None:
        reader, writer = await asyncio.open_connection(host, port)
        try:
            while (at := await due.get()) is not None:
                body = bodies[counts["sent"] % len(bodies)]
                counts["sent"] += 1
                writer.write(head + str(len(body)).encode() + b"\r\n\r\n" + body)
                try:
                    status, _ = await _response(reader)
                except (OSError, asyncio.IncompleteReadError):
                    status = 0
                    writer.close()
                    reader, writer = await asyncio.open_connection(host, port)
                done = time.perf_counter()
                counts["created" if status == 201 else "errors"] += 1
                if at >= measure_from:
                    latencies.append((done - at) * 1000)
                    counts["created_measured"] += status == 201
        finally:
            writer.close()

    async with asyncio.TaskGroup() as tasks:
        for _ in range(args.connections):
            tasks.create_task(worker())
        await _pace(due, start, args.rate, total)
        for _ in range(args.connections):
            due.put_nowait(None)
    stored = _count(db) if db is not None else None
    return _result(args, seconds, latencies, counts, stored)


async def _pace(due: asyncio.Queue[float | None], start: float, rate: float, total: int) -> None:
    """Put each request's due time on the queue when it is due (open loop)."""
    for i in range(total):
        at = start + i / rate
        delay = at - time.perf_counter()
        if delay > 0.001:
            await asyncio.sleep(delay)
        due.put_nowait(at)


async def _response(reader: asyncio.StreamReader) -> tuple[int, bytes]:
    head = await reader.readuntil(b"\r\n\r\n")
    status = int(head[9:12])
    length = 0
    for line in head.split(b"\r\n"):
        if line[:15].lower() == b"content-length:":
            length = int(line[15:])
    return status, await reader.readexactly(length)


def _address(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    return parts.hostname or "127.0.0.1", parts.port or 80


def _count(db: Path) -> int:
    with contextlib.closing(sqlite3.connect(db)) as conn:
        return int(conn.execute("SELECT count(*) FROM mail").fetchone()[0])


def _result(args: argparse.Namespace, seconds: float, latencies: list[float], counts: dict[str, int],
            stored: int | None) -> Result:
    lat = sorted(latencies) or [float("nan")]

    def pct(p: float) -> float:
        return round(lat[min(len(lat) - 1, int(p * len(lat)))], 2)

    achieved = counts["created_measured"] / seconds
    p99 = pct(0.99)
    return Result(args.rate, seconds, args.connections, 0 if args.url else args.sim_drones, counts["sent"],
                  counts["created"],
                  counts["errors"], round(achieved, 1), round(statistics.median(lat), 2), pct(0.90), p99,
                  round(lat[-1], 2), stored,
                  achieved >= min(args.rate, TARGET_RATE) * 0.99 and p99 <= TARGET_P99_MS and counts["errors"] == 0
                  and (stored is None or stored >= counts["created"]))


def _print(result: Result, as_json: bool) -> None:
    if as_json:
        print(json.dumps(asdict(result)), flush=True)
        return
    r = result
    fleet = f"{r.drones} simulated drones flying" if r.drones else "the service's own fleet flying"
    print(f"mail submissions, open loop at {r.rate:.0f}/s for {r.seconds:.0f} s over {r.connections} connections, "
          f"{fleet}")
    print(f"  201 answers   {r.created} of {r.sent} sent ({r.errors} errors); {r.achieved:.1f}/s measured")
    print(f"  latency ms    p50 {r.p50_ms:.2f}  p90 {r.p90_ms:.2f}  p99 {r.p99_ms:.2f}  max {r.max_ms:.2f}")
    if r.stored is not None:
        print(f"  durable       {r.stored} mails in the database after the run (201 answers: {r.created})")
    print(f"  target        >= {TARGET_RATE:.0f}/s with p99 <= {TARGET_P99_MS:.0f} ms: "
          f"{'yes' if r.meets_target else 'NO'}")
