"""``drona bench coordination``: end-to-end coordination latency of N agents over Zenoh on loopback.

The agents run in ``--processes`` ``drona agent --count`` subprocesses (a Zenoh
session per process, ``--shared-session``; or one per drone, as on a real
fleet, with ``--session-per-drone``) against N fake vehicles in a ``drona sim-vehicle``
subprocess; an outside session keeps every drone busy with mail over Zenoh,
from the moment every drone is alive, stepping (every process flying) and
parked: first two mails to every drone at once, so that the whole fleet
coordinates at once (Protocol 1's worst case: each round waits for those
before it in line), then one more each time one is delivered. Only the plans
made for the mail count, not the drones' moves to their parking cells at
start-up, made while the last process may still be joining.
Latency is measured per plan, from the task's arrival (the task planner's
decision at a step boundary) to the plan scheduled (the protocol's
StartExecuting, after every peer answered): Protocol 1 over the network,
waiting on peers that coordinate at the same time, and the planner.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, cast

from drona_gcs.audit import audit
from drona_gcs.stack.drone import default_lead_steps
from drona_gcs.stack.protocol import State
from drona_gcs.workspace import Cell, Workspace
from drona_gcs.workspace_files import load_workspace
from fleet.bench import BenchError
from fleet.bench import plot as bench_plot
from fleet.sim.ports import free_port_block, free_udp_base
from fleet.transport.fleet_client import FleetClient
from fleet.transport.identity import SERVICE, make_certs
from fleet.transport.keys import FleetKeys
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings
from fleet.transport.wire import DroneState, MailOrder, MailStatus, MailStatusReport, WireError, decode

VEHICLE_SPEEDUP = 2.0  #: enough to track a cell per tau; telemetry rates scale with it, as in SITL
TELEMETRY_HZ = 10.0  #: the agent's default: a vehicle sent a cell ahead at most is sent on as soon as seen there
IDLE_BOUND_S = 90.0  #: how long the drones may take to park at start-up (some detour around the others)


@dataclass(frozen=True)
class CoordinationResult:
    agents: int
    seconds: float
    plans: int
    p50_ms: float
    p99_ms: float
    max_ms: float
    steady_plans: int  #: plans after the first burst (every drone given mail at once) has settled
    steady_p50_ms: float
    steady_p99_ms: float
    steady_max_ms: float
    messages_per_round: float
    cpu_ms_per_s_per_agent: float
    vehicles_cpu_s_per_s: float
    delivered: int


def bench_workspace(agents: int) -> str:
    """A square grid with room for every drone, a parking cell of its own on the rim, and two chargers.

    A parking cell per drone matters: with fewer, idle drones race for the nearest free one, and
    every race lost is a coordination round that ends in no plan (and holds up the rounds after it).
    """
    side = max(12, 2 * int(agents**0.5) + 8)
    while len(_rim(side)) < agents:
        side += 1
    starts = [(2 + 2 * (i % ((side - 4) // 2)), 2 + 2 * (i // ((side - 4) // 2))) for i in range(agents)]
    rim = _rim(side)
    return "\n".join([
        f"name: bench-{agents}", f"size: [{side}, {side}, 1]", "cell_size_m: 1.0", "tau_s: 0.5", "beta_s: 0.2",
        "geo_origin: {lat: 47.397742, lon: 8.545594, alt_m: 488.0, layer0_alt_m: 2.0}",
        f"charging_stations: [[0, 0, 0], [{side - 1}, {side - 1}, 0]]",
        "parking: [" + ", ".join(f"[{x}, {y}, 0]" for x, y in rim[:agents]) + "]",
        "drones:", *(f"  d{i + 1}: [{x}, {y}, 0]" for i, (x, y) in enumerate(starts)),
    ]) + "\n"


def _rim(side: int) -> list[tuple[int, int]]:
    """The grid's edge, less the corners (two are the chargers) and the cells beside them (drones
    parked there would wall a corner off): room for 4 (side - 4) drones, so the grid grows with the
    square root of the fleet, not with the fleet."""
    edge = range(2, side - 2)
    return ([(x, 0) for x in edge] + [(x, side - 1) for x in edge] + [(0, y) for y in edge]
            + [(side - 1, y) for y in edge])


async def run_bench(agents: int, processes: int, seconds: float, steady_after: float, workdir: Path,
                    seed: int = 1, shared_session: bool = True, secure: bool = True,
                    record: Path | None = None) -> CoordinationResult:
    """``secure``: mutual TLS and access control (certificates made in ``workdir``), a session per drone;
    ``record``: each agent process records its drones' flights there (``record.<first drone>``)."""
    ws_file = workdir / f"bench-{agents}.yaml"
    ws_file.write_text(bench_workspace(agents))
    workspace = load_workspace(ws_file)
    names = list(workspace.drones)[:agents]
    tls_dir = workdir / "tls" if secure else None
    share = -(-agents // processes)
    if tls_dir is not None:  # a host certificate for each process's session
        hosts = {f"host-{names[first]}": names[first:first + share] for first in range(0, agents, share)}
        make_certs(tls_dir, [*workspace.drones, SERVICE], hosts=hosts if shared_session else None)
    security = [*(["--tls-dir", str(tls_dir)] if tls_dir else ["--insecure"]),
                *(["--shared-session"] * shared_session)]
    base, port = free_udp_base(agents), free_port_block(agents, socket.SOCK_STREAM)
    fleet = f"bench-{port}"
    children = [_spawn(["sim-vehicle", "--workspace", str(ws_file), "--count", str(agents), "--base-port",
                        str(base), "--speedup", str(VEHICLE_SPEEDUP), "--ready-after", "0.5"])]
    for first in range(0, agents, share):
        count = min(share, agents - first)
        # Agent i listens on port + i and connects to agent 0's port; gossip meshes the rest.
        children.append(_spawn(["agent", "--workspace", str(ws_file), "--drone", names[first], "--count", str(count),
                                "--fleet", fleet, "--listen", f"tcp/127.0.0.1:{port + first}",
                                "--connect", f"tcp/127.0.0.1:{port}", "--vehicle-base-port", str(base),
                                "--lead-steps", str(default_lead_steps(workspace, VEHICLE_SPEEDUP)),
                                "--hover-lead-steps", str(max(4, workspace.delta + 1)),
                                "--telemetry-hz", str(TELEMETRY_HZ), "--log-level", "WARNING",
                                *security, *_recording(record, workdir, names[first])]))
    try:
        result = await _measure(children, workspace, names, fleet, port, seconds, steady_after, seed, tls_dir)
    finally:
        # The agents first (they land and leave), then the vehicles they land.
        for group in (children[1:], children[:1]):
            for child in group:
                child.send_signal(signal.SIGINT)
            for child in group:
                try:
                    child.wait(60)
                except subprocess.TimeoutExpired:
                    child.kill()
                    child.wait()
    if record is not None:
        gather_records(record, sorted(workdir.glob(f"{RECORD_PART}.*")))
    return result


async def _measure(children: list[subprocess.Popen[bytes]], workspace: Workspace, names: list[str], fleet: str,
                   port: int, seconds: float, steady_after: float, seed: int,
                   tls_dir: Path | None) -> CoordinationResult:
    keys = FleetKeys(fleet)
    settings = ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",)).secured(tls_dir, SERVICE, keys, names)
    node = await ZenohNode.open(settings, "bench")
    latencies = PlanLatencies()
    alive: set[str] = set()
    all_up = asyncio.Event()
    stepping: set[str] = set()
    all_stepping = asyncio.Event()

    def on_state(key: str, payload: bytes) -> None:
        with contextlib.suppress(WireError):
            body = decode(payload).body
            if not isinstance(body, DroneState):
                return
            if body.step > 0:  # its first boundary taken: steps count from the fleet epoch
                stepping.add(body.drone)
                if stepping >= set(names):
                    all_stepping.set()
            latencies.observe(body, time.monotonic())

    def on_alive(key: str, up: bool) -> None:
        (alive.add if up else alive.discard)(keys.last_chunk(key))
        if alive >= set(names):
            all_up.set()

    try:
        node.subscribe(keys.state(), on_state)
        node.watch_liveliness(keys.alive(), on_alive)
        await _up_or_gone(all_up, children, 120, "alive on Zenoh")
        # And flying: a drone is alive (and takes mail) as soon as it joined, but its process steps only once
        # all its drones have joined. Mail given before would measure the start-up of the last process
        # (its queries to the fleet) as much as coordination.
        await _up_or_gone(all_stepping, children, 60, "stepping")
        client = FleetClient(node, keys, "bench")
        # And parked (idle): given its mail at once, the whole fleet then coordinates at once, the worst
        # case of Protocol 1 (each round waits for those before it in line). Their moves to their parking
        # cells at start-up, made while the last process may still be joining, are not counted.
        before = await _between_rounds(client, IDLE_BOUND_S, idle=True)
        latencies.count_after(before)
        cpu0 = [_cpu_of(c.pid) for c in children]
        started = time.monotonic()
        delivered, sent, plans = await _keep_busy(node, client, keys, workspace, names, seconds, seed, before)
        elapsed = time.monotonic() - started
        _check_alive(children)  # figures from a fleet that lost a process mean nothing
        cpu = [_cpu_of(c.pid) - c0 for c, c0 in zip(children, cpu0, strict=True)]
    finally:
        await node.close()
    values, steady = latencies.since(), latencies.since(started + steady_after)
    return CoordinationResult(
        len(names), elapsed, len(values), _percentile(values, 0.5), _percentile(values, 0.99), _percentile(values, 1),
        len(steady), _percentile(steady, 0.5), _percentile(steady, 0.99), _percentile(steady, 1),
        sent / plans if plans else float("nan"), 1000 * sum(cpu[1:]) / elapsed / len(names), cpu[0] / elapsed,
        delivered)


class PlanLatencies:
    """The coordination latency of every plan made for the mail, read from the drones' states.

    A state names how many plans its drone has made and the latency of the last one. Only plans made
    after :meth:`count_after` are counted: not the moves to the parking cells at start-up, nor any plan
    of a drone missing from the states it was given. The states repeat a plan until the next: it is
    taken once, when first seen."""

    def __init__(self) -> None:
        self._counted_from: dict[str, int] = {}  #: each drone's plans before the first mail
        self._seen: dict[tuple[str, int], tuple[float, float]] = {}  #: (drone, plan) -> (when seen, ms)

    def count_after(self, before: dict[str, DroneState]) -> None:
        self._counted_from.update({drone: state.plans for drone, state in before.items()})

    def observe(self, state: DroneState, now: float) -> None:
        if state.coordination_ms is not None and state.plans > self._counted_from.get(state.drone, sys.maxsize):
            self._seen.setdefault((state.drone, state.plans), (now, state.coordination_ms))

    def since(self, when: float = -math.inf) -> list[float]:
        """The latencies (ms) of the plans first seen at ``when`` or later, sorted."""
        return sorted(ms for seen, ms in self._seen.values() if seen >= when)


#: Each agent process records its drones' flights in the bench's own directory, in a file named so.
RECORD_PART = "flight"


def _recording(record: Path | None, workdir: Path, first: str) -> list[str]:
    return [] if record is None else ["--record", str(workdir / f"{RECORD_PART}.{first}")]


def gather_records(record: Path, parts: list[Path]) -> None:
    """The agent processes' flight records, one after the other, into ``record`` (replaced)."""
    lines = [line for part in parts for line in part.read_text(encoding="utf-8").splitlines() if line]
    record.write_text("".join(f"{line}\n" for line in lines), encoding="utf-8")


def audit_records(record: Path, workspace_text: str) -> str:
    """Audit the flight record ``record``, with its workspace written beside it."""
    lines = [line for line in record.read_text(encoding="utf-8").splitlines() if line]
    ws_file = record.with_name(f"{record.name}.workspace.yaml")
    ws_file.write_text(workspace_text, encoding="utf-8")
    verdict = audit(load_workspace(ws_file), [json.loads(line) for line in lines])
    worst = verdict.conformance.worst
    return (f"flight record {record} ({len(lines)} records, workspace {ws_file.name}): delta {verdict.delta}, "
            f"{'safe' if verdict.safe else f'{len(verdict.violations)} separation violations'}, "
            f"{len(verdict.jumps)} jumps, conformance {verdict.conformance.fraction:.1%}"
            + (f" (worst {worst})" if worst is not None else ""))


def _spawn(arguments: list[str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "fleet.cli", *arguments], stdout=subprocess.DEVNULL)


async def _up_or_gone(all_up: asyncio.Event, children: list[subprocess.Popen[bytes]], timeout_s: float,
                      what: str) -> None:
    """Until ``all_up`` (every agent ``what``); :class:`BenchError` at once if a child process exits first
    (a bad setting, a port taken: its own error is on stderr above), or after ``timeout_s``."""
    loop = asyncio.get_running_loop()
    gone: asyncio.Future[None] = loop.create_future()
    fds = [os.pidfd_open(child.pid) for child in children]

    def one_gone() -> None:
        if not gone.done():
            gone.set_result(None)

    for fd in fds:
        loop.add_reader(fd, one_gone)
    up: asyncio.Future[Any] = asyncio.create_task(all_up.wait())
    try:
        await asyncio.wait([up, gone], timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED)
    finally:
        up.cancel()
        for fd in fds:
            loop.remove_reader(fd)
            os.close(fd)
    _check_alive(children)
    if not all_up.is_set():
        raise BenchError(f"the agents were not all {what} after {timeout_s:g} s")


def _check_alive(children: list[subprocess.Popen[bytes]]) -> None:
    for child in children:
        if (code := child.poll()) is not None:
            command = cast(list[str], child.args)[3]  # [python, -m, fleet.cli, command, ...] (see _spawn)
            raise BenchError(f"`drona {command}` (pid {child.pid}) exited with code {code}; its error is above")


async def _keep_busy(node: ZenohNode, client: FleetClient, keys: FleetKeys, workspace: Workspace, names: list[str],
                     seconds: float, seed: int, before: dict[str, DroneState]) -> tuple[int, int, int]:
    """Two mails per drone at first, and one more each time one is delivered, for ``seconds``. Returns
    the mails delivered, and the protocol messages sent and plans made since the states ``before`` (the
    fleet between rounds)."""
    rng = random.Random(seed)
    # Not where a drone starts either: one that has no mail yet rests there, and a mail there waits for it.
    free = sorted(workspace.main_region - set(workspace.parking) - set(workspace.charging_stations)
                  - set(workspace.drones.values()))
    deliveries: asyncio.Queue[str] = asyncio.Queue()
    count = delivered = 0

    def on_report(key: str, payload: bytes) -> None:
        with contextlib.suppress(WireError):
            body = decode(payload).body
            if isinstance(body, MailStatusReport) and body.status is MailStatus.DELIVERED:
                deliveries.put_nowait(body.drone)

    async def give(drone: str) -> None:
        nonlocal count
        pickup, dropoff = rng.sample(free, 2)
        count += 1
        await client.assign(drone, MailOrder(id=f"b{count}", pickup=_list(pickup), dropoff=_list(dropoff),
                                             priority=rng.randint(0, 9)))

    node.subscribe(keys.status(), on_report)
    # Every order at once: one after the other they can take longer than a step, and the drones would
    # take their mail at several boundaries, in bursts of a size left to chance.
    async with asyncio.TaskGroup() as group:
        for drone in names:
            for _ in range(2):
                group.create_task(give(drone))
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        try:
            drone = await asyncio.wait_for(deliveries.get(), left)
        except TimeoutError:
            break
        delivered += 1
        await give(drone)
    after = await _between_rounds(client)
    sent = sum(s.messages_sent - before[d].messages_sent for d, s in after.items() if d in before)
    plans = sum(s.plans - before[d].plans for d, s in after.items() if d in before)
    return delivered, sent, plans


async def _between_rounds(client: FleetClient, bound_s: float = 5.0, idle: bool = False) -> dict[str, DroneState]:
    """The drones' states once none is coordinating (``idle``: none has a plan either, every one waits for
    a task), or after ``bound_s`` (saying on stderr which drones were still at it: the figures then
    count part of a round, or mail given to a fleet not yet parked). Messages and plans are counted
    between two such snapshots: a round under way at the first would add its plan without its request,
    and the messages per round would come out too few. The states are asked again until then: nothing
    announces a fleet between rounds."""
    busy = {State.COORDINATING.value, State.EXECUTING.value} if idle else {State.COORDINATING.value}
    deadline = time.monotonic() + bound_s
    while True:
        states = await client.states()
        still = sorted(drone for drone, state in states.items() if state.mode in busy)
        if not still:
            return states
        if time.monotonic() > deadline:
            doing = "flying or coordinating" if idle else "coordinating"
            print(f"drona bench coordination: after {bound_s:g} s, drones still {doing}: {', '.join(still)}; "
                  "measuring anyway", file=sys.stderr)
            return states
        await asyncio.sleep(0.02)


def _list(cell: Cell) -> list[int]:
    return [cell[0], cell[1], cell[2]]


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    return values[min(len(values) - 1, int(q * len(values)))] if q < 1 else values[-1]


def _cpu_of(pid: int) -> float:
    """CPU seconds used so far by process ``pid`` (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def default_processes() -> int:
    """One agent process per CPU core this process may run on. A round waits for every process
    to answer; with more processes than cores, each round also waits for them to be scheduled."""
    return len(os.sched_getaffinity(0))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--agents", type=int,
                        help="agents, each with its own fake vehicle (default 32; 8 with --quick)")
    parser.add_argument("--seconds", type=float, help="how long to keep them busy (default 60; 15 with --quick)")
    parser.add_argument("--processes", type=int,
                        help="agent processes the agents are spread over (default: one per CPU core available)")
    parser.add_argument("--session-per-drone", action="store_true",
                        help="each agent with its own Zenoh session, as on a real fleet (default: the agents of a "
                             "process share one, `drona agent --shared-session`, under a host certificate)")
    parser.add_argument("--insecure", action="store_true",
                        help="plain TCP (default: mutual TLS and the fleet's access control, with certificates made "
                             "for the run)")
    parser.add_argument("--record", type=Path, help="record every drone's flight here (JSON Lines, with the "
                        "workspace beside it) and audit it after the run")
    parser.add_argument("--steady-after", type=float, default=10.0,
                        help="also report the plans after this many seconds, past the opening burst (default 10)")


def run(args: argparse.Namespace) -> int:
    agents = args.agents or (8 if args.quick else 32)
    seconds = args.seconds or (15.0 if args.quick else 60.0)
    if agents < 2 or seconds <= 0:
        print("drona bench coordination: --agents must be >= 2 and --seconds > 0", file=sys.stderr)
        return 2
    processes = max(1, min(args.processes or default_processes(), agents))
    shared = not args.session_per_drone
    if not args.json:
        links = "plain TCP" if args.insecure else "mutual TLS, access control"
        print(f"drona bench coordination: {agents} agents (a Zenoh session per "
              f"{'process' if shared else 'drone'}, {links}) in {processes} `drona agent --count` processes, "
              f"{agents} fake vehicles in a `drona sim-vehicle`, loopback; mail for {seconds:g} s", flush=True)
    with tempfile.TemporaryDirectory() as workdir:
        try:
            result = asyncio.run(run_bench(agents, processes, seconds, args.steady_after, Path(workdir),
                                           shared_session=shared, secure=not args.insecure,
                                           record=args.record.resolve() if args.record else None))
        except BenchError as exc:
            print(f"drona bench coordination: {exc}", file=sys.stderr)
            return 1
    if args.json:
        if args.record is not None:
            print(audit_records(args.record, bench_workspace(agents)), file=sys.stderr)
        # A figure with nothing to go on (no plan after the opening) is null: strict JSON parsers refuse NaN.
        row = {"processes": processes, **asdict(result)}
        print(json.dumps({k: None if isinstance(v, float) and math.isnan(v) else v for k, v in row.items()}))
        bench_plot.write(args, "coordination", result)
        return 0
    print(f"plans {result.plans} in {result.seconds:.1f} s ({result.delivered} mails delivered)\n"
          f"coordination latency, task arrival to plan scheduled: p50 {result.p50_ms:.2f} ms, "
          f"p99 {result.p99_ms:.2f} ms, max {result.max_ms:.2f} ms (target p50 <= 20, p99 <= 100)\n"
          f"  after the first {args.steady_after:g} s (the opening burst: every drone given mail at once): "
          f"{result.steady_plans} plans, p50 {result.steady_p50_ms:.2f} ms, p99 {result.steady_p99_ms:.2f} ms, "
          f"max {result.steady_max_ms:.2f} ms\n"
          f"protocol messages per round {result.messages_per_round:.1f} (5(N-1) = {5 * (agents - 1)} for a drone "
          f"coordinating alone: asked, answered, planned, held, flown; 4(N-1) = {4 * (agents - 1)} for a fleet "
          f"coordinating at once, whose requests and decisions are the answers)\n"
          f"CPU per agent {result.cpu_ms_per_s_per_agent:.1f} ms/s (the agent processes / agents; the vehicles' "
          f"process {result.vehicles_cpu_s_per_s:.2f} s/s)")
    bench_plot.write(args, "coordination", result)
    if args.record is not None:
        print(audit_records(args.record, bench_workspace(agents)))
    return 0
