"""The agent process: one or more drones (``--count``), one TaskGroup, one setpoint timer.

Start-up, per drone and concurrently: open its own Zenoh session (or, with
``--shared-session``, one for the process that its drones share, each with its
own declarations), connect its vehicle and give it ``ready_timeout_s`` to be
ready; then every drone joins the fleet. A vehicle still not ready (ArduCopter
SITL needs about 45 s for its position estimate) joins ``waiting_for_position``
and takes no task until it is; its placement is checked once it has a position.
Steps are counted on the process's clock from the fleet epoch.

Shutdown (SIGINT or SIGTERM): no new mail or tasks; drones flying a plan
finish it (peers planned around it) and coordinations under way end; then
the drones land in their own column, publish a last state and leave (every
Zenoh declaration undeclared, then the session closed). A second signal skips
the wait: the drones hold where they are and leave at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import signal
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import TextIO, TypeVar

from drona_gcs.errors import DronaError, VehicleError, VehicleLimitsError
from drona_gcs.geo import GeoFrame
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.drone import DroneStack, StackConfig, default_hover_lead_steps, default_lead_steps
from drona_gcs.workspace import Workspace
from fleet import runtime
from fleet.agent.admission import TaskBudget
from fleet.agent.drone import BROADCAST, DroneAgent
from fleet.agent.settings import AgentSettings
from fleet.clock import FleetClock, cancel_all, periodic
from fleet.setpoint_loop import Sample, SetpointFleet, SetpointLoop, StepReport
from fleet.transport.identity import Speakers, identity_for
from fleet.transport.inbox import inbox_of
from fleet.transport.keys import FleetKeys, check_name
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings, agent_endpoint
from fleet.vehicle.limits import bound_flying_on, parameters_to_read, shortfalls
from fleet.vehicle.link import REOPEN_S, Autopilot, VehicleLink
from fleet.vehicle.mavlink_link import PymavlinkLink
from fleet.vehicle.policy import Timeouts

log = logging.getLogger(__name__)

CONNECT_LOG_EVERY = 10  #: a vehicle that does not answer is logged at the first and every tenth attempt
LANDING_BOUND_S = 30.0  #: at shutdown, how long the drones may take to land


@dataclass
class Host:
    settings: AgentSettings
    workspace: Workspace
    names: list[str]
    agents: list[DroneAgent] = field(default_factory=list)
    stop_stepping: asyncio.Event = field(default_factory=asyncio.Event)
    draining: asyncio.Event = field(default_factory=asyncio.Event)
    hurry: asyncio.Event = field(default_factory=asyncio.Event)
    drained: asyncio.Event = field(default_factory=asyncio.Event)

    clock_stepped: bool = False  #: with ``clock_step_on_signal``: SIGUSR1 came
    clock: FleetClock = field(init=False)  #: the drones' schedule's: it never steps

    def __post_init__(self) -> None:
        self.clock = FleetClock(self._system_clock)

    def _system_clock(self) -> float:
        """The system clock, shifted by ``--clock-offset`` (from the start, or from SIGUSR1 on)."""
        shifted = self.clock_stepped or not self.settings.clock_step_on_signal
        return time.time() + (self.settings.clock_offset_s if shifted else 0.0)


def select_drones(settings: AgentSettings, workspace: Workspace) -> list[str]:
    """``--drone`` and the ``count - 1`` drones after it in the workspace (the first ``count`` without it)."""
    drones = list(workspace.drones)
    for drone in drones:
        check_name("drone", drone)
        if drone == BROADCAST:
            raise ValueError(f"a drone may not be called {BROADCAST!r}: proto/{BROADCAST} reaches every drone")
    first = 0
    if settings.drone is not None:
        check_name("drone", settings.drone)
        if settings.drone not in workspace.drones:
            raise ValueError(f"drone {settings.drone!r} is not in the workspace (it has {', '.join(drones)})")
        first = drones.index(settings.drone)
    names = drones[first:first + settings.count]
    if len(names) < settings.count:
        raise ValueError(f"--count {settings.count} from {drones[first]!r}: the workspace has only "
                         f"{len(names)} drones from there ({', '.join(drones)})")
    return names


def session_groups(settings: AgentSettings, names: Sequence[str]) -> list[list[str]]:
    """The drones of each Zenoh session: one each (as on a real fleet), or all in one (``--shared-session``)."""
    return [list(names)] if settings.shared_session else [[name] for name in names]


def zenoh_settings(settings: AgentSettings, workspace: Workspace, names: Sequence[str],
                   first: int = 0) -> ZenohSettings:
    """A session of drones ``names``, the ``first``-th of the process onwards, listening wherever they
    are expected: explicit endpoints (the i-th drone of a process ``i`` ports up), a config file, or
    the one-machine default (drone k of the workspace on 7448 + k, connecting to the others')."""
    listen = tuple(_shift_port(ep, first + i) for i in range(len(names)) for ep in settings.listen)
    connect = tuple(ep for ep in settings.connect if ep not in listen)
    if settings.zenoh_config is None and not listen and not connect:
        drones = list(workspace.drones)
        listen = tuple(agent_endpoint(drones.index(name)) for name in names)
        connect = tuple(agent_endpoint(i) for i, drone in enumerate(drones) if drone not in names)
    plain = ZenohSettings(listen=listen, connect=connect, config_file=settings.zenoh_config, lease_s=settings.lease_s,
                          max_frames=len(workspace.drones))
    name = host_name(settings, names) or names[0]
    return plain.secured(settings.tls_dir, name, FleetKeys(settings.fleet), list(workspace.drones))


def host_name(settings: AgentSettings, names: Sequence[str]) -> str | None:
    """The host a session of several drones speaks as (None: one drone's session, or no TLS to name a host)."""
    if settings.tls_dir is None or len(names) < 2:
        return None
    return identity_for(settings.tls_dir, names)


def _shift_port(endpoint: str, offset: int) -> str:
    if offset == 0:
        return endpoint
    head, _, port = endpoint.rpartition(":")
    if not port.isdigit():
        raise ValueError(f"listen endpoint {endpoint!r} needs a port to give each of --count agents its own")
    return f"{head}:{int(port) + offset}"


def vehicle_url(settings: AgentSettings, workspace: Workspace, drone: str) -> str:
    if settings.vehicle is not None:
        return settings.vehicle
    return f"udpin://127.0.0.1:{settings.vehicle_base_port + list(workspace.drones).index(drone)}"


async def run_host(host: Host, record: TextIO | None, on_ready: Callable[[Host], None] | None = None) -> None:
    settings, ws = host.settings, host.workspace
    frame = GeoFrame(ws)
    planner = SafePlanner(ws, delta=ws.delta)
    battery = BatteryModel.for_period(ws.tau_s, settings.drain_per_step, settings.safe_threshold)
    lead = settings.lead_steps or default_lead_steps(ws)
    hover = min(settings.hover_lead_steps or default_hover_lead_steps(ws), lead)
    config = StackConfig(ws, planner, battery, lead_steps=lead, hover_lead_steps=hover)
    keys = FleetKeys(settings.fleet)
    signing = settings.signing_keys(host.names)  # before any network: a missing key stops the process here
    groups = session_groups(settings, host.names)
    sessions = await _all_or_none([ZenohNode.open(zenoh_settings(settings, ws, group, host.names.index(group[0])),
                                                  "+".join(group)) for group in groups], lambda node: node.close())
    nodes = [session.view(name) for session, group in zip(sessions, groups, strict=True) for name in group]
    hosts = {name: host_name(settings, group) for group in groups for name in group}
    speakers = Speakers.of(settings.tls_dir, ws.drones)
    links: list[VehicleLink] = []
    try:
        # Nothing flies yet: a signal while a vehicle is awaited leaves at once.
        connected = await _unless_stopped(host, _all_or_none(
            [_connect(host, frame, name, signing.get(name)) for name in host.names], lambda link: link.close()))
        if connected is None:
            log.info("stopped before any vehicle answered")
            return
        links = connected
        budget = TaskBudget.of_period(ws.tau_s)  # one for the host: its drones share its CPU
        for node, link, name in zip(nodes, links, host.names, strict=True):
            stack = DroneStack(name, config, ws.drones, epoch=time.time_ns() // 1_000_000)
            agent = DroneAgent(stack, node, keys, link, frame, host.clock, record, timeouts(settings),
                               epoch_s=settings.epoch, host=hosts[name], speakers=speakers)
            agent.mail.adopt = settings.adopt_mail
            if not settings.adopt_mail:  # a service dispatches the mail: it clears each for pickup
                stack.mail.cleared = set()
            agent.lease_steps = math.ceil(settings.lease_s / ws.tau_s)
            agent.backlog_s = inbox_of(asyncio.get_running_loop()).backlog_s
            agent.budget = budget
            host.agents.append(agent)
        for agent in host.agents:
            _check_placement(agent)
        runtime.settle_gc()  # before the drones join: nobody waits on this process yet
        # Together: each joins with two queries to the fleet, and the process steps only once all have
        # joined, while the drones already flying elsewhere take work without it.
        joined = await asyncio.gather(*(agent.start() for agent in host.agents), return_exceptions=True)
        failures = [failure for failure in joined if isinstance(failure, BaseException)]
        if len(failures) == 1:
            raise failures[0]
        if failures:  # each drone's reason (the CLI prints every one)
            raise BaseExceptionGroup("drones could not join the fleet", failures)
        log.info("drones %s up: fleet %r, tau %.3g s, Delta %d, lead %d steps", ", ".join(host.names),
                 settings.fleet, ws.tau_s, ws.delta, lead)
        if on_ready is not None:
            on_ready(host)
        await _fly(host, frame, record)
    finally:
        await asyncio.gather(*(node.close() for node in nodes), return_exceptions=True)
        await asyncio.gather(*(session.close() for session in sessions), return_exceptions=True)
        await asyncio.gather(*(link.close() for link in links), return_exceptions=True)
        log.info("drones %s left the fleet", ", ".join(host.names))


T = TypeVar("T")


async def _unless_stopped(host: Host, work: Awaitable[T]) -> T | None:
    """``work``'s result, or None if a signal came first (``work`` is then cancelled)."""
    task, stop = asyncio.ensure_future(work), asyncio.ensure_future(host.draining.wait())
    try:
        await asyncio.wait([task, stop], return_when=asyncio.FIRST_COMPLETED)
    finally:
        await cancel_all([stop, *([] if task.done() else [task])])
    return task.result() if not task.cancelled() else None


async def _all_or_none(starts: Sequence[Awaitable[T]], close: Callable[[T], Awaitable[object]]) -> list[T]:
    """Start everything concurrently; if anything fails, close what did start and raise the first failure."""
    started = await asyncio.gather(*starts, return_exceptions=True)
    good = [item for item in started if not isinstance(item, BaseException)]
    failure = next((item for item in started if isinstance(item, BaseException)), None)
    if failure is not None:
        await asyncio.gather(*(close(item) for item in good), return_exceptions=True)
        raise failure
    return good


def _check_placement(agent: DroneAgent) -> None:
    """The stack starts the drone at its workspace start cell: its vehicle must be there (in that
    column), or its first plan would fly it from elsewhere across cells nobody reserved. A vehicle
    without a position yet is placed by its agent once it has one."""
    start, here = agent.stack.executor.cell, agent.watch.recorded_cell()
    if here is None:
        return
    if here[:2] != start[:2]:
        raise DronaError(f"drone {agent.me}: its vehicle is over cell {list(here)}, not at its start cell "
                         f"{list(start)}: bring it there, or give the workspace its cell")
    agent.placed = True


def timeouts(settings: AgentSettings) -> Timeouts:
    return Timeouts(takeoff_start_s=settings.takeoff_timeout_s, command_s=settings.command_timeout_s)


def open_link(settings: AgentSettings, url: str, frame: GeoFrame, signing_key: bytes | None = None) -> VehicleLink:
    """The vehicle link of ``--backend``: pymavlink (the default), or MAVSDK (the ``mavsdk`` extra, which
    refuses a signing key). With ``signing_key`` the link signs and hears only signed messages."""
    hz, rate, limits = settings.telemetry_hz, settings.rate_hz, timeouts(settings)
    if settings.backend == "mavsdk":
        try:
            from fleet.vehicle.mavsdk_link import MavsdkLink
        except ImportError as exc:
            raise DronaError(f"--backend mavsdk needs MAVSDK (pip install 'drona-gcs[mavsdk]'): {exc}") from exc
        return MavsdkLink(url, frame=frame, stream_hz=hz, setpoint_hz=rate, timeouts=limits, signing_key=signing_key)
    return PymavlinkLink(url, frame=frame, stream_hz=hz, setpoint_hz=rate, timeouts=limits, signing_key=signing_key)


async def _connect(host: Host, frame: GeoFrame, name: str, signing_key: bytes | None) -> VehicleLink:
    """The drone's link, once its vehicle answers: a vehicle not up yet (or rebooting) is waited for."""
    settings, ws = host.settings, host.workspace
    url = vehicle_url(settings, ws, name)
    for attempt in itertools.count():
        link = open_link(settings, url, frame, signing_key)
        try:
            await link.connect()
            await _check_limits(link, ws, name)  # a VehicleLimitsError is not retried: the vehicle must be set
            break
        except VehicleError as exc:
            await link.close()
            if attempt % CONNECT_LOG_EVERY == 0:
                log.warning("drone %s: no vehicle yet (%s); trying again every %g s", name, exc, REOPEN_S)
            await asyncio.sleep(REOPEN_S)  # a connection refused comes back at once: pace the attempts
        except BaseException:
            await link.close()
            raise
    with contextlib.suppress(VehicleError):  # not ready yet: it joins waiting for its position
        await link.wait_ready(settings.ready_timeout_s)
    return link


async def _check_limits(link: VehicleLink, workspace: Workspace, name: str) -> None:
    """Refuse a vehicle whose autopilot is set to fly less than the workspace's ``vehicle`` limits, which
    lambda, and so every plan's margin, is derived from (:mod:`fleet.vehicle.limits`)."""
    autopilot = link.telemetry().autopilot or Autopilot.OTHER
    names = parameters_to_read(autopilot)
    if not names:
        log.warning("drone %s: its autopilot (%s) has no limits this agent can read: not checked against the "
                    "workspace's vehicle", name, autopilot.value)
        return
    values = await bound_flying_on(link, autopilot, await link.read_parameters(names), workspace.tau_s, name)
    short = shortfalls(autopilot, values, workspace.vehicle, workspace.tau_s)
    if short:
        raise VehicleLimitsError(f"drone {name}: its vehicle flies less than the workspace's vehicle limits, "
                                 f"which lambda is derived from: {'; '.join(short)}. Set its parameters, or give "
                                 "the workspace what it flies")


async def _fly(host: Host, frame: GeoFrame, record: TextIO | None) -> None:
    settings, ws = host.settings, host.workspace
    # A route after a stall is checked as often as positions come.
    loops = [SetpointLoop(agent.link, frame, agent.stack.executor, settings.epoch, ws.tau_s, host.clock,
                          settings.telemetry_hz, tick=agent.tick, lateness_s=ws.lateness_s, link_clock=agent.link.clock)
             for agent in host.agents]
    for agent, loop in zip(host.agents, loops, strict=True):
        agent.setpoints = loop

    def on_step(i: int, report: StepReport, actions: Sequence[object]) -> None:
        host.agents[i].on_step(report, actions)
        if i == len(host.agents) - 1 and host.draining.is_set() and not any(agent.busy for agent in host.agents):
            host.drained.set()

    def on_sample(i: int, sample: Sample) -> None:
        host.agents[i].on_sample(sample)
        if i == len(host.agents) - 1 and record is not None:
            record.flush()

    async with asyncio.TaskGroup() as group:
        group.create_task(SetpointFleet(loops).run(on_step, host.stop_stepping, on_sample))
        supervisors = [group.create_task(agent.vehicle.run()) for agent in host.agents]
        clocks = group.create_task(_check_clocks(host))
        await host.draining.wait()
        for agent in host.agents:
            agent.mail.accepting = False
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(_first(host.drained, host.hurry), _drain_bound(host))
        await _land_all(host)
        host.stop_stepping.set()
        for agent in host.agents:
            agent.vehicle.stop()
            agent.publish_state()
        await cancel_all([clocks, *supervisors])


def _drain_bound(host: Host) -> float:
    """Long enough for every plan under way to finish, with a few steps to spare."""
    ends = [agent.stack.protocol.trajectory.end_step for agent in host.agents
            if agent.stack.protocol.trajectory is not None]
    now = max(agent.stack.now for agent in host.agents)
    return (max([*ends, now]) - now + 4) * host.workspace.tau_s + 2.0


async def _land_all(host: Host) -> None:
    """Each drone lands in its own column (bounded; skipped on a second signal). A lost vehicle is not
    waited for: it cannot be told to land, and its link keeps trying until the process ends."""
    if host.hurry.is_set():
        return
    for agent in host.agents:
        agent.vehicle.land_for_good()
    answering = [agent for agent in host.agents if not agent.watch.lost]
    landed = asyncio.gather(*(agent.vehicle.reached.wait() for agent in answering))
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(_first_of(landed, host.hurry.wait()), LANDING_BOUND_S)


async def _first(*events: asyncio.Event) -> None:
    await _first_of(*(event.wait() for event in events))


async def _first_of(*waits: Awaitable[object]) -> None:
    waiters = [asyncio.ensure_future(w) for w in waits]
    try:
        await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
    finally:
        await cancel_all(waiters)


async def _check_clocks(host: Host) -> None:
    """The host's drones share its clock: one of them measures it against the fleet, all judge."""
    async for _ in periodic(host.settings.clock_check_s):  # a measurement period, not a wait for an event
        samples = await host.agents[0].measure_clocks()
        for agent in host.agents:
            agent.judge_clocks(samples)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def install_signals(host: Host) -> None:
    """First SIGINT/SIGTERM: drain and land; a second one: leave now."""
    loop = asyncio.get_running_loop()

    def on_signal() -> None:
        if host.draining.is_set():
            log.warning("second signal: leaving now, drones hold where they are")
            host.hurry.set()
        else:
            log.info("stopping: finishing the plans under way, then landing")
        host.draining.set()

    for sig in STOP_SIGNALS:
        loop.add_signal_handler(sig, on_signal)
    if host.settings.clock_step_on_signal:
        loop.add_signal_handler(CLOCK_STEP_SIGNAL, lambda: _step_clock(host))


CLOCK_STEP_SIGNAL = signal.SIGUSR1


def _step_clock(host: Host) -> None:
    log.warning("clock stepped by %+g s (SIGUSR1)", host.settings.clock_offset_s)
    host.clock_stepped = True


def ignore_signals() -> None:
    """The fleet has left: what is left is the exit. A second Ctrl-C then would kill the process by
    the default handler (exit -2, a traceback) rather than end it cleanly: it is ignored."""
    loop = asyncio.get_running_loop()
    for sig in STOP_SIGNALS:
        loop.remove_signal_handler(sig)
        signal.signal(sig, signal.SIG_IGN)
