"""Agents in separate processes, each drone on a host of its own (a network namespace the test makes),
joined through a `drona router` per host: a clock off within and beyond beta, a vehicle killed in
flight. (Fleets that deliver, and an agent killed: test_agents.py; a partition: test_partition.py.)

Judged independently of the agents, as in test_agents.py: the flight record audited, deliveries and their
order from the status reports, battery from the published states.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import pytest

from fleet.transport.wire import DroneState, MailAck, MailOrder, MailStatus
from tests.integration.harness import FleetProcesses, Observer
from tests.integration.runs import (
    MIN_CONFORMANCE,
    check_run,
    check_run_record,
    check_truth,
    deliver_all,
    random_orders,
    unsafe,
)

pytestmark = pytest.mark.slow


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
                await obs.joined()
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
                await obs.parked()
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
        assert result.safe, unsafe(result, fleet)
        assert not result.jumps, f"{result.jumps[:5]}\n{fleet.logs()}"
        ends = {drone: t.end_step for drone, t in result.trajectories.items()}
        assert ends["d2"] < min(ends[d] for d in ("d1", "d3", "d4")) - 10, ends  # never recorded once lost
        assert result.conformance.fraction >= MIN_CONFORMANCE, str(result.conformance.worst)
        check_truth(fleet)
    finally:
        fleet.kill_all()


def _in_flight_to_pickup(state: DroneState | None) -> bool:
    vehicle = None if state is None else state.vehicle
    return state is not None and state.phase == "to_pickup" and vehicle is not None and vehicle.landed == "in_air"
