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
import json
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
from contextlib import ExitStack
from dataclasses import asdict
from pathlib import Path

from drona_gcs.audit import Conformance, audit
from drona_gcs.stack.drone import default_lead_steps
from drona_gcs.workspace_files import load_workspace
from fleet.bench import BenchError
from fleet.bench import plot as bench_plot
from fleet.bench.faults import VICTIM_HOST, Fault, FaultPlan, Victim
from fleet.bench.hosts import Hosts, network_hosts
from fleet.bench.latency import OPENING_S, CoordinationResult, Disturbance, measure
from fleet.bench.processes import spawn
from fleet.sim.ports import free_port_block, free_udp_base
from fleet.transport.identity import SERVICE, make_certs

#: The bench's vehicles, quick enough for a 1 m cell every 0.5 s without cutting corners at turns (an
#: ArduCopter at its defaults needs tau 1 s): sim-vehicle sets them from the workspace, as an operator would.
BENCH_VEHICLE = "vehicle: {speed_m_s: 20.0, accel_m_s2: 10.0, jerk_m_s3: 40.0}"
BENCH_BETA_S = 0.2
TELEMETRY_HZ = 10.0  #: the agent's default: a vehicle sent a cell ahead at most is sent on as soon as seen there
#: The agents yield the CPU to the fake vehicles: real vehicles fly on their own computers, and a
#: simulation starved by the agents it serves flies them slower than physics would (late for nothing).
AGENT_NICE = 5


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
        f"name: bench-{agents}", f"size: [{side}, {side}, 1]", "cell_size_m: 1.0", "tau_s: 0.5",
        f"beta_s: {BENCH_BETA_S}",
        BENCH_VEHICLE,
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
                    record: Path | None = None, fault: FaultPlan | None = None) -> CoordinationResult:
    """``secure``: mutual TLS and access control (certificates made in ``workdir``), a session per drone;
    ``record``: each agent process records its drones' flights there (``record.<first drone>``);
    ``fault``: the last drone, in processes of its own, is struck mid-run (:mod:`fleet.bench.faults`)."""
    with ExitStack() as hosts_made:
        cut_off = fault is not None and fault.kind is Fault.PARTITION
        hosts = hosts_made.enter_context(network_hosts([VICTIM_HOST])) if cut_off else None
        fleet = _BenchFleet(agents, processes, workdir, shared_session, secure, record, fault, hosts)
        try:
            children, victim = fleet.spawn_all()
            disturbance = None if victim is None else Disturbance(
                victim.strike, frozenset(fleet.struck), (victim.agent, victim.vehicle))
            return await measure(children, fleet.workspace, fleet.names, fleet.fleet, fleet.connect, seconds,
                                 steady_after, seed, fleet.tls_dir, disturbance)
        finally:
            _stop(fleet.agents, fleet.vehicles)
            if record is not None:
                gather_records(record, sorted(workdir.glob(f"{RECORD_PART}.*")))
                gather_records(truth_path(record), sorted(workdir.glob(f"{TRUTH_PART}.*")))


def _stop(agents: list[subprocess.Popen[bytes]], vehicles: list[subprocess.Popen[bytes]]) -> None:
    """The agents first (they land and leave), then the vehicles they land."""
    for group in (agents, vehicles):
        for child in group:
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
        for child in group:
            try:
                child.wait(60)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()


class _BenchFleet:
    """The bench's processes: the vehicles' simulator and the agent processes, and with a ``fault`` the
    struck drone's own two (on a host of its own, of ``hosts``, for a partition)."""

    def __init__(self, agents: int, processes: int, workdir: Path, shared_session: bool, secure: bool,
                 record: Path | None, fault: FaultPlan | None, hosts: Hosts | None) -> None:
        self.ws_file = workdir / f"bench-{agents}.yaml"
        self.ws_file.write_text(bench_workspace(agents))
        self.workspace = load_workspace(self.ws_file)
        self.names = list(self.workspace.drones)[:agents]
        self.struck = self.names[-1:] if fault else []
        self.crowd = self.names[:agents - len(self.struck)]
        self.workdir, self.record, self.fault, self.hosts = workdir, record, fault, hosts
        self.tls_dir = workdir / "tls" if secure else None
        self.share = -(-len(self.crowd) // processes)
        if self.tls_dir is not None:  # a host certificate for each process's session
            firsts = [*range(0, len(self.crowd), self.share), *(len(self.crowd) + i for i in range(len(self.struck)))]
            groups = {f"host-{self.names[first]}": self._group(first) for first in firsts}
            make_certs(self.tls_dir, [*self.workspace.drones, SERVICE], hosts=groups if shared_session else None)
        self.security = [*(["--tls-dir", str(self.tls_dir)] if self.tls_dir else ["--insecure"]),
                         *(["--shared-session"] * shared_session)]
        self.base, self.port = free_udp_base(agents), free_port_block(agents, socket.SOCK_STREAM)
        self.fleet = f"bench-{self.port}"
        self.here = hosts.gateway if hosts else "127.0.0.1"  #: where the crowd listens
        self.connect = f"tcp/{self.here}:{self.port}"
        self.vehicles: list[subprocess.Popen[bytes]] = []  #: the simulators started
        self.agents: list[subprocess.Popen[bytes]] = []  #: the agent processes started

    def _group(self, first: int) -> list[str]:
        """The drones of the agent process whose first is drone ``first``."""
        return self.names[first:min(first + self.share, len(self.crowd))] if first < len(self.crowd) else \
            [self.names[first]]

    def spawn_all(self) -> tuple[list[subprocess.Popen[bytes]], Victim | None]:
        """The crowd's processes (the vehicles' first), and the struck drone's; each is also in
        ``vehicles`` or ``agents`` as soon as it runs, to be stopped whatever happens next."""
        self.vehicles.append(spawn(self._vehicles(0, len(self.crowd))))
        for first in range(0, len(self.crowd), self.share):
            self.agents.append(spawn(self._agent(first, self.here), nice=AGENT_NICE))
        children = [*self.vehicles, *self.agents]
        if self.fault is None:
            return children, None
        first = len(self.crowd)
        on = [] if self.hosts is None else self.hosts.run_on(VICTIM_HOST, [])
        where = self.here if self.hosts is None else self.hosts.ip[VICTIM_HOST]
        offset = self.fault.clock_offset_s(self.workspace.beta_s)
        extra = [*(["--clock-offset", str(offset)] if offset else []),
                 *(["--clock-step-on-signal"] if self.fault.kind is Fault.CLOCK_STEP else [])]
        self.vehicles.append(vehicle := spawn(self._vehicles(first, 1), on=on))
        self.agents.append(agent := spawn([*self._agent(first, where), *extra], nice=AGENT_NICE, on=on))
        return children, Victim(self.fault, agent, vehicle, self.hosts)

    def _vehicles(self, first: int, count: int) -> list[str]:
        return ["sim-vehicle", "--workspace", str(self.ws_file), "--count", str(count), "--instance", str(first),
                "--base-port", str(self.base), "--ready-after", "0.5", *self._recording(TRUTH_PART, first)]

    def _agent(self, first: int, address: str) -> list[str]:
        """Agent process of the drones from ``first``, listening on ``address``; each agent listens on
        its port (``port + i``) and connects to the first's; gossip meshes the rest."""
        return ["agent", "--workspace", str(self.ws_file), "--drone", self.names[first],
                "--count", str(len(self._group(first))), "--fleet", self.fleet,
                "--listen", f"tcp/{address}:{self.port + first}", "--connect", self.connect,
                "--vehicle-base-port", str(self.base), "--lead-steps", str(default_lead_steps(self.workspace)),
                "--hover-lead-steps", str(max(4, self.workspace.delta + 1)),
                "--telemetry-hz", str(TELEMETRY_HZ), "--log-level", "WARNING", *self.security,
                *self._recording(RECORD_PART, first)]

    def _recording(self, part: str, first: int) -> list[str]:
        """``--record`` into this run's ``part`` for the process whose first drone is ``first``."""
        return [] if self.record is None else ["--record", str(self.workdir / f"{part}.{self.names[first]}")]


RECORD_PART = "flight"
TRUTH_PART = "truth"


def truth_path(record: Path) -> Path:
    """Where the simulator records, beside the agents' ``record``: where each vehicle really was."""
    return record.with_suffix(f".truth{record.suffix}")


def gather_records(record: Path, parts: list[Path]) -> None:
    """The processes' flight records, one after the other, into ``record`` (replaced). A process killed
    may have left its last line half written: only whole lines are kept."""
    texts = [part.read_text(encoding="utf-8") for part in parts]
    lines = [line for text in texts for line in text[:text.rfind("\n") + 1].splitlines() if line]
    record.write_text("".join(f"{line}\n" for line in lines), encoding="utf-8")


def audit_records(record: Path, workspace_text: str, what: str = "flight record") -> str:
    """Audit the flight record ``record``, with its workspace written beside it."""
    lines = [line for line in record.read_text(encoding="utf-8").splitlines() if line]
    ws_file = record.with_name(f"{record.name}.workspace.yaml")
    ws_file.write_text(workspace_text, encoding="utf-8")
    verdict = audit(load_workspace(ws_file), [json.loads(line) for line in lines])
    return (f"{what} {record} ({len(lines)} records, workspace {ws_file.name}): delta {verdict.delta}, "
            f"{'safe' if verdict.safe else f'{len(verdict.violations)} separation violations'}, "
            f"{len(verdict.jumps)} jumps, {_conformance(verdict.conformance)}")


def _conformance(conformance: Conformance) -> str:
    if not conformance.planned_steps:  # the simulator's record: no plan
        return "no plan in it"
    worst = "" if conformance.worst is None else f" (worst {conformance.worst})"
    return f"conformance {conformance.fraction:.1%}{worst}"


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
                        "workspace beside it), and the simulator's own record beside it (NAME.truth.jsonl: "
                        "where each vehicle really was), and audit both after the run")
    parser.add_argument("--fault", choices=[f.value for f in Fault],
                        help="strike the last drone mid-run (its agent and vehicle run apart): kill its agent "
                             "(SIGKILL), cut its host off (a network namespace; needs root), set its clock "
                             "past beta from its start, step its system clock in flight, or kill its vehicle; "
                             "judge with --record")
    parser.add_argument("--fault-at", type=float,
                        help="seconds into the mail the fault strikes (default: a third of --seconds)")
    parser.add_argument("--fault-for", type=float, default=30.0,
                        help="how long a partition lasts, s (default 30)")
    parser.add_argument("--steady-after", type=float, default=10.0,
                        help="also report the plans after this many seconds, past the opening burst (default 10)")


def run(args: argparse.Namespace) -> int:
    agents = args.agents or (8 if args.quick else 32)
    seconds = args.seconds or (15.0 if args.quick else 60.0)
    if agents < 2 or seconds <= 0:
        print("drona bench coordination: --agents must be >= 2 and --seconds > 0", file=sys.stderr)
        return 2
    if args.fault is not None and agents < 3:  # the survivor of a pair cannot tell a fault from its own
        print("drona bench coordination: --fault needs --agents >= 3", file=sys.stderr)
        return 2
    fault = None if args.fault is None else FaultPlan(
        Fault(args.fault), seconds / 3 if args.fault_at is None else args.fault_at, args.fault_for)
    if fault is not None and not (fault.at_s >= 0 and fault.for_s > 0 and fault.over_s < seconds):
        print("drona bench coordination: --fault-at must be >= 0, --fault-for > 0, and the fault over (--fault-at, "
              f"and --fault-for for a partition) before --seconds ({seconds:g})", file=sys.stderr)
        return 2
    processes = max(1, min(args.processes or default_processes(), agents - (fault is not None)))
    shared = not args.session_per_drone
    if not args.json:
        links = "plain TCP" if args.insecure else "mutual TLS, access control"
        print(f"drona bench coordination: {agents} agents (a Zenoh session per "
              f"{'process' if shared else 'drone'}, {links}) in {processes} `drona agent --count` processes, "
              f"{agents} fake vehicles in a `drona sim-vehicle`, loopback; mail for {seconds:g} s", flush=True)
        if fault is not None:
            struck = fault.describe(f"d{agents}", BENCH_BETA_S)
            print(f"fault: {struck} (it runs in an agent process and a simulator of its own)", flush=True)
    with tempfile.TemporaryDirectory() as workdir:
        try:
            result = asyncio.run(run_bench(agents, processes, seconds, args.steady_after, Path(workdir),
                                           shared_session=shared, secure=not args.insecure,
                                           record=args.record.resolve() if args.record else None, fault=fault))
        except BenchError as exc:
            print(f"drona bench coordination: {exc}", file=sys.stderr)
            return 1
    if args.json:
        if args.record is not None:
            print(_audits(args.record, agents), file=sys.stderr)
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
          f"  the opening burst: {result.plans - result.steady_plans} plans, the head of the line flown "
          f"{result.opening_first_ms:.2f} ms after its task; each drone's first plan seen, from the mail given "
          f"(waits for a task to start included): p50 {result.opening_first_plan_p50_ms:.0f} ms, the last "
          f"{result.opening_last_first_plan_ms:.0f} ms; CPU of each agent process in the first "
          f"{OPENING_S:g} s of the mail: {', '.join(f'{ms:.0f}' for ms in result.opening_cpu_ms)} ms\n"
          f"protocol messages per round {result.messages_per_round:.1f} (3(N-1) = {3 * (agents - 1)} for a plan "
          f"proposed at once and held: proposed, held, flown; 5(N-1) = {5 * (agents - 1)} for a round that asks "
          f"first: asked and answered too)\n"
          f"CPU per agent {result.cpu_ms_per_s_per_agent:.1f} ms/s (the agent processes / agents; the vehicles' "
          f"process {result.vehicles_cpu_s_per_s:.2f} s/s)\n"
          f"host speed: a reference Python loop took {result.reference_ms_before:.0f} ms before the mail and "
          f"{result.reference_ms_after:.0f} ms after (lower is faster; the figures above scale with it)")
    for line in result.fault:
        print(f"fault: {line}")
    bench_plot.write(args, "coordination", result)
    if args.record is not None:
        print(_audits(args.record, agents))
    return 0


def _audits(record: Path, agents: int) -> str:
    """The agents' record (what telemetry showed them) and the simulator's (where the vehicles were)."""
    return "\n".join((audit_records(record, bench_workspace(agents)),
                      audit_records(truth_path(record), bench_workspace(agents), "the simulator's record")))
