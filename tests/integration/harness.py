"""A fleet in separate processes for the integration tests: `drona sim-vehicle` plus one `drona agent` each.

Everything runs on 127.0.0.1 with ports the OS reports free, under a fleet
name of its own. The :class:`Observer` is an outside Zenoh session (like
`drona mail` or the service) that gives mail, follows the status reports and
states, and sees drones come and go.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from drona_gcs.audit import Audit, audit
from drona_gcs.workspace import ARDUCOPTER
from drona_gcs.workspace_files import load_workspace
from fleet.sim.ports import free_port_block, free_udp_base
from fleet.transport.fleet_client import FleetClient
from fleet.transport.identity import SERVICE
from fleet.transport.keys import FleetKeys
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings
from fleet.transport.wire import DroneState, MailOrder, MailStatus, MailStatusReport, WireError, decode
from tests.conftest import fleet_tls_dir
from tests.integration.hosts import Hosts

DRONA = [sys.executable, "-m", "fleet.cli"]
SPEEDUP = 6.0  #: the fake vehicles' simulated seconds per second: they track a cell per tau easily
#: Delta + 1, and 6 steps (3 s) for the take-off: the fake spools up for 3.5 s and climbs 2 m (simulated,
#: about 1.2 s at SPEEDUP), after the mode change and arming are acknowledged and confirmed. A vehicle
#: still climbing when its plan moves on is late, past lambda.
LEAD_STEPS = 8


#: An agent as a Zenoh client of its host's router (the test adds the router's endpoint): it waits for
#: the router at start-up as deploy/zenoh/client.json5 does, and never scouts.
CLIENT_CONFIG = """{
  mode: "client",
  connect: { timeout_ms: 30000, exit_on_failure: true,
             retry: { period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2 } },
  scouting: { multicast: { enabled: false } },
}
"""


def workspace_yaml(drones: int) -> str:
    """A 10x10 grid with a wall in the middle, two chargers, a parking cell per drone on the rim."""
    starts = [(1 + 2 * (i % 4), 1 + 7 * (i // 4)) for i in range(drones)]
    parking = [(0, 2 + 2 * (i % 4)) if i < 4 else (9, 2 + 2 * (i % 4)) for i in range(drones)]
    lines = [
        # Vehicles at SPEEDUP enter their cells within a fifth of a second: lambda is theirs, not ArduCopter's.
        "name: integration", "size: [10, 10, 1]", "cell_size_m: 1.0", "tau_s: 0.5", "beta_s: 0.2", "lambda_s: 0.3",
        f"vehicle: {json.dumps(asdict(ARDUCOPTER.sped_up(SPEEDUP)))}",  # ArduCopters at SPEEDUP
        "geo_origin: {lat: 47.397742, lon: 8.545594, alt_m: 488.0, layer0_alt_m: 2.0}",
        "obstacles:", "  - box: [[4, 4, 0], [5, 5, 0]]",
        "charging_stations: [[0, 0, 0], [9, 9, 0]]",
        "parking: [" + ", ".join(f"[{x}, {y}, 0]" for x, y in parking) + "]",
        "drones:", *(f"  d{i + 1}: [{x}, {y}, 0]" for i, (x, y) in enumerate(starts)),
    ]
    return "\n".join(lines) + "\n"


@dataclass
class FleetProcesses:
    tmp: Path
    drones: list[str]
    fleet: str = field(default_factory=lambda: f"it-{uuid.uuid4().hex[:8]}")
    offsets: dict[str, float] = field(default_factory=dict)  #: injected clock offsets, s
    hosted: bool = False  #: every drone in one `drona agent --count N --shared-session` process
    agent_options: tuple[str, ...] = ()  #: more `drona agent` options for every agent
    vehicles_apart: bool = False  #: each vehicle in its own `drona sim-vehicle` process (it may die alone)
    #: each drone (agent and vehicle) on its host, ``host_of[drone]``; the vehicles apart then
    hosts: Hosts | None = None
    host_of: dict[str, str] = field(default_factory=dict)
    #: a `drona router` on every host, joined to the others; the agents its Zenoh clients (else a peer mesh)
    routers: bool = False
    #: by drone, or "all"; and the routers, "router-<host>": stopped with the vehicles
    sims: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    agents: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    others: list[subprocess.Popen[bytes]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.workspace = self.tmp / "ws.yaml"
        self.workspace.write_text(workspace_yaml(len(self.drones)))
        self.vehicle_base = free_udp_base(len(self.drones))
        # A block below the ephemeral range: a port picked there cannot be taken meanwhile by some
        # socket's outgoing connection (the agents and the observer make many).
        base = free_port_block(len(self.drones) + 1, socket.SOCK_STREAM)
        self.ports = {d: base + i for i, d in enumerate(self.drones)}
        self.router_port = base + len(self.drones)
        self.vehicles_apart = self.vehicles_apart or self.hosts is not None
        self.client_config = self.tmp / "client.json5"
        self.client_config.write_text(CLIENT_CONFIG)

    @property
    def tls_dir(self) -> Path:
        """The fleet's certificates (a hosted fleet's session presents the test session's host certificate)."""
        return fleet_tls_dir()

    def endpoint(self, drone: str) -> str:
        """Where a session reaches ``drone``: its agent, or its host's router."""
        if self.hosts is None:
            return f"tcp/127.0.0.1:{self.ports[drone]}"
        ip = self.hosts.ip[self.host_of[drone]]
        return f"tcp/{ip}:{self.router_port if self.routers else self.ports[drone]}"

    def endpoints(self) -> list[str]:
        """Where an outside session connects: every agent, or every router."""
        return list(dict.fromkeys(self.endpoint(d) for d in self.drones))

    def record(self, drone: str) -> Path:
        return self.tmp / f"record-{drone}.jsonl"

    def truth(self, sim: str) -> Path:
        """The record of simulator ``sim`` (a drone's, or "all"): where its vehicles were."""
        return self.tmp / f"truth-{sim}.jsonl"

    def start(self) -> None:
        if self.routers:
            assert self.hosts is not None, "routers run on hosts"
            for host in dict.fromkeys(self.host_of.values()):
                self.sims[f"router-{host}"] = self._spawn(f"router-{host}", self.router_command(host), host)
        vehicles = [*DRONA, "sim-vehicle", "--workspace", str(self.workspace), "--base-port", str(self.vehicle_base),
                    "--speedup", str(SPEEDUP), "--ready-after", "0.5"]
        if self.vehicles_apart:
            for i, drone in enumerate(self.drones):
                self.sims[drone] = self._spawn(f"sim-{drone}", [*vehicles, "--count", "1", "--instance", str(i),
                                                                "--record", str(self.truth(drone))],
                                               self.host_of.get(drone))
        else:
            self.sims["all"] = self._spawn("sim", [*vehicles, "--count", str(len(self.drones)),
                                                   "--record", str(self.truth("all"))])
        if self.hosted:
            self.agents["+".join(self.drones)] = self._spawn("host", self.host_command())
            return
        for i, drone in enumerate(self.drones):
            self.agents[drone] = self._spawn(drone, self.agent_command(drone, i), self.host_of.get(drone))

    def router_command(self, host: str) -> list[str]:
        """The router of ``host``, joined to every other host's; with the agents' lease, if they set one."""
        assert self.hosts is not None
        others = [f"tcp/{ip}:{self.router_port}" for h, ip in self.hosts.ip.items()
                  if h != host and h in self.host_of.values()]
        lease = self.agent_options[self.agent_options.index("--lease"):][:2] if "--lease" in self.agent_options else ()
        return [*DRONA, "router", "--listen", f"tcp/{self.hosts.ip[host]}:{self.router_port}",
                *(arg for ep in others for arg in ("--connect", ep)), "--workspace", str(self.workspace),
                "--fleet", self.fleet, *lease]

    def add_router(self, host: str) -> None:
        """A router on ``host``, which flies no drone (the service's, say), joined to every drone's host."""
        self.sims[f"router-{host}"] = self._spawn(f"router-{host}", self.router_command(host), host)

    def host_command(self) -> list[str]:
        """One process for the whole fleet: drone i listens i ports up from the first (as the ports are)."""
        first = self.drones[0]
        return [*DRONA, "agent", "--workspace", str(self.workspace), "--drone", first,
                "--count", str(len(self.drones)), "--shared-session", "--vehicle-base-port", str(self.vehicle_base),
                "--fleet", self.fleet, "--listen", self.endpoint(first), "--record", str(self.record("host")),
                "--lead-steps", str(LEAD_STEPS), *self.agent_options]

    def agent_command(self, drone: str, index: int) -> list[str]:
        command = [*DRONA, "agent", "--workspace", str(self.workspace), "--drone", drone,
                   "--vehicle", f"udpin://127.0.0.1:{self.vehicle_base + index}", "--fleet", self.fleet,
                   "--record", str(self.record(drone)), "--lead-steps", str(LEAD_STEPS)]
        if self.routers:
            command += ["--zenoh-config", str(self.client_config), "--connect", self.endpoint(drone)]
        else:
            command += ["--listen", self.endpoint(drone)]
            command += [arg for other in self.drones if other != drone for arg in ("--connect", self.endpoint(other))]
        if drone in self.offsets:
            command += ["--clock-offset", str(self.offsets[drone])]
        return command + list(self.agent_options)

    def spawn(self, name: str, arguments: list[str], host: str | None = None) -> subprocess.Popen[bytes]:
        """Another `drona` process of this run (stopped by :meth:`kill_all`), its output in ``<name>.log``."""
        process = self._spawn(name, [*DRONA, *arguments], host)
        self.others.append(process)
        return process

    def _spawn(self, name: str, command: list[str], host: str | None = None) -> subprocess.Popen[bytes]:
        """``command`` on ``host`` (None: this one), its output in ``<name>.log``."""
        if host is not None:
            assert self.hosts is not None
            command = self.hosts.run_on(host, command)
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONFAULTHANDLER": "1"}
        with (self.tmp / f"{name}.log").open("ab") as log:  # the child keeps its own handle
            return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)

    def signal(self, drone: str, sig: int) -> None:
        self.agents[drone].send_signal(sig)

    def stop(self, timeout: float = 30.0) -> dict[str, int | None]:
        """SIGINT every agent (graceful: finish, land, leave), then the vehicles; the agents' exit codes."""
        codes: dict[str, int | None] = {}
        for process in self.agents.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout
        for drone, process in self.agents.items():
            try:
                codes[drone] = process.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                process.kill()
                codes[drone] = None
        for sim in self.sims.values():
            if sim.poll() is None:
                sim.send_signal(signal.SIGINT)
                try:
                    sim.wait(10)
                except subprocess.TimeoutExpired:
                    sim.kill()
        return codes

    def kill_all(self) -> None:
        for process in [*self.others, *self.agents.values(), *self.sims.values()]:
            if process.poll() is None:
                process.send_signal(signal.SIGABRT)  # still running at the end: its stacks go to its log
                try:
                    process.wait(3)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait(10)

    def audit(self) -> Audit:
        records = []
        for drone in ["host"] if self.hosted else self.drones:
            path = self.record(drone)
            if path.exists():
                records += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
        return audit(load_workspace(self.workspace), records)

    def truth_audit(self) -> Audit:
        """The audit of the simulators' records: what was flown, judged apart from the agents."""
        records = [json.loads(line) for path in sorted(self.tmp.glob("truth-*.jsonl"))
                   for line in path.read_text().splitlines() if line.strip()]
        return audit(load_workspace(self.workspace), records)

    def logs(self) -> str:
        tails = (f"--- {p.name}\n{p.read_text(errors='replace')[-3000:]}" for p in sorted(self.tmp.glob("*.log")))
        return "\n".join(tails)


class Observer:
    """An outside session on the fleet: gives mail, keeps every status report and the latest states."""

    def __init__(self, fleet: FleetProcesses, lease_s: float | None = None) -> None:
        """``lease_s``: the session's Zenoh lease (the fleet's, when its agents run another)."""
        self.fleet, self.lease_s = fleet, lease_s
        self.keys = FleetKeys(fleet.fleet)
        self.reports: list[MailStatusReport] = []
        self.states: dict[str, DroneState] = {}
        self.min_battery: dict[str, float] = defaultdict(lambda: 100.0)
        self.alive: set[str] = set()
        self.changed = asyncio.Event()

    async def __aenter__(self) -> Observer:
        connect = tuple(self.fleet.endpoints())
        settings = ZenohSettings(connect=connect, lease_s=self.lease_s).secured(self.fleet.tls_dir, SERVICE, self.keys,
                                                                                self.fleet.drones)
        self.node = await ZenohNode.open(settings, "observer")
        self.node.subscribe(self.keys.status(), self._on_report)
        self.node.subscribe(self.keys.state(), self._on_state)
        self.node.watch_liveliness(self.keys.alive(), self._on_alive)
        self.client = FleetClient(self.node, self.keys, "observer")
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.node.close()

    def _on_report(self, key: str, payload: bytes) -> None:
        body = _body(payload)
        if isinstance(body, MailStatusReport):
            self.reports.append(body)
            self.changed.set()

    def _on_state(self, key: str, payload: bytes) -> None:
        body = _body(payload)
        if isinstance(body, DroneState):
            self.states[body.drone] = body
            if body.battery_pct is not None:
                self.min_battery[body.drone] = min(self.min_battery[body.drone], body.battery_pct)
            self.changed.set()

    def _on_alive(self, key: str, alive: bool) -> None:
        drone = self.keys.last_chunk(key)
        (self.alive.add if alive else self.alive.discard)(drone)
        self.changed.set()

    async def until(self, condition: object, timeout: float, what: str) -> None:
        """Wait (on events, not polling) until ``condition()`` holds; AssertionError naming ``what``."""
        assert callable(condition)
        deadline = time.monotonic() + timeout
        while not condition():
            self.changed.clear()
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"timed out after {timeout:g} s waiting for {what}\n{self.fleet.logs()}")
            try:
                await asyncio.wait_for(self.changed.wait(), left)
            except TimeoutError:
                continue

    async def joined(self) -> None:
        """Until every agent of the fleet is alive."""
        await self.until(lambda: self.alive >= set(self.fleet.drones), 60, "every agent to join")

    async def parked(self) -> None:
        """Until every agent is alive and every drone, its first plan flown (idle drones park first),
        rests landed and waiting for a task (at start-up every drone is landed and waiting, unplanned),
        its vehicle on time: one found late on its way takes no mail until a sample finds it there."""
        await self.joined()
        await self.until(lambda: len(self.states) == len(self.fleet.drones) and all(
            s.plans >= 1 and s.landed and s.mode == "WaitForTaskRequest"
            and not any(alarm.startswith("late:") for alarm in s.health.alarms) for s in self.states.values()),
            60, "all parked")

    async def give(self, order: MailOrder, drone: str) -> None:
        ack = await self.client.assign(drone, order)
        assert ack.accepted, f"{drone} refused {order.id}: {ack.reason}"

    def statuses(self, mail_id: str) -> list[MailStatus]:
        return [r.status for r in self.reports if r.id == mail_id]

    def delivered(self, mail_ids: Sequence[str]) -> bool:
        return all(MailStatus.DELIVERED in self.statuses(m) for m in mail_ids)

    def priority_violations(self, orders: dict[str, MailOrder]) -> list[str]:
        """Per drone: a mail started while a more urgent one had already been accepted and waited (not
        started, nor given up)."""
        found = []
        accepted: dict[tuple[str, str], int] = {}
        started: dict[tuple[str, str], int] = {}
        left: dict[tuple[str, str], int] = {}
        gone = (MailStatus.REJECTED, MailStatus.HANDED_BACK, MailStatus.CANCELLED)
        for r in self.reports:
            if r.status in (MailStatus.ACCEPTED, MailStatus.REASSIGNED):
                accepted.setdefault((r.drone, r.id), r.step)
            elif r.status is MailStatus.STARTED:
                started.setdefault((r.drone, r.id), r.step)
            elif r.status in gone:
                left.setdefault((r.drone, r.id), r.step)
        for (drone, mail), step in started.items():
            for (other_drone, other), since in accepted.items():
                if other_drone != drone or other == mail or since >= step:
                    continue
                other_start = started.get((drone, other), left.get((drone, other)))
                waiting = other_start is None or other_start > step
                if waiting and orders[other].priority > orders[mail].priority:
                    found.append(f"{drone} started {mail} (p{orders[mail].priority}) at step {step} while "
                                 f"{other} (p{orders[other].priority}) waited since step {since}")
        return found


def _body(payload: bytes) -> object:
    try:
        return decode(payload).body
    except WireError:
        return None
