"""One drone's whole stack (:class:`~drona_gcs.stack.drone.DroneStack`), driven step by step with the cell
telemetry puts its vehicle in: what it reports must be what the vehicle did, not what the plan said.

A lone drone on an open grid (no peers, so each task plans at once) takes one mail; the test plays
its vehicle, ideal or not. The energy tests drain the battery as the systematic tester's world does
(or, with the lead steps, as the agent flies its vehicle), and give the drone a peer whose answers
the test's network may hold back.
"""

from __future__ import annotations

import dataclasses
import random
from collections.abc import Callable, Mapping
from typing import TypeVar

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.drone import DroneAction, DroneStack, LegNotFlown, StackConfig, yield_spot
from drona_gcs.stack.mail import (
    DRAINED,
    MAX_MISSES,
    GoTo,
    MailDelivered,
    MailPickedUp,
    MailRejected,
    MailRequest,
    Phase,
)
from drona_gcs.stack.messages import CurrentTraj, Message, PlanAck, PlanProposal, ReqForCurrentTraj, Task, TaskId
from drona_gcs.stack.protocol import (
    Braked,
    Broadcast,
    CoordinationProtocol,
    Grounded,
    NewTask,
    Reroute,
    Send,
    StartExecuting,
    State,
    Threatened,
)
from drona_gcs.workspace import Cell, Workspace

WS = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 0, 0)})
MAIL = MailRequest("m1", pickup=(3, 0, 0), dropoff=(3, 3, 0), priority=5)
#: How the test's vehicle flies: from the stack and the step, the cell telemetry puts it in (None: none).
Vehicle = Callable[[DroneStack, int], Cell | None]
A = TypeVar("A")


def ideal(stack: DroneStack, step: int) -> Cell | None:
    """Where the last step took it: the executor's cell before the boundary."""
    return stack.executor.cell


def stuck_at_start(stack: DroneStack, step: int) -> Cell | None:
    """Never left its start (a take-off that never happened): seen in its start cell."""
    return (0, 0, 0)


def fly(vehicle: Vehicle, steps: int, stack: DroneStack | None = None,
        workspace: Workspace = WS) -> tuple[DroneStack, list[DroneAction]]:
    stack = stack or DroneStack("d1", StackConfig(workspace, SafePlanner(workspace)), dict(workspace.drones))
    if not stack.mail.queue and stack.mail.current is None:
        stack.assign(MAIL)
    actions: list[DroneAction] = []
    for step in range(stack.executor.step + 1, stack.executor.step + 1 + steps):
        actions += stack.step(step, 100.0, vehicle(stack, step))
    return stack, actions


def of(kind: type[A], actions: list[DroneAction]) -> list[A]:
    return [a for a in actions if isinstance(a, kind)]


def state_of(protocol: CoordinationProtocol) -> State:
    """The protocol's state now: read anew after an action (mypy keeps the state an earlier check found)."""
    return protocol.state


def in_touch(stack: DroneStack) -> bool:
    """Whether the drone is in touch with most of the fleet now (read anew, as :func:`state_of`)."""
    return stack.in_touch


def pair(cells: list[Cell]) -> tuple[Cell, Cell]:
    """The two cells of ``rng.sample(cells, 2)``, as a pair."""
    first, second = cells
    return first, second


def test_an_ideal_vehicle_picks_up_and_delivers_once_seen_at_each_cell() -> None:
    _, actions = fly(ideal, 40)
    assert of(MailPickedUp, actions) == [MailPickedUp(MAIL)] and of(MailDelivered, actions) == [MailDelivered(MAIL)]
    assert of(LegNotFlown, actions) == []


def test_a_vehicle_that_never_flew_picks_nothing_up_and_the_mail_is_handed_back() -> None:
    """The plan to the pickup ends, yet telemetry still puts the vehicle at its start: no pickup is
    reported. Each plan that ends so is a leg not flown; after MAX_MISSES the mail goes back."""
    _, actions = fly(stuck_at_start, 80)
    assert of(MailPickedUp, actions) == [] and of(MailDelivered, actions) == []
    missed = of(LegNotFlown, actions)
    assert missed[:MAX_MISSES] == [LegNotFlown(MAIL.pickup, (0, 0, 0))] * MAX_MISSES
    assert of(MailRejected, actions)[0].request == MAIL
    assert "never reached the pickup" in of(MailRejected, actions)[0].reason


@pytest.mark.parametrize("steps_late", [1, 2, 3])
def test_a_vehicle_late_within_lambda_still_picks_up_when_it_gets_there(steps_late: int) -> None:
    """Seen at each cell some boundaries after the plan put it there, within lambda (at tau 0.25 s
    a 1 m cell's default lambda, 1.88 s, is 8 steps): the mail is picked up and delivered, each when
    the vehicle is seen at the cell."""
    trail: list[Cell] = []

    def late(stack: DroneStack, step: int) -> Cell | None:
        trail.append(stack.executor.cell)
        return trail[max(0, len(trail) - 1 - steps_late)]

    _, actions = fly(late, 80, workspace=dataclasses.replace(WS, tau_s=0.25))
    assert of(MailPickedUp, actions) == [MailPickedUp(MAIL)] and of(MailDelivered, actions) == [MailDelivered(MAIL)]
    assert of(LegNotFlown, actions) == []


def test_a_lost_vehicle_plans_nothing_and_back_in_a_held_cell_the_drone_rests_there() -> None:
    stack, _ = fly(ideal, 3)  # under way to the pickup
    assert stack.protocol.state is State.EXECUTING and not stack.mail.carrying
    trajectory = stack.protocol.trajectory
    assert trajectory is not None
    seen = stack.executor.cell
    handed = stack.vehicle_lost(stack.now, seen, "its vehicle is lost")
    assert of(MailRejected, handed) == [MailRejected(MAIL, "its vehicle is lost", True)]  # another drone may fly it
    assert set(stack.protocol.holds()) >= {seen, *trajectory.suffix_from(stack.now).cells}
    stack, actions = fly(lambda s, k: None, 30, stack)  # nothing seen while lost: nothing reported
    assert of(MailPickedUp, actions) == []
    assert stack.protocol.state is State.WAIT_FOR_TASK  # the plan ran out; no new one while lost
    stack.vehicle_back((2, 0, 0), landed=False)
    assert (stack.executor.cell, stack.protocol.location, stack.protocol.holds()) == ((2, 0, 0), (2, 0, 0), ())
    stack, actions = fly(ideal, 40, stack)  # given the mail again, it flies it from there
    assert of(MailDelivered, actions) == [MailDelivered(MAIL)]


# ------------------------------------------------------------ energy, with a peer
#: (step, battery, landed, mail phase) of d1 at each step
Seen = tuple[int, float, bool, Phase]
CHARGED = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 2, 0), "d2": (5, 3, 0)},
                          charging_stations=((0, 0, 0), (5, 0, 0)), parking=((0, 5, 0), (5, 5, 0)))


def route(stacks: Mapping[str, DroneStack], inbox: list[tuple[str, Message]], sender: str,
          actions: list[DroneAction]) -> None:
    """Put ``sender``'s messages in ``inbox``, as (receiver, message), in the order sent."""
    for action in actions:
        if isinstance(action, Send):
            inbox.append((action.to, action.message))
        elif isinstance(action, Broadcast):
            inbox.extend((d, action.message) for d in stacks if d != sender)


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


# ------------------------------------------------------------ making way
#: A ring around a wall: from the pickup (2, 0) to the drop-off (3, 2), the way is by (0, 1) or
#: by (6, 1). A vehicle down rests on one, a drone parks on the other: together they wall it off.
RING_MAIL = MailRequest("m1", pickup=(2, 0, 0), dropoff=(3, 2, 0), priority=5)


def ring(parked_at: Cell) -> Workspace:
    return Workspace.build(size=(7, 3, 1), obstacles=frozenset((x, 1, 0) for x in range(1, 6)),
                           drones={"d1": (2, 0, 0), "d2": (0, 1, 0), "d3": (6, 1, 0)},
                           parking=(parked_at,))


def fleet_on_the_ring(ws: Workspace, down: str, steps: int) -> dict[str, list[DroneAction]]:
    """d1 carries RING_MAIL; ``down``'s vehicle came down where it started; every message arrives at once."""
    config = StackConfig(ws, SafePlanner(ws))
    stacks = {d: DroneStack(d, config, dict(ws.drones)) for d in ws.drones}
    early = stacks[down].vehicle_down("a failsafe", ws.drones[down])
    stacks["d1"].assign(RING_MAIL)
    done: dict[str, list[DroneAction]] = {d: [] for d in stacks}
    inbox: list[tuple[str, Message]] = []
    for peer in set(stacks) - {down}:  # its announcement that it stays there for good
        done[peer] += stacks[peer].peer_down(down, ws.drones[down])
    done[down] += early

    def post(sender: str, actions: list[DroneAction]) -> None:
        done[sender] += actions
        route(stacks, inbox, sender, actions)

    for step in range(steps):
        for drone, stack in stacks.items():
            post(drone, stack.step(step, 100.0, stack.executor.cell, may_plan=drone != down))
        while inbox:
            to, message = inbox.pop(0)
            post(to, stacks[to].receive(message))
    return done


@pytest.mark.parametrize("down", ["d2", "d3"])
def test_a_drone_parked_on_the_only_way_makes_way_for_mail_on_board(down: str) -> None:
    """The paper leaves MRMP incomplete: drones resting for good can wall a goal off. Found by the
    systematic tester: a vehicle down and a parked drone walled a drop-off off, and the mail on
    board waited for good. The drone whose leg found no plan asks those resting on a way to leave it
    (first the shortest; then around cells that stayed taken, as a vehicle down does)."""
    parked = "d3" if down == "d2" else "d2"
    ws = ring(parked_at=(6, 1, 0) if parked == "d3" else (0, 1, 0))
    done = fleet_on_the_ring(ws, down, 120)
    assert of(MailDelivered, done["d1"]) == [MailDelivered(RING_MAIL)]
    moves = [a for a in done[parked] if isinstance(a, GoTo)]
    assert moves[0].purpose is Phase.MAKING_WAY and moves[0].goal != ws.drones[parked]
    assert moves[-1].purpose is Phase.TO_PARKING  # and home again afterwards


def test_a_goal_that_found_no_plan_asks_its_way_clear_after_legs_elsewhere() -> None:
    """Found by a random sweep (seed 921887): a charger walled in by resting drones found no plan; a
    leg to a parking cell came between, and the next try at the charger no longer asked its way
    clear (only the last leg's goal was remembered). The drone went between charger and parking
    for good, and the mail it held waited."""
    ws = Workspace.build(size=(4, 2, 1), obstacles=frozenset({(0, 1, 0), (1, 1, 0)}),
                         charging_stations=((0, 0, 0),), parking=((3, 1, 0),),
                         drones={"d1": (3, 0, 0), "d2": (1, 0, 0)})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.peer_left("d2")  # at rest on the only way to the charger
    charger, parking = GoTo((0, 0, 0), None, Phase.TO_CHARGER), GoTo((3, 1, 0), None, Phase.TO_PARKING)
    assert stack._way_to_clear(charger) == ()  # a first try asks nothing
    stack._protocol(NewTask(stack._task(charger, 0, 0)))
    assert stack.protocol.state is State.WAIT_FOR_TASK  # cut off: no plan
    flown = stack._protocol(NewTask(stack._task(parking, 1, 1)))
    assert any(isinstance(a, StartExecuting) for a in flown)
    assert (1, 0, 0) in stack._way_to_clear(charger)


def test_a_drone_boxed_in_on_a_way_makes_way_to_a_charger_when_nothing_else_is_left() -> None:
    """Found by the 60 s sweep: boxed in by a parked drone and a vehicle down, a drone asked to make
    way found no cell but a charger, stayed, and the mail behind it waited for good."""
    corridor = Workspace.build(size=(4, 1, 1), charging_stations=((0, 0, 0),), drones={"d1": (1, 0, 0)})
    way = frozenset({(1, 0, 0), (2, 0, 0), (3, 0, 0)})  # where it rests is on the way
    assert yield_spot(corridor, (1, 0, 0), way, ()) == (0, 0, 0)
    assert yield_spot(corridor, (1, 0, 0), way | {(0, 0, 0)}, ()) is None
    wide = Workspace.build(size=(4, 2, 1), charging_stations=((0, 0, 0),), drones={"d1": (1, 0, 0)})
    assert yield_spot(wide, (1, 0, 0), way, ()) == (1, 1, 0)  # a free cell first, though farther


# ------------------------------------------------------------------ operator's commands
def test_a_paused_drone_starts_no_mail_and_takes_it_up_again_when_resumed() -> None:
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    stack.command("pause", "pause by ops")
    _, actions = fly(ideal, 30, stack)
    assert of(MailPickedUp, actions) == [] and stack.mail.queue == [MAIL] and stack.commanded == "pause"
    stack.command("resume", "resume by ops")
    _, actions = fly(ideal, 40, stack)
    assert of(MailDelivered, actions) == [MailDelivered(MAIL)] and stack.commanded is None


def test_a_paused_drone_still_delivers_the_mail_on_board() -> None:
    stack, actions = fly(ideal, 1)
    for _ in range(60):
        actions += stack.step(stack.executor.step + 1, 100.0, stack.executor.cell)
        if of(MailPickedUp, actions) and stack.commanded is None:
            stack.command("pause", "pause by ops")
    assert stack.commanded == "pause" and of(MailDelivered, actions) == [MailDelivered(MAIL)]


def test_a_recalled_drone_hands_back_the_mail_not_on_board() -> None:
    stack, _ = fly(ideal, 2)  # planning its way to the pickup
    handed = stack.command("recall", "recall by ops")
    assert [(a.request, a.reason) for a in of(MailRejected, handed)] == [(MAIL, "recall by ops")]
    _, actions = fly(ideal, 40, stack)
    assert of(MailPickedUp, actions) == [] and stack.mail.current is None


def test_a_drone_landed_by_the_operator_mid_flight_stops_through_a_round_and_stays() -> None:
    """Flying a plan, it plans its rest anew (a Reroute: a round every peer answers) to stay at the
    cell its plan reaches once a new plan may start, then holds there: no leg at all until resumed."""
    far = MailRequest("far", pickup=(5, 5, 0), dropoff=(0, 5, 0), priority=5)
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    stack.assign(far)
    actions: list[DroneAction] = []

    def boundary() -> None:
        actions.extend(stack.step(stack.executor.step + 1, 100.0, stack.executor.cell))

    while stack.protocol.state is not State.EXECUTING:
        boundary()
    for _ in range(3):  # a few cells along
        boundary()
    plan = stack.protocol.trajectory
    assert plan is not None
    stop = plan.at(stack.now + stack.protocol.lead_steps)
    landed = stack.command("land", "land by ops")
    assert [a.request for a in of(MailRejected, landed)] == [far]
    assert stack.protocol.trajectory is not None and stack.protocol.trajectory.last == stop  # alone: planned at once
    for _ in range(40):
        boundary()
    assert stack.executor.cell == stop != plan.last and stack.landed
    assert state_of(stack.protocol) is State.WAIT_FOR_TASK and not of(GoTo, actions[-40:])


def test_a_drone_that_brakes_short_of_a_vehicle_down_decides_its_leg_anew_from_there() -> None:
    """The plan to the pickup is cut short of a vehicle down in its way: where it holds is no pickup,
    and the leg is flown again from there, around the vehicle down."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 0, 0), "d2": (5, 5, 0)})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.assign(MAIL)
    down: Cell | None = None
    actions: list[DroneAction] = []
    for step in range(60):
        out = stack.step(step, 100.0, stack.executor.cell)
        if down is None and stack.executor.cell == (1, 0, 0):
            down = (2, 0, 0)
            out += stack.peer_down("d2", down)
        asks = [a.message for a in out if isinstance(a, Broadcast) and isinstance(a.message, ReqForCurrentTraj)]
        for ask in asks:
            where = Trajectory.stationary(down or ws.drones["d2"], step)
            out += stack.receive(CurrentTraj("d2", where, ask.task_id))
        for proposal in [a.message for a in out if isinstance(a, Broadcast) and isinstance(a.message, PlanProposal)]:
            out += stack.receive(PlanAck("d2", proposal.task_id, Trajectory.stationary(down or ws.drones["d2"], step)))
        actions += out
        assert stack.executor.cell != (2, 0, 0)
        assert not of(MailPickedUp, out) or stack.executor.cell == MAIL.pickup
    braked = of(Braked, actions)
    assert len(braked) == 1 and braked[0].trajectory.last == (1, 0, 0)
    assert of(MailPickedUp, actions) == [MailPickedUp(MAIL)] and of(MailDelivered, actions) == [MailDelivered(MAIL)]


def test_a_drone_cut_off_from_most_of_the_fleet_hands_back_its_mail_not_on_board_once() -> None:
    """Issue 25: under a partition the other side takes a gone drone's mail over; the drone cut off must
    not fly it too (two owners). Out of touch with a majority, it hands back what is not on board."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 0, 0), "d2": (5, 5, 0), "d3": (0, 5, 0)})
    stack = DroneStack("d3", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.assign(MAIL)
    stack.step(0, 100.0, (0, 5, 0))
    stack.peer_left("d1")
    stack.step(1, 100.0, (0, 5, 0))
    assert stack.in_touch  # 2 of 3: still a majority
    stack.peer_left("d2")
    handed = stack.step(2, 100.0, (0, 5, 0))
    assert of(MailRejected, handed) == [MailRejected(MAIL, "cut off from most of the fleet", True)]
    assert not in_touch(stack) and stack.mail.queue == [] and stack.mail.current is None
    assert of(MailRejected, stack.step(3, 100.0, (0, 5, 0))) == []  # once


def test_news_while_confirming_a_reroute_that_threatens_again_reroutes_once() -> None:
    """Found in review: a peer leaving while a rerouted rest waited for its acks dropped it (RerouteFailed:
    stop short instead, a reroute) and threatened the plan flown again (a second reroute): refused."""
    ws = Workspace.build(size=(5, 5, 1), drones={"a": (0, 0, 0), "b": (0, 4, 0), "c": (4, 2, 0)})
    stack = DroneStack("a", StackConfig(ws, SafePlanner(ws, 0)), dict(ws.drones))
    flown = Trajectory(0, ((0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0), (4, 1, 0), (4, 2, 0), (4, 3, 0)))
    protocol = stack.protocol
    protocol.task, protocol.trajectory = Task(TaskId(1, "a", 1), (4, 3, 0)), flown
    protocol._state = State.EXECUTING  # placed flying ``flown``, which no round of this fleet would plan
    stack.executor.start(flown)
    stack._protocol(Reroute(stack._reroute_task(Threatened("x", ((4, 1, 0),)))))
    assert protocol.task is not None
    task = protocol.task.id
    stack.receive(CurrentTraj("b", Trajectory.stationary((0, 4, 0), 0), task))
    stack.receive(CurrentTraj("c", Trajectory.stationary((4, 2, 0), 0), task))
    assert protocol.state is State.CONFIRMING
    actions = stack.peer_left("c")  # c may hold (4, 2) for good: on the plan flown
    assert state_of(protocol) is State.REROUTING and len([a for a in actions if isinstance(a, Threatened)]) == 1


def test_a_drone_starting_up_before_it_meets_its_peers_hands_back_nothing() -> None:
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 0, 0), "d2": (5, 5, 0), "d3": (0, 5, 0)})
    stack = DroneStack("d3", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.peer_left("d1")
    stack.peer_left("d2")  # not running yet
    stack.assign(MAIL)
    assert of(MailRejected, stack.step(0, 100.0, (0, 5, 0))) == [] and not stack.in_touch


def test_a_drone_in_the_air_starts_its_plan_sooner_than_one_on_the_ground() -> None:
    """A landed drone's plan starts ``lead_steps`` on (it climbs first); one in the air, having picked up,
    ``hover_lead_steps`` on."""
    config = StackConfig(WS, SafePlanner(WS), lead_steps=6, hover_lead_steps=3)
    stack = DroneStack("d1", config, dict(WS.drones))
    stack.assign(MAIL)
    leads = []
    for step in range(1, 60):
        for action in stack.step(step, 100.0, ideal(stack, step)):
            if isinstance(action, StartExecuting):
                leads.append((action.trajectory.last, action.trajectory.start_step - step))
    assert leads[:2] == [(MAIL.pickup, 6), (MAIL.dropoff, 3)]


def test_a_drone_with_nowhere_to_park_leaves_a_mail_stop_once_idle() -> None:
    """No parking cells: a drone that delivered to one of the workspace's pickups waits next to it,
    not on it, where it would wall in the next mail from there."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 0, 0)}, pickups=((3, 0, 0), (3, 3, 0)))
    stack, actions = fly(ideal, 60, DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones)), ws)
    assert of(MailDelivered, actions) == [MailDelivered(MAIL)]
    [leave] = [a for a in of(GoTo, actions) if a.purpose is Phase.MAKING_WAY]
    assert leave.goal not in ws.pickups and stack.executor.cell == leave.goal
    assert stack.protocol.state is State.WAIT_FOR_TASK


def test_a_pickup_on_the_plan_of_a_peer_whose_clock_is_off_waits_for_it_and_is_not_handed_back() -> None:
    """CI, issue 25: a peer whose clock went off in flight flies its plan to the end, and this drone holds
    every cell of that plan for good meanwhile. A mail whose pickup lay on it failed four rounds in a
    row and was handed back, though the peer was only passing through: it waits, then flies."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 5, 0), "d2": (5, 0, 0)})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.clock_bound(False, frozenset({"d2"}), "d2's clock is off")
    stack.assign(MAIL)
    crossing = Trajectory(0, ((5, 0, 0),) * 40 + tuple((x, 0, 0) for x in range(4, -1, -1)))
    actions: list[DroneAction] = []
    for step in range(120):
        where = crossing if step <= crossing.end_step else Trajectory.stationary((0, 0, 0), crossing.end_step)
        inbox = list(stack.step(step, 100.0, stack.executor.cell))
        while inbox:
            action = inbox.pop(0)
            actions.append(action)
            message = action.message if isinstance(action, Send | Broadcast) else None
            if isinstance(message, ReqForCurrentTraj):
                inbox += stack.receive(CurrentTraj("d2", where, message.task_id))
            elif isinstance(message, PlanProposal):
                inbox += stack.receive(PlanAck("d2", message.task_id, where))
    assert of(MailRejected, actions) == []
    assert of(MailDelivered, actions) == [MailDelivered(MAIL)]


def test_a_drone_whose_clock_is_off_lands_where_its_plan_ends() -> None:
    """Found by the systematic tester with a clock off (sweep 20121): the drone held where its plan ended,
    in the air, for as long as its clock stayed off, until its battery fell below the floor. It lands
    there: the cell stays held, and the ground costs nothing."""
    stack, _ = fly(ideal, 3)
    assert stack.protocol.state is State.EXECUTING and not stack.landed
    stack.clock_bound(True, frozenset(), "my clock is off")
    for step in range(stack.executor.step + 1, stack.executor.step + 40):
        stack.step(step, 100.0, stack.executor.cell, may_plan=False)
    assert state_of(stack.protocol) is State.WAIT_FOR_TASK and stack.landed


def test_a_pickup_where_a_peer_whose_clock_is_off_rests_is_handed_back_at_once() -> None:
    """A drone whose clock is off lands where its plan ends and stays there while it is off, as a vehicle
    down does: a pickup there is cut off, and handed back before any round is spent on it."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 5, 0), "d2": MAIL.pickup})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.clock_bound(False, frozenset({"d2"}), "d2's clock is off")
    stack.assign(MAIL)
    actions = stack.step(0, 100.0, stack.executor.cell)
    assert [a.reason for a in of(MailRejected, actions)] == [
        "its pickup [3, 0, 0] is cut off from here (obstacles, vehicles down, drones whose clock is off)"]


@pytest.mark.parametrize("moves", [0, 1])
def test_a_drone_whose_battery_affords_no_move_off_a_charger_is_down_for_good(moves: int) -> None:
    """Found by the systematic tester (sweep 20142 with --skews 1): a drone whose clock was off landed on a
    charger; a low drone beside it, on a drop-off, could not afford one move, and the mail's carrier
    tried that drop-off for good. Grounded by its battery, it says so as a vehicle down does: its peers
    hold its cell for good, and its mail goes back. One move more in the battery, it is not."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (3, 3, 0), "d2": (0, 5, 0)}, charging_stations=[(0, 0, 0)])
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.assign(MAIL)
    battery = stack.config.battery
    level = battery.safe_threshold + battery.drain_per_step * (stack.mail.leg_overhead + moves) + 0.5
    actions = stack.step(0, level, stack.executor.cell)
    grounded = of(Grounded, actions)
    if moves:
        assert grounded == [] and stack.protocol.down is None
        return
    assert [g.trajectory.last for g in grounded] == [(3, 3, 0)]
    assert [(r.request, r.reason) for r in of(MailRejected, actions)] == [
        (MAIL, f"drone d1: {DRAINED}")]
    stack.assign(MAIL)
    later = stack.step(1, level, stack.executor.cell)  # mail given later goes back too
    assert stack.landed and of(GoTo, later) == [] and [r.request for r in of(MailRejected, later)] == [MAIL]


def test_a_plan_that_ends_short_of_the_legs_goal_is_no_leg_done() -> None:
    """Found by the systematic tester (sweep 20162 with --skews 1): a round to stop short of a charger held
    for good gave way to news, and the next, to the same spot, no longer knew it was short. Seen there,
    the drone took itself for charging at no charger, for good. Only the leg's own goal ends the leg."""
    stack, _ = fly(ideal, 3)
    assert stack.protocol.state is State.EXECUTING and stack.mail.phase is Phase.TO_PICKUP
    short = (0, 1, 0)
    stack._protocol(Reroute(Task(stack.clock.next_id(stack.now), short, None, hovering_since=stack.now)))
    actions: list[DroneAction] = []
    while stack.executor.cell != short or state_of(stack.protocol) is not State.WAIT_FOR_TASK:
        assert stack.now < 40
        actions += stack.step(stack.now + 1, 100.0, stack.executor.cell)
    actions += stack.step(stack.now + 1, 100.0, stack.executor.cell)
    assert of(MailPickedUp, actions) == [] and stack.mail.cell == short
    assert [g.goal for g in of(GoTo, actions)] == [MAIL.pickup]
