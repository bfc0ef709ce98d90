"""The coordination protocol's clocks: task ids on hybrid clocks, and a clock beyond the
fleet's bound.
"""

from __future__ import annotations

import itertools

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import (
    TICK_LIMIT,
    CurrentTraj,
    HybridClock,
    PlanAck,
    PlanProposal,
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import (
    Braked,
    ClockBound,
    Holding,
    NewTask,
    PeerAnnounced,
    PeerJoined,
    PeerLeft,
    PlanCompleted,
    Present,
    Send,
    TaskFailed,
    Threatened,
)
from tests.drona_gcs.stack.protocol_helpers import (
    B_AWAY,
    GOAL,
    ID_A,
    ID_B_LOW,
    A,
    confirmed,
    flying_past_b,
    location_of,
    machine,
    request,
    started,
    traj,
)


# =========================================================== hybrid clocks
def test_task_ids_are_unique_and_totally_ordered_across_drones() -> None:
    clocks = [HybridClock(d) for d in ("a", "b", "c")]
    ids = [clock.next_id(physical) for physical in (0, 0, 5, 3, 3, 10) for clock in clocks]
    assert len(set(ids)) == len(ids)
    for x, y in itertools.combinations(ids, 2):
        assert (x < y) != (y < x)  # exactly one way round: a strict total order
    for clock in clocks:  # each drone's own ids only grow, even when physical time steps back
        own = [i for i in ids if i.drone == clock.drone]
        assert own == sorted(own) and [i.seq for i in own] == list(range(1, 7))


def test_ids_follow_physical_time_and_never_go_back() -> None:
    clock = HybridClock("a")
    first = clock.next_id(100)
    behind = clock.next_id(50)  # physical time stepped back: the stamp stays, the tick counts on
    assert (first.stamp, first.tick) == (100, 0) and (behind.stamp, behind.tick) == (100, 1) and behind > first
    assert (clock.next_id(200).stamp, clock.tick) == (200, 0)


def test_an_observed_id_makes_later_ids_rank_below_it() -> None:
    a, b = HybridClock("a"), HybridClock("b")
    seen = a.next_id(40)
    b.observe(seen)
    later = b.next_id(0)
    assert later.stamp == seen.stamp  # no further than the stamp seen: the tick orders them
    assert later > seen and later > TaskId(seen.stamp, "zzz", 10**6)
    b.observe(TaskId(3, "c", 1))  # an older id does not pull the clock back
    assert b.next_id(0) > later


def test_stamps_never_run_ahead_of_the_largest_physical_step() -> None:
    """Every drone sees every id: a fleet making many ids a step must not push stamps past its clocks
    (they would pass the bound on stamps ahead, and every message would then be refused as forged)."""
    clocks = [HybridClock(f"d{n}") for n in range(8)]
    last: TaskId | None = None
    for step in range(50):
        for _burst in range(5):
            for clock in clocks:
                if last is not None:
                    clock.observe(last)
                made = clock.next_id(step)
                assert last is None or made > last  # each after the last it saw
                assert made.stamp == step
                last = made


def test_a_tick_at_its_limit_moves_the_stamp_on() -> None:
    clock = HybridClock("a")
    forged = TaskId(7, "z", 1, tick=TICK_LIMIT)
    clock.observe(forged)
    after = clock.next_id(0)
    assert (after.stamp, after.tick) == (8, 0) and after > forged


# ====================================================== a clock beyond the fleet's bound
def test_a_drone_whose_clock_is_off_holds_where_its_plan_ends_and_plans_nothing() -> None:
    """Its steps are not the fleet's: every cell of the rest of its plan is held for good in its answers,
    and it plans nothing; the others plan around that and go on (they do not wait for it)."""
    proto = machine()
    plan = started(confirmed(proto, proto.handle(NewTask(Task(ID_A, GOAL)), 0)
                             + proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
                             + proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0))).trajectory
    # Every peer is told at once where its vehicle may be, not only the next round that asks.
    assert proto.handle(ClockBound(mine_off=True), 3) == [Holding(proto.holds(), for_now=True, seq=(0, 1))]
    assert set(plan.suffix_from(3).cells) <= set(proto.holds())
    assert proto.handle(ClockBound(mine_off=True), 4) == []  # said once
    [answer] = proto.handle(request(ID_B_LOW, "b", 4), 4)
    assert isinstance(answer, Send) and isinstance(answer.message, CurrentTraj)
    assert set(answer.message.holds) == set(proto.holds())
    proto.handle(PlanCompleted(), plan.end_step)
    failed = proto.handle(NewTask(Task(TaskId(9, "a", 2), A)), plan.end_step)
    failed += proto.handle(CurrentTraj("b", location_of("b"), TaskId(9, "a", 2)), plan.end_step)
    failed += proto.handle(CurrentTraj("c", location_of("c"), TaskId(9, "a", 2)), plan.end_step)
    assert [a.reason for a in failed if isinstance(a, TaskFailed)] == ["my clock is beyond the fleet's bound"]
    # At rest, it answers with the cell it rests in alone: peers hold every cell it answers with for good.
    assert proto.holds() == (GOAL,)
    [answer] = proto.handle(request(TaskId(30, "b", 3), "b", plan.end_step + 1), plan.end_step + 1)
    assert isinstance(answer, Send) and isinstance(answer.message, CurrentTraj)
    assert set(answer.message.trajectory.cells) == {GOAL}
    back = proto.handle(ClockBound(mine_off=False), plan.end_step + 1)
    assert back == [Holding((), for_now=True, seq=(0, 3))]  # peers hold no more (the second: its rest)
    assert proto.holds() == ()


def test_a_peer_whose_clock_is_off_gets_no_ack_and_is_held_where_it_flies_for_good() -> None:
    proto = machine()
    proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b"})), 0)
    assert proto.handle(PlanProposal("b", ID_B_LOW, traj(3, (4, 4), (3, 4)), ("a", "c")), 0) == []
    b_way = traj(0, (2, 1), (2, 0), (2, 1))  # across a's way, long before a gets there: in b's steps, not ours
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("b", b_way, ID_A), 0)
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)))
    held = {t.last for name, t in action.psi.items() if name.startswith("b@")}
    assert held == set(b_way.cells) and (2, 0, 0) not in action.trajectory.cells


@pytest.mark.parametrize(("verdict_at", "steered"), [(2, Threatened), (3, Braked)])
def test_the_plan_i_fly_steers_clear_of_the_plan_of_a_peer_found_with_its_clock_off(verdict_at: int,
                                                                                   steered: type) -> None:
    """Found in review: the cells of a peer whose clock is off were held for good only in plans made after
    the verdict. The plan I fly went on through a cell b left a few steps before, in steps b's clock no
    longer keeps with mine: it is planned anew there, or (too close for a round) cut short of it."""
    proto, _ = flying_past_b()
    actions = proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b"})), verdict_at)
    assert [type(a) for a in actions] == [steered]
    if steered is Threatened:
        assert actions == [Threatened("b", ((3, 0, 0),))]
    else:
        assert proto.trajectory is not None and (3, 0, 0) not in proto.trajectory.suffix_from(verdict_at).cells
    assert proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b"})), verdict_at) == []  # news once


def test_two_peers_found_off_at_once_have_the_plan_i_fly_planned_anew_once() -> None:
    """Found by the tester (sweep 20182 with --skews 2): one clock check found b and c off, each on the
    rest of my plan. Each was reported Threatened; the first had the rest planned anew, and the second
    asked for a new rest while that round was under way, which no state takes."""
    proto, _ = flying_past_b()
    proto.handle(PeerAnnounced("c", traj(1, (0, 4), (1, 4), (1, 3), (4, 3), (4, 1), (4, 0))), 1)
    actions = proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b", "c"})), 2)
    assert [type(a) for a in actions] == [Threatened]
    assert actions == [Threatened("b, c", ((3, 0, 0), (4, 0, 0)))]


def test_a_drone_whose_clock_is_off_stops_short_of_every_cell_of_its_peers_plans() -> None:
    """Its steps are not the fleet's: b left (3, 0) steps before I fly there by my clock, but by b's I may
    come while it is there (or after it rests there). Flying on to the plan's end, as before, is no longer
    safe: the plan is cut short of the first cell a peer's plan holds, and that is what I answer with."""
    proto, plan = flying_past_b()
    actions = proto.handle(ClockBound(mine_off=True), 2)
    assert [type(a) for a in actions] == [Braked, Holding]
    assert proto.trajectory is not None and proto.trajectory.last == plan.at(4) == (2, 0, 0)
    assert not set(proto.holds()) & set(B_AWAY.cells)


def test_a_drone_whose_clock_is_off_tells_every_peer_at_once_that_it_rests() -> None:
    """Found by the systematic tester (sweep 20132 with --skews 1): peers hold every cell of the plan they
    last heard a drone off fly, and one braked short of a charger that drone had left long before, walling
    it in. At its plan's end the drone off says it rests in one cell, without waiting to be asked."""
    proto, _ = flying_past_b()
    proto.handle(ClockBound(mine_off=True), 2)
    assert proto.trajectory is not None
    rest = Trajectory.stationary(proto.trajectory.last, proto.trajectory.end_step)
    told = proto.handle(PlanCompleted(), proto.trajectory.end_step)
    assert told == [*(Present(peer, rest, braked=False) for peer in ("b", "c")),
                    Holding((rest.last,), for_now=True, seq=(0, 2))]


def test_a_drone_found_off_at_rest_after_a_plan_tells_every_peer_at_once_that_it_rests() -> None:
    """Found by the systematic tester (sweep 20132, seed 74613): the clock check found a drone off after
    its plan had ended; it still answered with that plan, so peers held the charger it had left for good."""
    proto, _ = flying_past_b()
    assert proto.trajectory is not None
    end = proto.trajectory.end_step
    proto.handle(PlanCompleted(), end)
    rest = Trajectory.stationary(proto.trajectory.last, end + 3)
    told = proto.handle(ClockBound(mine_off=True), end + 3)
    assert told == [*(Present(peer, rest, braked=False) for peer in ("b", "c")),
                    Holding((rest.last,), for_now=True, seq=(0, 1))]
    assert proto.current_trajectory(end + 4) == rest


def test_a_drone_whose_clock_is_off_acks_with_the_cells_it_holds_for_good() -> None:
    """Its own check runs on steps that are not the fleet's: the proposer judges its plan against the cells
    the ack holds. Acking nothing stalled every plan of the fleet (found over real processes)."""
    proto = machine()
    proto.handle(ClockBound(mine_off=True), 0)
    proposal = PlanProposal("b", ID_B_LOW, traj(3, (4, 4), (4, 3)), ("a", "c"))
    assert proto.handle(proposal, 0) == [Send("b", PlanAck("a", ID_B_LOW, location_of("a"), proto.holds()))]
    assert A in proto.holds()


def test_a_late_vehicle_is_told_to_every_peer_at_once_and_held_on_its_plan_until_it_is_on_time() -> None:
    """Found over 128 agents on 2 cores: d26's vehicle was late on its way to (23, 7); it braked and said so,
    but its holds went only into answers. d43, flying, heard of the brake and stopped short of (23, 7) in
    (22, 7), where d26's vehicle still was. Now every peer hears at once every cell the vehicle may be in,
    also once my steps end the plan (the vehicle is still on its way), and that no more once it is on time."""
    proto, plan = flying_past_b()
    late = proto.handle(ClockBound(mine_off=True, on_time_at=1), 3)
    [told] = [a for a in late if isinstance(a, Holding)]
    assert proto.trajectory is not None
    assert set(proto.trajectory.suffix_from(0).cells) <= set(told.cells)  # from on time, less Delta + 1
    assert set(told.cells) <= set(plan.cells)
    rest = proto.handle(PlanCompleted(), proto.trajectory.end_step)
    assert isinstance(rest[-1], Holding) and set(rest[-1].cells) == set(told.cells)  # its vehicle is on it still
    assert proto.handle(ClockBound(mine_off=False), proto.trajectory.end_step + 2) == [
        Holding((), for_now=True, seq=(0, 3))]


def test_a_peer_back_is_told_at_once_where_my_late_vehicle_may_be() -> None:
    """A peer back from a partition missed the news that my vehicle went late: told only my plan, it would
    plan through the cells my vehicle trails in until it next asked me."""
    proto, _ = flying_past_b()
    [told] = [a for a in proto.handle(ClockBound(mine_off=True, on_time_at=1), 3) if isinstance(a, Holding)]
    proto.handle(PeerLeft("b"), 4)
    back = proto.handle(PeerJoined("b", B_AWAY.last), 5)
    assert Holding(told.cells, for_now=True, seq=told.seq) in back  # the same holds: the same count
    assert any(isinstance(a, Present) and a.to == "b" for a in back)
