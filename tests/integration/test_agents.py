"""Agents in separate processes, each with its own fake vehicle, over real Zenoh and MAVLink.

Fleets that deliver run on loopback, the agents a Zenoh peer mesh. The fault runs (an agent killed, a
clock off, a vehicle lost; a partition in test_partition.py) put each drone, agent and vehicle, on a host
of its own (a network namespace the test makes), joined through a `drona router` per host.

Judged independently of the agents: collisions from the cells the vehicles'
telemetry put them in (the ``--record`` files, checked under Delta by the
safety checker), deliveries and their order from the status reports, battery
from the published states.
"""

from __future__ import annotations

import asyncio
import json
import random
import signal
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest

from drona_gcs.audit import Audit
from fleet.transport.wire import DroneState, MailAck, MailOrder, MailStatus
from tests.integration.harness import DRONA, FleetProcesses, Observer
from tests.integration.hosts import network_hosts

pytestmark = pytest.mark.slow

SAFE_THRESHOLD = 20.0
MIN_CONFORMANCE = 0.95  #: drona audit's default bound


@pytest.fixture
def hosted_apart(tmp_path: Path) -> Iterator[Callable[..., FleetProcesses]]:
    """``hosted_apart(drones, **options)``: a fleet with each drone on a host of its own, through routers."""
    with ExitStack() as stack:
        def fleet(drones: list[str], **options: object) -> FleetProcesses:
            hosts = stack.enter_context(network_hosts(drones))
            return FleetProcesses(tmp_path, drones, hosts=hosts, host_of={d: d for d in drones}, routers=True,
                                  **options)  # type: ignore[arg-type]
        yield fleet


def random_orders(count: int, seed: int, fleet: FleetProcesses) -> list[MailOrder]:
    rng = random.Random(seed)
    free = [(x, y) for x in range(1, 9) for y in range(1, 9) if not (4 <= x <= 5 and 4 <= y <= 5)]
    orders = []
    for i in range(count):
        pickup, dropoff = rng.sample(free, 2)
        orders.append(MailOrder(id=f"m{i}", pickup=[*pickup, 0], dropoff=[*dropoff, 0], priority=rng.randint(0, 9)))
    return orders


async def deliver_all(fleet: FleetProcesses, orders: list[MailOrder], timeout: float) -> Observer:
    async with Observer(fleet) as obs:
        await obs.until(lambda: obs.alive >= set(fleet.drones), 60, "every agent to join")
        # Each drone gets its share in one burst, so its queue has mail of several priorities.
        for i, order in enumerate(orders):
            await obs.give(order, fleet.drones[i % len(fleet.drones)])
        await obs.until(lambda: obs.delivered([o.id for o in orders]), timeout, "every mail delivered")
        return obs


def check_run(fleet: FleetProcesses, obs: Observer, orders: list[MailOrder]) -> None:
    check_run_record(fleet)
    assert obs.priority_violations({o.id: o for o in orders}) == []
    assert min(obs.min_battery.values()) >= SAFE_THRESHOLD


def check_run_record(fleet: FleetProcesses) -> Audit:
    """Stop the agents (each exits 0) and audit the flight record: safe, no jumps, flown as planned."""
    codes = fleet.stop()
    assert all(code == 0 for code in codes.values()), f"agents exited {codes}\n{fleet.logs()}"
    result = fleet.audit()
    assert set(result.trajectories) == set(fleet.drones)
    assert all(t.end_step - t.start_step > 20 for t in result.trajectories.values())  # the run was recorded
    assert result.safe, _unsafe(result, fleet)
    assert not result.jumps, f"moves of more than a cell per step: {result.jumps[:5]}\n{fleet.logs()}"
    conformance = result.conformance
    assert conformance.planned_steps > 20 and conformance.fraction >= MIN_CONFORMANCE, (
        f"flown in the planned cell: {conformance.fraction:.1%}, worst {conformance.worst}")
    return result


def _unsafe(result: Audit, fleet: FleetProcesses) -> str:
    """What an auditor needs to judge a failure: the violations, the steps with no fix (filled with the cell
    before), the flown cells around each violation, the agents' logs."""
    return (f"collisions in the flown cells: {result.violations[:5]}; steps without a fix: {dict(result.gaps)}\n"
            f"{_around(result)}\n{fleet.logs()}")


def _around(result: Audit) -> str:
    """The flown cells, a few steps either side of each violation, of the drones there."""
    lines = []
    for violation in result.violations[:3]:
        for drone, flown in sorted(result.trajectories.items()):
            if flown.start_step <= violation.step <= flown.end_step and flown.at(violation.step) == violation.cell:
                steps = range(max(flown.start_step, violation.step - 3), min(flown.end_step, violation.step + 2) + 1)
                lines.append(f"{drone} around step {violation.step}: {[flown.at(k) for k in steps]}")
    return "\n".join(lines)


@pytest.mark.parametrize("drones, mails, hosted", [(4, 8, False), (8, 12, False), (4, 8, True)],
                         ids=["4-8", "8-12", "4-8-one-process-shared-session"])
def test_agents_deliver_every_mail_without_collisions(tmp_path: Path, drones: int, mails: int, hosted: bool) -> None:
    fleet = FleetProcesses(tmp_path, [f"d{i + 1}" for i in range(drones)], hosted=hosted)
    orders = random_orders(mails, seed=drones, fleet=fleet)
    fleet.start()
    try:
        obs = asyncio.run(deliver_all(fleet, orders, timeout=150))
        check_run(fleet, obs, orders)
    finally:
        fleet.kill_all()


def test_an_agent_killed_mid_coordination_neither_blocks_the_others_nor_loses_its_mail(
        hosted_apart: Callable[..., FleetProcesses]) -> None:
    fleet = hosted_apart(["d1", "d2", "d3", "d4"])
    doomed = MailOrder(id="doomed", pickup=[2, 6, 0], dropoff=[7, 6, 0], priority=5)
    fleet.start()
    try:
        async def scenario() -> Observer:
            async with Observer(fleet) as obs:
                await obs.until(lambda: obs.alive >= set(fleet.drones), 60, "every agent to join")
                # Idle drones fly to their parking cells first; d3 must be parked before it freezes.
                # (At start-up every drone is landed and waiting too, before its first plan.)
                await obs.until(lambda: len(obs.states) == 4 and all(
                    s.plans >= 1 and s.landed and s.mode == "WaitForTaskRequest" for s in obs.states.values()),
                    60, "all parked")
                fleet.signal("d3", signal.SIGSTOP)  # d3 will not answer: d2's coordination stalls on it
                await obs.give(doomed, "d2")
                await obs.until(lambda: obs.states["d2"].mode == "CoordinateAndGeneratePlan", 5, "d2 coordinating")
                fleet.signal("d2", signal.SIGKILL)  # killed while it waits for d3
                fleet.signal("d3", signal.SIGCONT)
                await obs.until(lambda: "d2" not in obs.alive, 10, "d2's liveliness to go")
                # The operator's command line, as on a real fleet: it follows the mail until delivered.
                mail = await asyncio.create_subprocess_exec(
                    *DRONA, "mail", "--pickup", "8,3,0", "--dropoff", "6,7,0", "--priority", "3", "--drone", "d4",
                    "--id", "after", "--wait", "--timeout", "120", "--fleet", fleet.fleet,
                    "--connect", fleet.endpoint("d1"), "--connect", fleet.endpoint("d4"),
                    stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
                out, err = await asyncio.wait_for(mail.communicate(), 150)
                assert mail.returncode == 0, err.decode()
                lines = [json.loads(line) for line in out.decode().splitlines()]
                assert lines[0]["status"] == "accepted" and lines[-1]["status"] == "delivered"
                await obs.until(lambda: obs.delivered(["doomed", "after"]), 120, "both mails delivered")
                return obs

        obs = asyncio.run(scenario())
        taken_over = [r for r in obs.reports if r.id == "doomed" and r.status is MailStatus.REASSIGNED]
        assert taken_over and taken_over[0].drone != "d2"
        delivered_by = {r.drone for r in obs.reports if r.id == "doomed" and r.status is MailStatus.DELIVERED}
        assert delivered_by == {taken_over[0].drone}
        codes = fleet.stop()
        assert codes["d2"] == -signal.SIGKILL
        assert all(codes[d] == 0 for d in ("d1", "d3", "d4")), f"{codes}\n{fleet.logs()}"
        result = fleet.audit()
        assert result.safe, _unsafe(result, fleet)
    finally:
        fleet.kill_all()


def test_clock_offsets_within_beta_stay_safe(tmp_path: Path) -> None:
    # beta is 0.2 s: every two clocks within it (the fleet's steps differ by up to Delta = 1).
    fleet = FleetProcesses(tmp_path, ["d1", "d2", "d3", "d4"],
                           offsets={"d1": 0.0, "d2": 0.18, "d3": 0.07, "d4": 0.12})
    orders = random_orders(6, seed=11, fleet=fleet)
    fleet.start()
    try:
        obs = asyncio.run(deliver_all(fleet, orders, timeout=150))
        assert all(s.health.ok for s in obs.states.values()), [s.health for s in obs.states.values()]
        check_run(fleet, obs, orders)
    finally:
        fleet.kill_all()


def test_a_clock_offset_beyond_beta_excludes_that_drone_and_the_others_deliver(
        hosted_apart: Callable[..., FleetProcesses]) -> None:
    """Issue 25: one skewed clock stalled the fleet (every drone alarmed, none planned). The drone whose
    clock most peers disagree with holds where its plan ends and takes no mail; the others hold its
    cells for good and deliver; the flight record audits clean."""
    fleet = hosted_apart(["d1", "d2", "d3"], offsets={"d3": 0.6})
    orders = [MailOrder(id="m1", pickup=[2, 2, 0], dropoff=[7, 7, 0], priority=9),
              MailOrder(id="m2", pickup=[6, 2, 0], dropoff=[2, 7, 0], priority=4)]
    fleet.start()
    try:
        async def scenario() -> MailAck:
            async with Observer(fleet) as obs:
                await obs.until(lambda: obs.alive >= set(fleet.drones), 60, "every agent to join")
                # The clock alarm itself, not any alarm: a vehicle lagging on its first flight
                # also makes a drone unhealthy, before the first clock check has run.
                # A verdict needs most of the fleet measured: a check that heard one peer waits for the next.
                await obs.until(lambda: len(obs.states) == 3 and "mine is off" in _alarms(obs, "d3") and all(
                    "d3 out of the fleet's bound" in _alarms(obs, d) for d in ("d1", "d2")), 30, "the clock verdicts")
                refused = await obs.client.assign("d3", MailOrder(id="m3", pickup=[3, 3, 0], dropoff=[6, 6, 0],
                                                                  priority=1))
                await obs.give(orders[0], "d1")
                await obs.give(orders[1], "d2")
                await obs.until(lambda: obs.delivered(["m1", "m2"]), 120, "d1 and d2 to deliver")
                return refused

        refused = asyncio.run(scenario())
        assert not refused.accepted and "clock" in refused.reason
        check_run_record(fleet)
    finally:
        fleet.kill_all()


def _alarms(obs: Observer, drone: str) -> str:
    return " ".join(obs.states[drone].health.alarms) if drone in obs.states else ""


def test_a_vehicle_killed_in_flight_is_one_drones_problem(hosted_apart: Callable[..., FleetProcesses]) -> None:
    """d2's vehicle (its own `drona sim-vehicle` process) is killed while d2 flies to a pickup: d2's agent
    stays up and a member, raises vehicle_lost and hands its mail back, which its heir d1 takes over (no
    service runs to reassign it); the other drones deliver theirs;
    every agent leaves cleanly; the flight record audits clean (d2's lost steps are gaps, not cells)."""
    fleet = hosted_apart(["d1", "d2", "d3", "d4"])
    # d2 parks at (0, 4): its leg to (3, 3) and the cells held for it while lost stay west of the others'.
    doomed = MailOrder(id="doomed", pickup=[3, 3, 0], dropoff=[3, 8, 0], priority=5)
    others = [MailOrder(id=f"m{i}", pickup=[*a, 0], dropoff=[*b, 0], priority=p) for i, (a, b, p) in
              enumerate([((6, 2), (8, 7), 5), ((7, 8), (6, 1), 3), ((8, 3), (7, 6), 7), ((9, 6), (6, 7), 1)])]
    fleet.start()
    try:
        async def scenario() -> Observer:
            async with Observer(fleet) as obs:
                await obs.until(lambda: obs.alive >= set(fleet.drones), 60, "every agent to join")
                await obs.until(lambda: len(obs.states) == 4 and all(
                    s.plans >= 1 and s.landed and s.mode == "WaitForTaskRequest" for s in obs.states.values()),
                    60, "all parked")
                await obs.give(doomed, "d2")
                await obs.until(lambda: _in_flight_to_pickup(obs.states.get("d2")), 60, "d2 in flight")
                fleet.sims["d2"].kill()
                for i, order in enumerate(others):
                    await obs.give(order, ["d1", "d3", "d4"][i % 3])
                await obs.until(lambda: any(a.startswith("vehicle_lost") for a in obs.states["d2"].health.alarms),
                                10, "d2's vehicle_lost alarm")
                await obs.until(lambda: MailStatus.HANDED_BACK in obs.statuses("doomed"), 10, "d2 to hand back")
                await obs.until(lambda: MailStatus.REASSIGNED in obs.statuses("doomed"), 10, "d1 to take it over")
                await obs.until(lambda: obs.delivered([o.id for o in others]), 150, "the others' mail delivered")
                assert "d2" in obs.alive and fleet.agents["d2"].poll() is None
                return obs

        asyncio.run(scenario())
        codes = fleet.stop()
        assert all(code == 0 for code in codes.values()), f"agents exited {codes}\n{fleet.logs()}"
        result = fleet.audit()
        assert result.safe, _unsafe(result, fleet)
        assert not result.jumps, f"{result.jumps[:5]}\n{fleet.logs()}"
        ends = {drone: t.end_step for drone, t in result.trajectories.items()}
        assert ends["d2"] < min(ends[d] for d in ("d1", "d3", "d4")) - 10, ends  # never recorded once lost
        assert result.conformance.fraction >= MIN_CONFORMANCE, str(result.conformance.worst)
    finally:
        fleet.kill_all()


def _in_flight_to_pickup(state: DroneState | None) -> bool:
    vehicle = None if state is None else state.vehicle
    return state is not None and state.phase == "to_pickup" and vehicle is not None and vehicle.landed == "in_air"
