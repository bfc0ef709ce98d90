"""``drona bench delivery``: a workspace's whole fleet delivers a batch of mail posted at once.

It runs ``drona demo`` on ``--workspace`` (the service, an agent for each of the workspace's
drones, their fake vehicles at ``--speedup``) and posts ``--mails`` mails at once through the
REST API. Pickups and drop-offs are drawn with ``--seed`` among the cells the service accepts,
never a drone's start, charger or parking cell. It follows them on ``/v1/events`` until each is
delivered, failed or cancelled, or ``--minutes`` have passed, then prints the mail delivered per
minute and the audit of the flight record (every drone's cell at every step, from telemetry).
Exit 0 only when every mail was delivered and the record audits clean: safe, no jumps,
conformance at least 95%.

Target (issue 25): the DRONA workspace 16_4 (four drones, no parking cell, no charger) delivers
all 44 mails. At ``--speedup`` s a vehicle flies s simulated seconds a second and drains its
battery as fast: keep 1 where the workspace has no charger.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import random
import secrets
import signal
import socket
import sys
import tempfile
import time
from collections import Counter
from collections.abc import AsyncGenerator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO

import httpx

from api.validation import MailChecker
from drona_gcs.audit import Audit, audit
from drona_gcs.errors import DronaError
from drona_gcs.workspace import Cell, Workspace
from drona_gcs.workspace_files import load_workspace
from fleet.bench import BenchError
from fleet.bench import plot as bench_plot
from fleet.sim.ports import free_port_block, free_udp_base

FINAL = ("delivered", "failed", "cancelled")
UP_TIMEOUT_S = 120.0  #: for the demo to say its drones fly
STOP_TIMEOUT_S = 120.0  #: for the demo to land its drones and leave, once asked
Mail = tuple[Cell, Cell, int]  #: pickup, drop-off, priority


@dataclass(frozen=True)
class DeliveryResult:
    workspace: str
    drones: int
    mails: int
    delivered: int
    failed: int
    unfinished: int  #: neither delivered nor failed nor cancelled when time ran out
    seconds: float  #: from the posts to the last mail's end (or to the time limit)
    per_minute: float  #: delivered per minute of ``seconds``
    record_steps: int  #: the flight record's lines
    violations: int
    jumps: int
    conformance: float
    delivered_s: tuple[float, ...] = ()  #: when each mail was delivered, seconds after the posts, in order
    record_broken: tuple[str, ...] = ()  #: what the record breaks (drona audit's default bounds)

    @property
    def passed(self) -> bool:
        return self.delivered == self.mails and not self.record_broken


def draw_mails(workspace: Workspace, count: int, seed: int) -> list[Mail]:
    """``count`` mails the service accepts, drawn with ``seed``: two distinct cells where no drone rests."""
    checker = MailChecker(workspace)
    resting = set(workspace.drones.values())
    cells = sorted(c for c in workspace.main_region if c not in resting and checker.check_cell("pickup", c) is None)
    rng = random.Random(seed)
    mails: list[Mail] = []
    for _ in range(100 * count):
        if len(mails) == count or len(cells) < 2:
            break
        pickup, dropoff = rng.sample(cells, 2)
        if not checker.check(pickup, dropoff):
            mails.append((pickup, dropoff, rng.randint(0, 9)))
    if len(mails) < count:
        raise BenchError(f"found {len(mails)} of {count} mails the service accepts in {workspace.name}")
    return mails


def summarize(workspace: Workspace, mails: int, statuses: dict[str, str], seconds: float, verdict: Audit,
              steps: int, delivered_s: tuple[float, ...] = ()) -> DeliveryResult:
    counts = Counter(statuses.values())
    delivered = counts["delivered"]
    return DeliveryResult(workspace=workspace.name, drones=len(workspace.drones), mails=mails, delivered=delivered,
                          failed=counts["failed"] + counts["cancelled"],
                          unfinished=mails - sum(counts[s] for s in FINAL), seconds=round(seconds, 1),
                          per_minute=round(60 * delivered / seconds, 2) if seconds > 0 else 0.0,
                          record_steps=steps, violations=len(verdict.violations), jumps=len(verdict.jumps),
                          conformance=round(verdict.conformance.fraction, 4),
                          delivered_s=tuple(round(t, 1) for t in sorted(delivered_s)),
                          record_broken=tuple(verdict.broken()))


@dataclass
class Followed:
    """The mails as they went: each one's last status, when each delivery came, and the seconds from the
    posts to the last mail's end (or to the time limit)."""

    statuses: dict[str, str] = field(default_factory=dict)
    delivered_s: list[float] = field(default_factory=list)
    seconds: float = 0.0


async def run_bench(ws_file: Path, mails: list[Mail], speedup: float, minutes: float, workdir: Path,
                    log: IO[str], record: Path) -> Followed:
    """The demo up, ``mails`` posted and followed, every drone's flight recorded in ``record``."""
    token = secrets.token_urlsafe(18)
    drones = len(load_workspace(ws_file).drones)
    port = free_port_block(1, socket.SOCK_STREAM)
    demo = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "fleet.cli", "demo", "--workspace", str(ws_file), "--port", str(port),
        "--db", str(workdir / "mail.db"), "--record", str(record), f"--token={token}", "--speedup", str(speedup),
        "--ready-after", "2", "--vehicle-port", str(free_udp_base(drones)),
        "--zenoh-port", str(free_port_block(drones, socket.SOCK_STREAM)),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT, start_new_session=True)
    assert demo.stdout is not None
    try:
        async with asyncio.TaskGroup() as group:
            await _until_flying(demo.stdout, log)
            group.create_task(_copy(demo.stdout, log))  # ends when the demo does
            url = f"http://127.0.0.1:{port}"
            followed = await _post_and_follow(url, token, mails, minutes)
            await _stop(demo)
    finally:
        with contextlib.suppress(ProcessLookupError):
            demo.kill()
        await demo.wait()
    return followed


async def _until_flying(stdout: asyncio.StreamReader, log: IO[str]) -> None:
    try:
        async with asyncio.timeout(UP_TIMEOUT_S):
            while line := (await stdout.readline()).decode(errors="replace"):
                log.write(line)
                if " drones flying; dashboard " in line:
                    return
    except TimeoutError:
        raise BenchError(f"`drona demo`'s drones did not fly within {UP_TIMEOUT_S:g} s") from None
    raise BenchError("`drona demo` ended before its drones flew")


async def _copy(stdout: asyncio.StreamReader, log: IO[str]) -> None:
    while line := await stdout.readline():
        log.write(line.decode(errors="replace"))


async def _stop(demo: asyncio.subprocess.Process) -> None:
    """Ask the demo to land its drones and leave (its Ctrl-C); killed if it does not in time."""
    demo.send_signal(signal.SIGINT)
    try:
        async with asyncio.timeout(STOP_TIMEOUT_S):
            await demo.wait()
    except TimeoutError:
        demo.kill()


async def _post_and_follow(url: str, token: str, mails: list[Mail], minutes: float) -> Followed:
    headers = {"Authorization": f"Bearer {token}"}
    followed = Followed()
    statuses = followed.statuses
    async with httpx.AsyncClient(base_url=url, headers=headers, timeout=30) as client:
        events = _mail_events(client, token)
        await anext(events)  # subscribed: no change is missed from here on
        started = time.monotonic()
        for i, (pickup, dropoff, priority) in enumerate(mails):
            res = await client.post("/v1/mail", json={"pickup": list(pickup), "dropoff": list(dropoff),
                                                      "priority": priority})
            if res.status_code != 201:
                raise BenchError(f"mail {i} ({list(pickup)} -> {list(dropoff)}) refused: {res.status_code} {res.text}")
            statuses[res.json()["id"]] = res.json()["status"]
        last = started
        try:
            async with asyncio.timeout(minutes * 60):
                async for mail_id, status in events:
                    if mail_id not in statuses or statuses[mail_id] == status:
                        continue
                    statuses[mail_id], last = status, time.monotonic()
                    if status == "delivered":
                        followed.delivered_s.append(last - started)
                    _progress(last - started, statuses)
                    if all(s in FINAL for s in statuses.values()):
                        break
        except TimeoutError:
            last = time.monotonic()
        await events.aclose()
    followed.seconds = last - started
    return followed


async def _mail_events(client: httpx.AsyncClient, token: str) -> AsyncGenerator[tuple[str, str]]:
    """The service's mail events as (id, status); first ("", "") once subscribed."""
    async with client.stream("GET", "/v1/events", params={"access_token": token},
                             timeout=httpx.Timeout(30.0, read=60.0)) as stream:
        kind, subscribed = "", False
        async for line in stream.aiter_lines():
            if not subscribed:
                subscribed = True
                yield "", ""
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: ") and kind == "mail":
                data = json.loads(line[6:])
                yield data["id"], data["status"]
    raise BenchError("the service closed its event stream")


def _progress(seconds: float, statuses: dict[str, str]) -> None:
    counts = Counter(statuses.values())
    print(f"{seconds:7.1f} s  " + ", ".join(f"{s} {counts[s]}" for s in sorted(counts)), file=sys.stderr, flush=True)


def audit_record(workspace: Workspace, record: Path) -> tuple[Audit, int]:
    lines = [json.loads(line) for line in record.read_text(encoding="utf-8").splitlines() if line] \
        if record.exists() else []
    return audit(workspace, lines), len(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--workspace", type=Path, required=True, help="the workspace to fly, every drone of it")
    parser.add_argument("--mails", type=int, help="mails posted at once (default 44; 4 with --quick)")
    parser.add_argument("--speedup", type=float, default=1.0,
                        help="the fake vehicles' simulated seconds per second, battery drain included (default 1)")
    parser.add_argument("--minutes", type=float, help="most minutes to wait for the mail (default 30; 5 with --quick)")
    parser.add_argument("--record", type=Path, help="keep the flight record here, written anew (JSON Lines, for "
                        "`drona audit` and `drona replay` with the same --workspace)")


def run(args: argparse.Namespace) -> int:
    mails_wanted = args.mails if args.mails is not None else (4 if args.quick else 44)
    minutes = args.minutes or (5.0 if args.quick else 30.0)
    if mails_wanted < 1 or minutes <= 0 or args.speedup <= 0:
        print("drona bench delivery: --mails must be >= 1, --minutes and --speedup > 0", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        try:
            ws_file: Path = args.workspace
            workspace = load_workspace(ws_file)
            mails = draw_mails(workspace, mails_wanted, args.seed)
            record = args.record.resolve() if args.record is not None else workdir / "flight.jsonl"
            record.write_text("", encoding="utf-8")  # the agents append to it
        except (DronaError, BenchError, OSError, ValueError) as exc:
            print(f"drona bench delivery: {exc}", file=sys.stderr)
            return 2
        if not args.json:
            print(f"drona bench delivery: {len(workspace.drones)} drones of {workspace.name}, {len(mails)} mails "
                  f"posted at once (seed {args.seed}), vehicles at speedup {args.speedup:g}; at most "
                  f"{minutes:g} min", flush=True)
        failures: list[Exception] = []
        with (workdir / "demo.log").open("w", encoding="utf-8") as log:
            try:
                followed = asyncio.run(run_bench(ws_file, mails, args.speedup, minutes, workdir, log, record))
            except* (BenchError, httpx.HTTPError, OSError) as group:
                failures = list(group.exceptions)
        if failures:
            tail = (workdir / "demo.log").read_text(encoding="utf-8").splitlines()[-20:]
            print("\n".join(tail), file=sys.stderr)
            print(f"drona bench delivery: {'; '.join(map(str, failures))}", file=sys.stderr)
            return 1
        try:
            verdict, steps = audit_record(workspace, record)
        except (DronaError, ValueError) as exc:
            print(f"drona bench delivery: the flight record {record.name}: {exc}", file=sys.stderr)
            return 1
    result = summarize(workspace, len(mails), followed.statuses, followed.seconds, verdict, steps,
                       tuple(followed.delivered_s))
    print(json.dumps(asdict(result)) if args.json else _table(result, verdict.delta))
    bench_plot.write(args, "delivery", result)
    return 0 if result.passed else 1


def _table(result: DeliveryResult, delta: int) -> str:
    left = f", {result.unfinished} unfinished" if result.unfinished else ""
    return (f"delivered {result.delivered} of {result.mails} ({result.failed} failed{left}) in {result.seconds:.1f} s: "
            f"{result.per_minute:.2f} a minute (target: all)\n"
            f"flight record: {result.record_steps} records, delta {delta}, "
            f"{'safe' if not result.violations else f'{result.violations} separation violations'}, "
            f"{result.jumps} jumps, conformance {result.conformance:.1%}\n"
            f"{'PASSED' if result.passed else 'FAILED'}" + "".join(f"; {why}" for why in result.record_broken))
