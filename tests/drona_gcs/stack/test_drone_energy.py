"""One drone's whole stack, energy with a peer: the tests drain the battery as the systematic
tester's world does (or, with the lead steps, as the agent flies its vehicle), and give the drone
a peer whose answers the test's network may hold back.
"""

from __future__ import annotations

import random
from collections.abc import Callable

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.drone import DroneAction, DroneStack, StackConfig
from drona_gcs.stack.mail import (
    GoTo,
    MailDelivered,
    MailRequest,
    Phase,
)
from drona_gcs.stack.messages import Message
from drona_gcs.stack.protocol import (
    State,
    Threatened,
)
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.stack.drone_helpers import fly, ideal, route


def pair(cells: list[Cell]) -> tuple[Cell, Cell]:
    """The two cells of ``rng.sample(cells, 2)``, as a pair."""
    first, second = cells
    return first, second


# ------------------------------------------------------------ energy, with a peer
#: (step, battery, landed, mail phase) of d1 at each step
Seen = tuple[int, float, bool, Phase]
CHARGED = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 2, 0), "d2": (5, 3, 0)},
                          charging_stations=((0, 0, 0), (5, 0, 0)), parking=((0, 5, 0), (5, 5, 0)))


def fleet_of_two(ws: Workspace, mail: MailRequest, level: float, steps: int,
                 held: Callable[[DroneStack, int], bool]) -> list[Seen]:
    """d1 and d2 on ``ws``, d1 with ``mail`` and ``level`` % of battery; the network delivers every
    message at once, except while ``held(d1, step)``. The world drains a flying or hovering drone's
    battery 1 % a step and charges one charging on a charger, as the systematic tester's does."""
    config = StackConfig(ws, SafePlanner(ws))
    stacks = {d: DroneStack(d, config, dict(ws.drones)) for d in ws.drones}
    levels = dict.fromkeys(ws.drones, 100.0) | {"d1": level}
    stacks["d1"].assign(mail)
    inbox: list[tuple[str, Message]] = []
    seen: list[Seen] = []

    def post(sender: str, actions: list[DroneAction]) -> None:
        route(stacks, inbox, sender, actions)

    for step in range(steps):
        for drone, stack in stacks.items():
            if stack.mail.phase is Phase.CHARGING and stack.executor.cell in ws.charging_stations:
                levels[drone] = min(100.0, levels[drone] + config.battery.charge_per_step)
            elif not stack.landed:
                levels[drone] -= config.battery.drain_per_step
            post(drone, stack.step(step, max(levels[drone], 0.0), stack.executor.cell))
        while inbox and not held(stacks["d1"], step):
            to, message = inbox.pop(0)
            post(to, stacks[to].receive(message))
        d1 = stacks["d1"]
        seen.append((step, levels["d1"], d1.landed, d1.mail.phase))
    return seen


def test_a_drone_hovering_in_a_round_that_never_ends_lands_before_its_battery_runs_low() -> None:
    """Found by the systematic tester (seed 1 of 4 drones, 6 mails, Delta 1): a drone that had just
    delivered hovered in a round a protocol deadlock never let end, 59 steps, until its battery
    fell to 19 %. Its leg's budget counted the hovering, but only at planning, which never came."""
    mail = MailRequest("m1", pickup=(2, 2, 0), dropoff=(3, 2, 0), priority=5)
    # once d1 has the mail on board, the drop-off leg's round hangs
    seen = fleet_of_two(CHARGED, mail, 60.0, 120, held=lambda d1, step: d1.mail.carrying)
    assert min(level for _, level, _, _ in seen) >= BatteryModel().safe_threshold
    assert sum(not landed for _, _, landed, _ in seen[10:]) > 10  # it hovered in the round a while
    assert seen[-1][2]  # then landed, to wait for free


def late_after_pickup(late: int) -> Callable[[DroneStack, int], bool]:
    """Every message held for ``late`` steps from when d1 has its mail on board: the drop-off
    leg's round ends that late."""
    picked: list[int] = []

    def held(d1: DroneStack, step: int) -> bool:
        if d1.mail.carrying and not picked:
            picked.append(step)
        return bool(picked) and step < picked[0] + late

    return held


#: Its chargers are as far as each other from (3, 3): 6 steps.
EVEN = Workspace.build(size=(7, 7, 1), drones={"d1": (2, 6, 0), "d2": (6, 4, 0)},
                       charging_stations=((0, 0, 0), (6, 0, 0)), parking=((0, 6, 0), (6, 6, 0)))


def test_a_drone_hovering_in_a_round_that_ends_late_arrives_with_the_way_to_a_charger() -> None:
    """Found by the systematic tester (seed 5 of 4 drones, 8 mails, Delta 2): a leg's plan took its
    whole budget, and the step held in the start cell, not counted, took the last step of the way to
    a charger; with both chargers as far, the drone stayed on the ground for good, its mail waiting."""
    mail = MailRequest("m1", pickup=(3, 5, 0), dropoff=(3, 3, 0), priority=5)
    for late in range(30):
        seen = fleet_of_two(EVEN, mail, 50.0, 150, late_after_pickup(late))
        assert min(level for _, level, _, _ in seen) >= BatteryModel().safe_threshold, late
        # low after the mail, it charges (before the mail it had enough)
        assert any(phase is Phase.CHARGING for _, _, _, phase in seen), f"{late} steps late: stranded"


#: The shortest way from the east to the charger (0, 0) is through d2's parking cell (1, 0); the
#: way around, by (2, 1) and (0, 1), is 4 steps longer.
WALLED = Workspace.build(size=(7, 3, 1), obstacles=frozenset({(1, 1, 0), (3, 1, 0), (4, 1, 0), (5, 1, 0)}),
                         drones={"d1": (6, 2, 0), "d2": (1, 0, 0)}, charging_stations=((0, 0, 0),),
                         parking=((6, 2, 0), (1, 0, 0)))


def test_the_way_to_a_charger_kept_in_the_battery_goes_around_the_drones_parked_on_it() -> None:
    """Found by the systematic tester (seed 2 of 5 drones, 5 mails, Delta 1): the energy rules kept
    the way to a charger through a parking cell, where a drone rested; low after its mail, the drone
    could afford no plan around it and waited on the ground for good (126 rounds, no plan)."""
    mail = MailRequest("m1", pickup=(6, 1, 0), dropoff=(5, 0, 0), priority=5)
    for late in range(30):
        seen = fleet_of_two(WALLED, mail, 45.0, 200, late_after_pickup(late))
        assert min(level for _, level, _, _ in seen) >= BatteryModel().safe_threshold, late
        charged = any(phase is Phase.CHARGING for _, _, _, phase in seen)
        assert charged or seen[-1][1] >= StackConfig(WALLED, SafePlanner(WALLED)).low_mark, \
            f"{late} steps late: stranded at {seen[-1][1]} %"


OPEN = Workspace.build(size=(8, 8, 1), drones={"d1": (3, 3, 0)}, charging_stations=((0, 0, 0), (7, 0, 0)),
                       parking=((0, 7, 0),))


def test_a_drone_in_the_air_from_its_plan_on_keeps_its_battery_above_the_floor() -> None:
    """A vehicle takes off once its plan is made, to climb during the lead steps (the agent wants
    it airborne while the protocol executes), and hovers at a goal until seen there. Budgets that
    took those steps as free (Delta 2: three lead steps a leg) let the battery fall to 18 %."""
    planner = SafePlanner(OPEN, 2)
    free = [c for c in OPEN.free_cells if c not in OPEN.charging_stations and c not in OPEN.parking]
    model = BatteryModel()
    for seed in range(40):
        rng = random.Random(seed)
        stack = DroneStack("d1", StackConfig(OPEN, planner), dict(OPEN.drones))
        mails = [MailRequest(f"m{i}", *pair(rng.sample(free, 2)), rng.randint(0, 9), i) for i in range(6)]
        for m in mails:
            stack.assign(m)
        level, delivered = float(rng.randint(35, 60)), []
        for step in range(500):
            airborne = not stack.landed or stack.protocol.state is State.EXECUTING
            if airborne:
                level -= model.drain_per_step
            elif stack.mail.phase is Phase.CHARGING and stack.executor.cell in OPEN.charging_stations:
                level = min(100.0, level + model.charge_per_step)
            assert level >= model.safe_threshold, f"seed {seed}: {level} % at step {step}"
            actions = stack.step(step, level, stack.executor.cell)
            delivered += [a.request for a in actions if isinstance(a, MailDelivered)]
        assert sorted(m.id for m in delivered) == sorted(m.id for m in mails), f"seed {seed}"


def test_a_plan_made_anew_in_flight_is_budgeted_as_a_leg_from_the_air_is() -> None:
    """Found by the systematic tester (sweep 20171 with --skews 1): a low drone's way to a charger was
    planned anew around a cell a drone whose clock was off held. The new rest was budgeted with its first
    step free, as no leg from the air is (see DroneStack._task), and the battery fell to 19 %."""
    stack, _ = fly(ideal, 8, workspace=OPEN)
    assert stack.protocol.state is State.EXECUTING and not stack.landed
    plan = stack.protocol.trajectory
    assert plan is not None
    level = 60.0
    stack.level = level
    rest = stack._reroute_task(Threatened("x", (plan.cells[-2],)))
    leg = GoTo(rest.goal, stack.mail.flight_to(rest.goal, level), Phase.TO_PICKUP)
    assert rest.flight_steps is not None
    assert rest.flight_steps == stack._task(leg, stack.now, stack.now).flight_steps
