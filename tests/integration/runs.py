"""What the runs of agents over real processes share: mail to give, delivering it all, and judging the run
from the flight record (safe, no jumps, flown as planned) and the drones' reports."""

from __future__ import annotations

import random

from drona_gcs.audit import Audit
from fleet.transport.wire import MailOrder
from tests.integration.harness import FleetProcesses, Observer

SAFE_THRESHOLD = 20.0
MIN_CONFORMANCE = 0.95  #: drona audit's default bound


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
        await obs.joined()
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
    assert result.safe, unsafe(result, fleet)
    assert not result.jumps, f"moves of more than a cell per step: {result.jumps[:5]}\n{fleet.logs()}"
    conformance = result.conformance
    assert conformance.planned_steps > 20 and conformance.fraction >= MIN_CONFORMANCE, (
        f"flown in the planned cell: {conformance.fraction:.1%}, worst {conformance.worst}")
    check_truth(fleet)
    return result


def check_truth(fleet: FleetProcesses) -> None:
    """The simulators' own records (where the vehicles were, not what the agents saw): no two vehicles
    in one cell within a step, none crossing cells unseen."""
    truth = fleet.truth_audit()
    assert set(truth.trajectories) == set(fleet.drones), sorted(truth.trajectories)
    assert truth.safe, f"the simulators' records: {truth.violations[:5]}\n{fleet.logs()}"
    assert not truth.jumps, f"the simulators' records: {truth.jumps[:5]}"


def unsafe(result: Audit, fleet: FleetProcesses) -> str:
    """What an auditor needs to judge a failure: the violations, the steps with no fix (filled with the cell
    before), the flown cells around each violation, the agents' logs."""
    return (f"collisions in the flown cells: {result.violations[:5]}; steps without a fix: {dict(result.gaps)}\n"
            f"{around(result)}\n{fleet.logs()}")


def around(result: Audit) -> str:
    """The flown cells, a few steps either side of each violation, of the drones there."""
    lines = []
    for violation in result.violations[:3]:
        for drone, flown in sorted(result.trajectories.items()):
            if flown.start_step <= violation.step <= flown.end_step and flown.at(violation.step) == violation.cell:
                steps = range(max(flown.start_step, violation.step - 3), min(flown.end_step, violation.step + 2) + 1)
                lines.append(f"{drone} around step {violation.step}: {[flown.at(k) for k in steps]}")
    return "\n".join(lines)
