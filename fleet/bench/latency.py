"""What ``drona bench coordination`` measures, once its fleet is up: every drone kept busy with mail over
Zenoh, and the latency of each plan made for it read from the drones' states."""

from __future__ import annotations

import asyncio
import contextlib
import math
import random
import subprocess
import sys
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from pathlib import Path

from drona_gcs.stack.protocol import State
from drona_gcs.workspace import Cell, Workspace
from fleet.bench import BenchError
from fleet.bench.processes import check_alive, cpu_seconds, reference_loop_ms, up_or_gone
from fleet.transport.fleet_client import FleetClient, FleetUnavailable
from fleet.transport.identity import SERVICE
from fleet.transport.keys import FleetKeys
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings
from fleet.transport.wire import DroneState, MailOrder, MailStatus, MailStatusReport, WireError, decode

#: How long a drone may take to answer an order: a fleet short of CPU answers late, and is measured so.
ORDER_TIMEOUT_S = 10.0
IDLE_BOUND_S = 90.0  #: how long the drones may take to park at start-up (some detour around the others)
OPENING_S = 1.0  #: the CPU of each agent process is also measured this long from the mail given


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
    #: the host's speed before and after (fleet.bench.processes.reference_loop_ms; lower is faster)
    reference_ms_before: float = math.nan
    reference_ms_after: float = math.nan
    #: the latency of the opening burst's first plan flown (the head of the line's, mostly)
    opening_first_ms: float = math.nan
    #: the CPU each agent process used in the first OPENING_S from the mail given (ms): a process busy all
    #: along bounds the opening burst by its CPU, one mostly idle by waiting
    opening_cpu_ms: tuple[float, ...] = ()
    #: from the opening's mail given to each drone's first plan seen (ms), waits for a task start included
    opening_first_plan_p50_ms: float = math.nan
    opening_last_first_plan_ms: float = math.nan
    fault: tuple[str, ...] = ()  #: what struck the fleet meanwhile, and when (``--fault``)


@dataclass(frozen=True)
class Disturbance:
    """What strikes the fleet once the mail is under way: ``strike`` (it says what it did), the drones that
    may stop answering since, and the processes that may die of it (not counted as a fleet broken)."""

    strike: Callable[[], Coroutine[None, None, list[str]]]
    fallible: frozenset[str]
    processes: tuple[subprocess.Popen[bytes], ...]


async def measure(children: list[subprocess.Popen[bytes]], workspace: Workspace, names: list[str], fleet: str,
                   connect: str, seconds: float, steady_after: float, seed: int,
                   tls_dir: Path | None, disturbance: Disturbance | None = None) -> CoordinationResult:
    """``children``: the vehicles' process first, then the agents'; ``connect``: where the agents are reached."""
    keys = FleetKeys(fleet)
    settings = ZenohSettings(connect=(connect,)).secured(tls_dir, SERVICE, keys, names)
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
        everyone = [*children, *(disturbance.processes if disturbance else ())]
        await up_or_gone(all_up, everyone, 120, "alive on Zenoh")
        # And flying: a drone is alive (and takes mail) as soon as it joined, but its process steps only once
        # all its drones have joined. Mail given before would measure the start-up of the last process
        # (its queries to the fleet) as much as coordination.
        await up_or_gone(all_stepping, everyone, 60, "stepping")
        client = FleetClient(node, keys, "bench")
        # And parked (idle): given its mail at once, the whole fleet then coordinates at once, the worst
        # case of Protocol 1 (each round waits for those before it in line). Their moves to their parking
        # cells at start-up, made while the last process may still be joining, are not counted.
        before = await between_rounds(client, IDLE_BOUND_S, idle=True)
        latencies.count_after(before)
        reference_before = reference_loop_ms()
        cpu0 = [_cpu_of(c.pid) for c in children]
        started = time.monotonic()
        opening = asyncio.create_task(_cpu_after(children, cpu0, OPENING_S))
        struck = asyncio.create_task(disturbance.strike()) if disturbance else None
        fallible = disturbance.fallible if disturbance else frozenset()
        delivered, sent, plans = await _keep_busy(node, client, keys, workspace, names, seconds, seed, before,
                                                  fallible)
        elapsed = time.monotonic() - started
        opening_cpu = await opening
        fault = tuple(await struck) if struck else ()
        reference_after = reference_loop_ms()
        check_alive(children)  # figures from a fleet that lost a process mean nothing
        cpu = _cpu_since(children, cpu0)
    finally:
        await node.close()
    values, steady = latencies.since(), latencies.since(started + steady_after)
    first_plans = sorted(1000 * (seen - started) for seen in latencies.first_seen().values())
    return CoordinationResult(
        len(names), elapsed, len(values), _percentile(values, 0.5), _percentile(values, 0.99), _percentile(values, 1),
        len(steady), _percentile(steady, 0.5), _percentile(steady, 0.99), _percentile(steady, 1),
        sent / plans if plans else float("nan"), 1000 * sum(cpu[1:]) / elapsed / (len(names) - len(fallible)),
        cpu[0] / elapsed,
        delivered, reference_before, reference_after, latencies.first(until=started + steady_after),
        tuple(1000 * c for c in opening_cpu[1:]), _percentile(first_plans, 0.5), _percentile(first_plans, 1), fault)


async def _cpu_after(children: list[subprocess.Popen[bytes]], cpu0: list[float], seconds: float) -> list[float]:
    """The CPU seconds each of ``children`` used in the ``seconds`` after it had used ``cpu0``."""
    await asyncio.sleep(seconds)
    return _cpu_since(children, cpu0)


def _cpu_since(children: list[subprocess.Popen[bytes]], cpu0: list[float]) -> list[float]:
    """The CPU seconds each of ``children`` used since it had used ``cpu0``."""
    return [_cpu_of(c.pid) - c0 for c, c0 in zip(children, cpu0, strict=True)]


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

    def first_seen(self) -> dict[str, float]:
        """When each drone's first plan counted was first seen."""
        seen: dict[str, float] = {}
        for (drone, _), (when, _) in self._seen.items():
            seen[drone] = min(when, seen.get(drone, when))
        return seen

    def first(self, when: float = -math.inf, until: float = math.inf) -> float:
        """The latency (ms) of the plan first seen at ``when`` or later (and before ``until``); NaN if none."""
        seen = [each for each in self._seen.values() if when <= each[0] < until]
        return min(seen)[1] if seen else math.nan


async def _keep_busy(node: ZenohNode, client: FleetClient, keys: FleetKeys, workspace: Workspace, names: list[str],
                     seconds: float, seed: int, before: dict[str, DroneState],
                     fallible: frozenset[str] = frozenset()) -> tuple[int, int, int]:
    """Two mails per drone at first, and one more each time one is delivered, for ``seconds``. Returns
    the mails delivered, and the protocol messages sent and plans made since the states ``before`` (the
    fleet between rounds). A drone ``fallible`` may not answer its mail: it is given none then."""
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
        order = MailOrder(id=f"b{count}", pickup=_list(pickup), dropoff=_list(dropoff), priority=rng.randint(0, 9))
        try:
            await client.assign(drone, order, ORDER_TIMEOUT_S)
        except FleetUnavailable:
            if drone not in fallible:
                raise

    node.subscribe(keys.status(), on_report)
    try:
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
    except* FleetUnavailable as unanswered:  # a fleet too busy to take its mail: said so, not as a traceback
        raise BenchError(str(unanswered.exceptions[0])) from unanswered
    after = await between_rounds(client)
    sent = sum(s.messages_sent - before[d].messages_sent for d, s in after.items() if d in before)
    plans = sum(s.plans - before[d].plans for d, s in after.items() if d in before)
    return delivered, sent, plans


async def between_rounds(client: FleetClient, bound_s: float = 5.0, idle: bool = False) -> dict[str, DroneState]:
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
    """The ``q``-quantile of the sorted ``values`` (0: the least, 1: the most)."""
    if not values:
        return float("nan")
    return values[min(len(values) - 1, int(q * len(values)))] if q < 1 else values[-1]


def _cpu_of(pid: int) -> float:
    """CPU seconds used so far by process ``pid`` (0 where /proc is not there)."""
    return cpu_seconds(pid) or 0.0
