"""The coordination protocol while a plan is flown: lost vehicles, peers that leave across
the plan, vehicles that come down, brakes and the operator's release.
"""

from __future__ import annotations

import pytest

from drona_gcs.errors import ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_trajectory
from drona_gcs.stack.messages import (
    CurrentTraj,
    ReqForCurrentTraj,
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import (
    Braked,
    Broadcast,
    Grounded,
    Holding,
    NewTask,
    NextStep,
    PeerAnnounced,
    PeerBraked,
    PeerDown,
    PeerJoined,
    PeerLeft,
    PeerLost,
    PlanCompleted,
    Present,
    Released,
    Relocated,
    Reroute,
    RerouteFailed,
    Send,
    State,
    TaskFailed,
    Threatened,
    VehicleDown,
    VehicleLost,
)
from drona_gcs.workspace import Workspace
from tests.drona_gcs.stack.protocol_helpers import (
    B_AWAY,
    GOAL,
    ID_A,
    ID_B_LOW,
    OPEN,
    A,
    B,
    C,
    confirmed,
    flying_past_b,
    location_of,
    machine,
    manhattan,
    request,
    started,
    state_of,
    traj,
)


# ============================================================ a lost vehicle
def test_a_lost_vehicle_may_trail_its_plan_by_the_window_so_those_cells_are_held_too() -> None:
    """Delta covers a vehicle up to lambda late: lost at step 5 of its plan, seen in the plan's cell of
    step 5, it may still be in those of steps 3 and 4 (a killed vehicle's peer flew into one)."""
    proto = machine({"a": A, "b": B})
    proto.delta = 2
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0))).trajectory
    proto.handle(VehicleLost(5, plan.at(5)), 5)
    assert {plan.at(3), plan.at(4)} <= set(proto.holds()) and plan.at(3) != plan.at(5)


def test_a_drone_whose_vehicle_is_lost_holds_the_rest_of_its_plan_and_plans_nothing() -> None:
    """Lost at step 4 of its plan, last seen in (1, 0): its vehicle may be anywhere on the rest of the
    plan from then on. Its answers and requests say so; a task of its own finds no plan."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0))).trajectory
    assert proto.handle(VehicleLost(4, (1, 0, 0)), 4) == [Holding(proto.holds(), seq=(0, 1))]  # every peer, at once
    answer = proto.handle(request(ID_B_LOW, "b", 4), 4)
    assert answer == [Send("b", CurrentTraj("a", plan, ID_B_LOW, ((1, 0, 0), A, *plan.suffix_from(4).cells)))]
    reply = answer[0]
    assert isinstance(reply, Send) and isinstance(reply.message, CurrentTraj)
    assert set(reply.message.holds) == {A, (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0)}

    proto.handle(PlanCompleted(), plan.end_step)
    actions = proto.handle(NewTask(Task(TaskId(20, "a", 2), (0, 3, 0))), 10)
    assert actions[0] == Broadcast(ReqForCurrentTraj(TaskId(20, "a", 2), "a", plan, ("b",), proto.holds()))
    failed = proto.handle(CurrentTraj("b", location_of("b", 10), TaskId(20, "a", 2)), 10)
    assert [type(a) for a in failed] == [TaskFailed]
    assert isinstance(failed[0], TaskFailed) and "vehicle is lost" in failed[0].reason

    assert proto.handle(Relocated((2, 0, 0)), 11) == [Holding((), seq=(0, 2))]
    assert proto.holds() == () and proto.current_trajectory(11) == Trajectory.stationary((2, 0, 0), 11)


def test_a_plan_avoids_every_cell_a_lost_peer_holds_for_good() -> None:
    """b's vehicle is lost: the straight way from a to the goal crosses cells b holds, though b's own
    trajectory (resting at B) never comes near. a plans around them, for good."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    held = ((2, 0, 0), (2, 1, 0))
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A, held), 0)))
    assert not set(plan.trajectory.cells) & set(held)
    assert check_trajectory(OPEN, plan.trajectory, {"hold": Trajectory.stationary((2, 0, 0), 0)}, 0) == []
    assert manhattan(A, GOAL) < len(plan.trajectory.cells) - 1  # the detour


# ========================================== a peer leaves across the plan I fly
def test_a_peer_that_leaves_across_the_rest_of_my_plan_has_me_plan_that_rest_anew() -> None:
    """Found by the systematic tester with a crash: b's agent died before it flew its plan (silent since
    step 0), its vehicle holding where it was; a drone that had planned around b's plan flew into it.
    Plans made before a leave is noticed avoided only the plan: the rest of mine is planned anew, flown
    on meanwhile."""
    proto, plan = flying_past_b()
    assert proto.handle(PeerLeft("b", silent_since=0), 2) == [Threatened("b", ((3, 0, 0),))]
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    assert proto.state is State.REROUTING and proto.trajectory == plan  # what it answers meanwhile
    actions = confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), TaskId(6, "a", 2)), 2))
    new = started(actions).trajectory
    assert all(new.at(s) == plan.at(s) for s in range(0, 5))  # the same until the new rest starts
    assert not {(3, 0, 0), (3, 1, 0)} & set(new.suffix_from(4).cells) and new.last == GOAL
    assert state_of(proto) is State.EXECUTING and proto.trajectory == new


@pytest.mark.parametrize(("start_by", "planned"), [(None, True), (3, False)])
def test_a_rest_that_must_start_by_a_step_is_not_planned_later(start_by: int | None, planned: bool) -> None:
    """A rest that stops short of a held cell, begun once the plan flown is at or past it, leaves the leg
    for nothing (the tester found one begun at the cell, after which the plan reached its drop-off: sweep
    30625, a clock off). A round that would start it later than its ``start_by`` fails: I fly on."""
    proto, plan = flying_past_b()
    proto.handle(PeerLeft("b", silent_since=0), 2)
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL, start_by=start_by)), 2)
    actions = proto.handle(CurrentTraj("c", location_of("c"), TaskId(6, "a", 2)), 2)
    failed = [a for a in actions if isinstance(a, RerouteFailed)]
    assert (not failed) is planned
    assert planned or ("too late" in failed[0].reason and proto.trajectory == plan)


def test_a_leave_behind_my_plan_changes_nothing() -> None:
    proto, _ = flying_past_b()
    assert proto.handle(PeerLeft("c"), 2) == []


def test_a_reroute_round_ends_when_the_plan_does() -> None:
    """The plan ended before the round: the drone rests at its end, and the round is moot."""
    proto, plan = flying_past_b()
    proto.handle(PeerLeft("b"), 2)
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    actions = proto.handle(PlanCompleted(), 6)
    assert [type(a) for a in actions] == [RerouteFailed]
    assert proto.state is State.WAIT_FOR_TASK and proto.location == plan.last


def test_a_peer_that_leaves_is_held_along_its_newest_plan_not_an_old_answer() -> None:
    """Found by a crash sweep: b answered my round at rest, then announced a plan and died; I kept
    the old answer as its last trajectory, held only where it had rested, and planned into its plan."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)))
    b_plan = traj(3, (4, 4), (3, 4), (3, 3), (3, 2))
    proto.heard("b", b_plan, 0)
    proto.handle(PeerLeft("b"), 4)
    assert {(3, 3, 0), (3, 2, 0)} <= set(proto.ghosts["b"].cells) and proto.ghosts["b"].last == (3, 2, 0)


# ================================================ a vehicle that comes down by itself
def test_a_drone_whose_vehicle_came_down_stays_there_and_tells_every_peer() -> None:
    """Found once the tester kept a vehicle down where it came down (its model flew the plan on):
    peers planned, and flew, into it. It rests there for good, says so, and plans nothing more."""
    proto, plan = flying_past_b()
    actions = proto.handle(VehicleDown(plan.at(3)), 3)
    assert actions[0] == Grounded(Trajectory.stationary(plan.at(3), 3))
    assert proto.state is State.WAIT_FOR_TASK and proto.current_trajectory(9) == Trajectory.stationary(plan.at(3), 3)
    failed = proto.handle(NewTask(Task(TaskId(9, "a", 2), GOAL)), 4)
    failed += proto.handle(CurrentTraj("b", location_of("b"), TaskId(9, "a", 2)), 4)
    failed += proto.handle(CurrentTraj("c", location_of("c"), TaskId(9, "a", 2)), 4)
    assert [a.reason for a in failed if isinstance(a, TaskFailed)] == ["my vehicle is down"]


def test_a_peer_down_on_the_rest_of_my_plan_has_me_plan_it_anew_and_stays_an_obstacle() -> None:
    proto, plan = flying_past_b()
    assert proto.handle(PeerDown("c", plan.at(5)), 2) == [Threatened("c", (plan.at(5),))]
    assert proto.handle(PeerDown("b", (2, 4, 0)), 2) == [Threatened("b", (plan.at(5),))]  # off my plan: c's stands
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    late_answer = CurrentTraj("c", traj(0, (0, 4), (1, 4)), TaskId(6, "a", 2))  # sent before it came down
    new = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), TaskId(6, "a", 2)), 2)
                            + proto.handle(late_answer, 2))).trajectory
    assert plan.at(5) not in new.suffix_from(4).cells
    assert proto.received["c"] == Trajectory.stationary(plan.at(5), 0)


def test_a_reroute_with_no_peer_left_to_ask_plans_from_the_plan_flown() -> None:
    """Found by a crash sweep: with nobody to wait for, the round planned at once, before it was
    marked a reroute, from where the drone had rested before its plan."""
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", B_AWAY, ID_A), 0))).trajectory
    assert proto.handle(PeerLeft("b", silent_since=0), 2) == [Threatened("b", ((3, 0, 0),))]
    new = started(confirmed(proto, proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2))).trajectory
    assert all(new.at(s) == plan.at(s) for s in range(0, 5)) and (3, 0, 0) not in new.suffix_from(4).cells


# ======================================================== braking short of a cell held for good
def test_a_vehicle_down_too_close_to_plan_around_has_me_brake_short_of_it() -> None:
    """Found by a sweep (seed 2027): a vehicle came down two steps ahead of a drone's plan, sooner than a
    round can plan around it, and the drone flew into it. It now stops at the cell before, and says so."""
    proto, plan = flying_past_b()
    actions = proto.handle(PeerDown("c", plan.at(5)), 4)
    cut = Trajectory(plan.start_step, (*(plan.at(t) for t in range(plan.start_step, 5)), plan.at(4)))
    assert actions == [Braked(cut, plan.at(5))]
    assert proto.trajectory == cut and proto.state is State.EXECUTING
    assert [a.message.trajectory for a in proto.handle(request(ID_B_LOW, "b"), 4) if isinstance(a, Send)
            and isinstance(a.message, CurrentTraj)] == [cut]


def test_a_drone_that_braked_tells_a_peer_back_of_the_brake() -> None:
    """Its announcement of the brake went nowhere across a partition: a peer back is told, as a brake."""
    proto, plan = flying_past_b()
    [braked] = proto.handle(PeerDown("c", plan.at(5)), 4)
    assert isinstance(braked, Braked)
    proto.handle(PeerLeft("b", silent_since=4), 4)
    assert proto.handle(PeerJoined("b", B), 5) == [Present("b", braked.trajectory, True)]


def test_a_peer_back_is_held_where_it_may_be_until_it_says_what_it_flies() -> None:
    """Sweep 10033: the cut healed, d4 dropped d1's ghost at once, and flew into d1, which had braked
    while they were apart. A peer back stays held where it may be until its own word comes."""
    proto = machine({"a": A, "b": B})
    way = traj(0, (4, 4), (3, 4), (2, 4), (2, 3))
    proto.heard("b", way, 0)
    proto.handle(PeerLeft("b", silent_since=0), 1)
    held = {t.last for t in proto.ghost_obstacles().values()}
    assert set(way.cells) <= held
    proto.handle(PeerJoined("b", way.last), 2)
    assert {t.last for t in proto.ghost_obstacles().values()} == held and "b" in proto.members
    cut = traj(0, (4, 4), (3, 4), (3, 4))
    proto.handle(PeerBraked("b", cut), 3)
    assert proto.ghost_obstacles() == {} and proto.known["b"] == cut and proto.braked == {"b": cut}


def test_a_round_that_ends_too_late_to_plan_around_a_vehicle_down_brakes_at_the_last_step() -> None:
    """Found by a crash sweep (seed 5151): the round to plan around it was still waiting for an answer
    when the plan entered the cell. At the boundary before, the drone brakes and the round ends."""
    proto, plan = flying_past_b()
    assert proto.handle(PeerDown("c", plan.at(5)), 2) == [Threatened("c", (plan.at(5),))]
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    assert proto.handle(NextStep(), 3) == []  # (3, 0) is two steps away: a plan may still come
    actions = proto.handle(NextStep(), 4)
    assert [type(a) for a in actions] == [Braked, RerouteFailed]
    assert proto.state is State.EXECUTING and proto.trajectory is not None and proto.trajectory.last == plan.at(4)
    assert plan.at(5) not in proto.trajectory.cells


def test_a_peer_that_braked_overrides_its_older_answer_until_its_next_plan() -> None:
    """Found by the tester once drones braked: a drone planned with a braked peer's answer, sent before
    the brake and delivered after its news, and so planned through where the peer held."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    cut = traj(0, (3, 0), (3, 0))
    proto.handle(PeerBraked("b", cut), 0)
    proto.handle(CurrentTraj("b", B_AWAY, ID_A), 0)  # sent before it braked
    assert proto.received["b"] == cut
    plan = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0))).trajectory
    assert (3, 0, 0) not in plan.cells
    later = traj(4, (3, 0), (3, 1))
    proto.heard("b", later, 0)
    assert proto.known["b"] == later and "b" not in proto.braked


def test_a_peer_that_braked_twice_on_one_plan_holds_where_it_braked_last_whatever_the_order_heard() -> None:
    """Found by the tester (sweep 20164 with --skews 1): a drone braked, then braked again shorter on the
    same plan; its first cut came last, and a peer planned through where it held."""
    proto = machine()
    first, second = traj(0, (3, 2), (3, 1), (3, 0), (3, 0)), traj(0, (3, 2), (3, 1), (3, 1))
    proto.handle(PeerBraked("b", second), 0)
    proto.handle(PeerBraked("b", first), 0)
    assert proto.known["b"] == second and proto.braked["b"] == second


def test_a_brake_heard_after_the_peers_rest_still_overtakes_the_answer_my_round_holds() -> None:
    """Found by the tester (sweep 20171 with --skews 1): b answered my round with its plan, braked on it,
    and, its clock off, said at once that it rests. The rest came first, so its brake was taken for old
    news, and I planned with the plan it had cut."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan = traj(0, (3, 2), (3, 1), (3, 0), (4, 0))
    cut = traj(0, (3, 2), (3, 1), (3, 1))
    proto.handle(CurrentTraj("b", plan, ID_A), 0)
    proto.handle(PeerAnnounced("b", Trajectory.stationary((3, 1, 0), 3)), 3)
    proto.handle(PeerBraked("b", cut), 3)
    assert proto.received["b"] == cut


def test_a_peers_brake_holds_on_past_the_rest_it_says_it_takes_there() -> None:
    """Found by the tester (sweep 20181 with --skews 1): b braked and, its clock off, said at once that it
    rests where it braked. Its answer to my round, sent before, came after both: the rest had ended the
    brake, and I planned with the plan b had cut."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan, cut = traj(0, (4, 4), (4, 3), (3, 3), (2, 3)), traj(0, (4, 4), (4, 3), (4, 3))
    proto.handle(PeerBraked("b", cut), 1)
    proto.handle(PeerAnnounced("b", Trajectory.stationary((4, 3, 0), 3)), 3)
    proto.handle(CurrentTraj("b", plan, ID_A), 3)  # sent before it braked
    assert proto.received["b"] == cut


def test_a_peers_brake_heard_after_its_rest_drops_the_plan_i_made_with_what_it_cut() -> None:
    """Found by the tester (sweep 20181 with --skews 1): b answered my round with its plan, braked, said
    it rests there, and acked my plan; its rest came first, so its brake was taken for old news and my
    plan, made with what it cut, was flown."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    plan, cut = traj(0, (4, 4), (4, 3), (3, 3), (2, 3)), traj(0, (4, 4), (4, 3), (4, 3))
    proto.handle(CurrentTraj("b", plan, ID_A), 0)
    proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)
    assert proto.state is State.CONFIRMING
    proto.handle(PeerAnnounced("b", Trajectory.stationary((4, 3, 0), 3)), 3)
    proto.handle(PeerBraked("b", cut), 3)
    assert state_of(proto) is not State.CONFIRMING and proto.proposed is None


def test_a_peer_that_braked_holds_there_until_the_plan_it_made_since_starts() -> None:
    """Found by the tester (sweep 20213 with --partitions 2): b braked across a cut; told once it healed,
    my rest could not be planned anew, and NextStep would have braked, but b's next plan, from where it
    held and starting later, came first and ended the brake. I flew into b, still waiting there."""
    proto, plan = flying_past_b()
    proto.handle(PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0))), 1)  # holds (3, 0) from step 2
    proto.heard("b", traj(9, (3, 0), (3, 1)), 0)  # its next plan, from there, starts at step 9
    actions = proto.handle(NextStep(), 4)
    assert [type(a) for a in actions] == [Braked]
    assert proto.trajectory is not None and (3, 0, 0) not in proto.trajectory.suffix_from(4).cells
    assert plan.at(5) == (3, 0, 0)


@pytest.mark.parametrize("brake_heard_last", [False, True])
def test_a_peer_down_elsewhere_no_longer_holds_where_it_braked(brake_heard_last: bool) -> None:
    """Found by the tester (sweep 20242 with --skews 1): b braked on a plan it never flew (its clock off),
    then its vehicle came down where it was. Its brake held a cell for good, which plans did not avoid: a
    drone planned into it, braked at once, and planned again, for good, its mail never delivered. A
    vehicle down stays where it came down: nothing else of it holds, nor does its brake heard late."""
    proto, plan = flying_past_b()
    down = PeerDown("b", (6, 6, 0))
    brake = PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0)))  # holds (3, 0) from step 2
    for event in (down, brake) if brake_heard_last else (brake, down):
        proto.handle(event, 2)
    assert "b" not in proto.braked
    assert proto.handle(NextStep(), 4) == []
    assert proto.trajectory == plan and plan.at(5) == (3, 0, 0)


def test_a_peer_down_then_restarted_holds_where_it_braked_since() -> None:
    """A second review: a peer's vehicle came down, its agent was restarted (it left and joined again), and
    it braked on a plan flown since. That brake is news of its new run, not of the vehicle down."""
    proto, plan = flying_past_b()
    proto.handle(PeerDown("b", (6, 6, 0)), 1)
    proto.handle(PeerLeft("b", silent_since=1), 1)
    proto.handle(PeerJoined("b", (6, 6, 0)), 1)
    actions = proto.handle(PeerBraked("b", traj(2, (3, 1), (3, 0), (3, 0))), 2)  # holds (3, 0) from step 3
    assert [type(a) for a in actions] in ([Threatened], [Braked])
    assert plan.at(5) == (3, 0, 0)


def test_a_peer_that_braked_on_my_plan_has_me_brake_or_plan_anew() -> None:
    """A brake holds a cell that plans made before it did not avoid: the plan flown steers clear of it."""
    proto, plan = flying_past_b()
    far = proto.handle(PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0))), 2)
    assert far == [Threatened("b", (plan.at(5),))]
    proto, plan = flying_past_b()
    near = proto.handle(PeerBraked("b", traj(0, (3, 1), (3, 0), (3, 0))), 4)
    assert [type(a) for a in near] == [Braked] and proto.trajectory is not None
    assert proto.trajectory.last == plan.at(4)


def test_a_drone_whose_vehicle_is_down_tells_a_peer_that_joins() -> None:
    """Found by a crash sweep (seed 101): an agent that restarted had missed the news, took the vehicle
    down for a drone at rest that would make way, and flew between two chargers for good."""
    proto, plan = flying_past_b()
    proto.handle(VehicleDown(plan.at(3)), 3)
    proto.handle(PeerLeft("b"), 4)
    assert proto.handle(PeerJoined("b", B), 5) == [Grounded(Trajectory.stationary(plan.at(3), 3))]


def test_the_operator_releases_a_departed_drones_cells_and_nothing_else() -> None:
    """A killed drone's whole remaining path stayed blocked for good (issue 25: 37 refusals in one
    run). Once the operator saw its vehicle out of the air, no cell is held for it; a drone in the
    fleet cannot be released."""
    proto, _ = flying_past_b()
    proto.handle(PeerLeft("c"), 2)
    assert proto.ghosts["c"].last == C
    with pytest.raises(ProblemError, match="b is not a drone gone"):
        proto.handle(Released("b"), 3)
    assert proto.handle(Released("c"), 3) == [] and "c" not in proto.ghosts and "c" not in proto.known
    assert proto.ghost_obstacles() == {}
    proto.handle(PeerJoined("c", (2, 2, 0)), 4)
    assert proto.known["c"] == Trajectory.stationary((2, 2, 0), 4) and "c" in proto.members


def test_a_peers_lost_vehicle_on_the_rest_of_my_plan_has_me_plan_it_anew_and_stays_an_obstacle() -> None:
    """Found over real processes: b's vehicle was lost where my plan was to pass later; b's answers said
    so, but only in my next round. Told at once (PeerLost), I steer clear as of a vehicle down."""
    proto, plan = flying_past_b()
    assert proto.handle(PeerLost("b", (plan.at(5), (4, 4, 0))), 2) == [Threatened("b", (plan.at(5),))]
    proto.handle(Reroute(Task(TaskId(6, "a", 2), GOAL)), 2)
    new = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), TaskId(6, "a", 2)), 2)
                            + proto.handle(CurrentTraj("c", location_of("c"), TaskId(6, "a", 2)), 2))).trajectory
    assert plan.at(5) not in new.suffix_from(4).cells
    proto.handle(PeerLost("b", ()), 3)  # back
    assert proto.peers_lost == {}


@pytest.mark.parametrize("held_steps", [(5,), (1, 2), (3, 7), (0, 6), (2,)])
def test_a_boundary_brakes_exactly_when_the_next_step_enters_a_held_cell(held_steps: tuple[int, ...]) -> None:
    """At every boundary of the plan: a brake when the plan's next cell is held for good and its cell
    now is not (already in one, stopping would not part us), and nothing otherwise."""
    for now in range(0, flying_past_b()[1].end_step + 2):
        proto, plan = flying_past_b()
        for peer, step in zip(("b", "c"), held_steps, strict=False):
            proto.peers_down[peer] = plan.at(step)
        held = {plan.at(step) for step in held_steps}
        enters = now < plan.end_step and plan.at(now) not in held and plan.at(now + 1) in held
        braked = [a for a in proto.handle(NextStep(), now) if isinstance(a, Braked)]
        assert bool(braked) == enters, now
        assert all(b.trajectory.last == plan.at(now) for b in braked)


def test_a_plan_made_after_a_peer_braked_keeps_out_of_where_it_holds_as_long_as_a_plan_flown_must() -> None:
    """Found by the tester (sweep 30691, a clock off, messages two steps late): a plan flown keeps out of
    where a braked peer holds from its arrival less my lead; a plan made by the plain window went in
    before the peer came, so the drone braked short of it as soon as it flew, where the braked peer had
    still to pass, and they met."""
    corridor = Workspace.build(size=(7, 2, 1))
    proto = machine({"a": (0, 0, 0), "b": (3, 1, 0)}, lead_steps=4, workspace=corridor)
    cut = traj(0, *[(3, 1)] * 9, (3, 0), (3, 0))  # b hovers over the corridor, then holds (3, 0) from step 9
    proto.handle(PeerBraked("b", cut), 0)
    proto.handle(NewTask(Task(ID_A, (6, 0, 0))), 0)
    plan = started(confirmed(proto, proto.handle(CurrentTraj("b", cut, ID_A), 0))).trajectory
    held_from = cut.end_step - proto.lead_steps
    assert all(plan.at(t) != (3, 0, 0) for t in range(held_from, plan.end_step + 1)), plan
    proto.location, proto.trajectory = plan.first, plan
    assert proto._held_on_plan(0) == []  # flown, it needs no brake
