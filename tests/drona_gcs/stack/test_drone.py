"""One drone's whole stack (:class:`~drona_gcs.stack.drone.DroneStack`), driven step by step with the cell
telemetry puts its vehicle in: what it reports must be what the vehicle did, not what the plan said.

A lone drone on an open grid (no peers, so each task plans at once) takes one mail; the test plays
its vehicle, ideal or not: late, lost, braking, cut off, its clock off.
"""

from __future__ import annotations

import dataclasses

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneAction, DroneStack, LegNotFlown, StackConfig
from drona_gcs.stack.mail import (
    DRAINED,
    MAX_MISSES,
    GoTo,
    MailDelivered,
    MailPickedUp,
    MailRejected,
    MailStarted,
    Phase,
)
from drona_gcs.stack.messages import CurrentTraj, PlanAck, PlanProposal, ReqForCurrentTraj, Task, TaskId
from drona_gcs.stack.protocol import (
    Braked,
    Broadcast,
    Grounded,
    Reroute,
    Send,
    StartExecuting,
    State,
    Threatened,
)
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.stack.drone_helpers import MAIL, WS, fly, ideal, of, state_of


def stuck_at_start(stack: DroneStack, step: int) -> Cell | None:
    """Never left its start (a take-off that never happened): seen in its start cell."""
    return (0, 0, 0)


def in_touch(stack: DroneStack) -> bool:
    """Whether the drone is in touch with most of the fleet now (read anew, as :func:`state_of`)."""
    return stack.in_touch


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


def _flying_rerouted(held: Cell) -> DroneStack:
    """Drone a flying a plan (lead 3) whose rest could not be planned anew around ``held``."""
    ws = Workspace.build(size=(5, 5, 1), drones={"a": (0, 0, 0), "b": (0, 4, 0)})
    stack = DroneStack("a", StackConfig(ws, SafePlanner(ws, 0), lead_steps=3, hover_lead_steps=3), dict(ws.drones))
    flown = Trajectory(0, ((0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0), (4, 1, 0), (4, 2, 0), (4, 3, 0)))
    protocol = stack.protocol
    protocol.task, protocol.trajectory = Task(TaskId(1, "a", 1), (4, 3, 0)), flown
    protocol._state = State.EXECUTING  # placed flying ``flown``, which no round of this fleet would plan
    stack.executor.start(flown)
    stack.threat = Threatened("b", (held,))
    return stack


@pytest.mark.parametrize(("held", "stops_short"), [((1, 0, 0), False), ((3, 0, 0), False), ((4, 1, 0), True)])
def test_a_rest_that_found_no_plan_stops_short_only_of_a_held_cell_still_ahead(held: Cell, stops_short: bool) -> None:
    """Found by the tester (sweep 30625, a clock off): no new rest was found around a held cell the plan
    crossed before a new plan could start, and the drone stopped short anyway, its mail's leg left for
    nothing. A cell entered after a new plan could start is stopped short of; at or before it, the plan
    flies on (a rest begun in the held cell cannot keep clear of it)."""
    stack = _flying_rerouted(held)
    stack._stop_short_instead()
    assert (stack.protocol.state is State.REROUTING) is stops_short
    assert stack.stop_short == ((3, 0, 0) if stops_short else None)  # where a new plan would start


@pytest.mark.parametrize("tried", ["stopping short", "no threat left"])
def test_a_plan_whose_rest_found_no_plan_at_all_brakes_short_of_the_held_cell_at_once(tried: str) -> None:
    """Found by the tester (sweep 30687, a clock off, messages a step late): no rest of the plan flown
    could be planned around a cell held for good ahead of it (the battery afforded none), and the drone
    flew on to brake only the step before the cell. A peer that had planned in behind it on its plan,
    its clock a step ahead, heard of the brake too late and met it. It brakes as soon as no rest is
    planned: peers hear where it stops while they can still keep clear."""
    stack = _flying_rerouted((4, 1, 0))
    stack.protocol.peers_down["b"] = (4, 1, 0)
    if tried == "stopping short":
        stack.stop_short = (3, 0, 0)  # the rest to stop short found no plan either
    else:
        stack.threat = None
    braked = of(Braked, stack._stop_short_instead())
    assert [(b.trajectory.last, b.trajectory.end_step, b.held) for b in braked] == [((4, 0, 0), 5, (4, 1, 0))]


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
        "its pickup [3, 0, 0] is cut off from here (obstacles, vehicles down or lost, drones whose clock is off)"]


def test_a_pickup_where_a_lost_vehicle_may_be_is_handed_back_at_once() -> None:
    """A vehicle killed on its way to a pickup: its agent held every cell of the rest of its plan, the
    pickup among them, for good. The heir took the mail over, flew back to park, tried four rounds,
    and only then handed it back (30 s), with other mail waiting behind it. Cut off as under a vehicle
    down: handed back before any round is spent on it, and the next mail goes at once."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 5, 0), "d2": (5, 0, 0)})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.peer_lost("d2", ((5, 0, 0), (4, 0, 0), MAIL.pickup))
    other = dataclasses.replace(MAIL, id="other", pickup=(0, 3, 0), priority=MAIL.priority - 1)
    stack.assign(MAIL)
    stack.assign(other)
    actions = stack.step(0, 100.0, stack.executor.cell)
    assert [a.reason for a in of(MailRejected, actions)] == [
        "its pickup [3, 0, 0] is cut off from here (obstacles, vehicles down or lost, drones whose clock is off)"]
    assert [a.request.id for a in of(MailStarted, actions)] == ["other"]


def test_a_pickup_on_a_late_peers_plan_is_held_for_now_and_not_handed_back() -> None:
    """Found by the fleets lane: d3's clock was found off while it flew to park, and it told every peer the
    cells of that plan. Taken as a lost vehicle's, they walled the pickup of d1's mail off for good, and d1
    rejected it, though d3 was to leave those cells within steps. A late drone or a clock off holds its
    cells until it says so: planned around, but no wall for the task planner."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 5, 0), "d2": (5, 0, 0)})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.peer_lost("d2", ((5, 0, 0), (4, 0, 0), MAIL.pickup), for_now=True)
    stack.assign(MAIL)
    actions = stack.step(0, 100.0, stack.executor.cell)
    assert not of(MailRejected, actions)
    assert [a.request.id for a in of(MailStarted, actions)] == [MAIL.id]
    assert MAIL.pickup in stack.protocol.peers_lost["d2"]  # planned around all the same


def test_a_drone_in_a_cell_a_lost_vehicle_may_be_in_is_not_walled_in() -> None:
    """A lost vehicle's cells include those its plan crossed shortly before it was last seen: this
    drone may have come to rest in one since. Had the vehicle stopped there, they would have met; as a
    wall, the cell cut this drone off from everything, and its mail was handed back."""
    ws = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 5, 0), "d2": (5, 0, 0)})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.peer_lost("d2", ((5, 0, 0), (0, 4, 0), (0, 5, 0)))
    stack.assign(MAIL)
    actions = stack.step(0, 100.0, stack.executor.cell)
    assert of(MailRejected, actions) == []
    assert [a.request.id for a in of(MailStarted, actions)] == [MAIL.id]


def test_a_leg_not_flown_from_a_cell_a_lost_vehicle_may_be_in_is_tried_again() -> None:
    """Found in review: after a leg not flown, the task planner measures ways from where the vehicle
    still is (the leg's start), not from the plan's end. A lost vehicle's cell there walled it in,
    and the mail was handed back at once as cut off, not tried again."""
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    stack.protocol.peers_lost["d9"] = ((5, 5, 0), (0, 0, 0))  # (a lone drone: no peer to say so)
    _, actions = fly(stuck_at_start, 80, stack)
    assert of(LegNotFlown, actions)[:MAX_MISSES] == [LegNotFlown(MAIL.pickup, (0, 0, 0))] * MAX_MISSES
    assert ["never reached the pickup" in a.reason for a in of(MailRejected, actions)][:1] == [True]


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
