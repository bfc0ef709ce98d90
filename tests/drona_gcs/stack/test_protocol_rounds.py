"""The coordination protocol's rounds: requests while coordinating, late requests,
stale replies and members that leave or join.
"""

from __future__ import annotations

import itertools

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_trajectory
from drona_gcs.stack.messages import (
    CurrentTraj,
    PlanAck,
    PlanDecision,
    PlanProposal,
    ReqForCurrentTraj,
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import (
    ASK_AGAIN_MOST_STEPS,
    ASK_AGAIN_STEPS,
    Broadcast,
    NewTask,
    NextStep,
    PeerJoined,
    PeerLeft,
    Present,
    Send,
    StartExecuting,
    State,
    TaskFailed,
)
from tests.drona_gcs.stack.protocol_helpers import (
    GOAL,
    ID_A,
    ID_B_HIGH,
    ID_B_LOW,
    ID_B_NEXT,
    ID_C_LOW,
    OPEN,
    STARTS,
    A,
    B,
    C,
    confirmed,
    location_of,
    machine,
    others,
    request,
    started,
    traj,
)


# ===================================================== requests while coordinating
def test_a_higher_priority_request_drops_its_old_reply_and_is_asked_again() -> None:
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0) == []  # b was idle
    # b got a task of higher priority (a lower id): it plans first, so its answer is stale. My
    # request again is my answer: b holds it until it has planned, and takes my location from it.
    actions = proto.handle(request(ID_B_HIGH, "b"), 1)
    assert actions == [Send("b", request(ID_A, "a", 1))]
    assert "b" not in proto.received and "b" not in proto.pending
    # c answering no longer completes the round: b's answer was dropped
    assert proto.handle(CurrentTraj("c", location_of("c"), ID_A), 1) == []
    assert proto.state is State.COORDINATING
    b_plan = traj(2, (4, 4), (4, 3), (4, 2), (3, 2))
    action = started(confirmed(proto, proto.handle(CurrentTraj("b", b_plan, ID_A), 2)))
    assert action.psi["b"] == b_plan


def test_a_higher_priority_that_has_not_answered_is_neither_answered_nor_asked_again() -> None:
    """Two drones given tasks at once: b, ranked first, holds my request until it has planned, and
    takes my location from it. Answering or asking it again would only cost a message (one per
    pair of drones coordinating together)."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert proto.handle(request(ID_B_HIGH, "b"), 0) == []
    assert proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0) == []  # still waiting for b
    b_plan = traj(2, (4, 4), (4, 3), (4, 2), (3, 2))
    action = started(confirmed(proto, proto.handle(CurrentTraj("b", b_plan, ID_A), 1)))
    assert action.psi["b"] == b_plan


def test_a_requester_that_is_no_member_is_alive_and_a_member_again() -> None:
    """c was gone when my request went out and came back (or was seen gone while it lived on): its
    request proves it alive. It is a member again and gets my request, not an answer: answered at
    once, it planned with my location while I planned without it (found by the tester's crash and
    restart of an agent)."""
    proto = machine()
    proto.handle(PeerLeft("c"), 0)
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    first, second = TaskId(2, "c", 1), TaskId(3, "c", 2)
    told = Present("c", Trajectory.stationary(A, 1), False)
    assert proto.handle(request(first, "c"), 1) == [told, Send("c", request(ID_A, "a", 1))]
    assert "c" in proto.members and "c" in proto.ghosts  # held where it may be until it says where it is
    assert proto.handle(PeerJoined("c", C), 1) == [told]  # its return, noticed late: told again
    assert proto.handle(request(second, "c"), 1) == []
    assert proto.state is State.COORDINATING  # waiting for b, and for c's plan
    proto.handle(PeerLeft("b"), 1)
    assert proto.handle(request(ID_B_HIGH, "b"), 1) == [Present("b", Trajectory.stationary(A, 1), False),
                                                        Send("b", request(ID_A, "a", 1))]
    assert proto.state is State.COORDINATING and proto.members == {"b", "c"}


def test_a_lower_priority_request_is_its_answer_and_waits_for_my_new_trajectory() -> None:
    proto = machine({"a": A, "b": B, "c": C})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    c_way = traj(0, (0, 4), (1, 4))  # c's last plan, which it flew and rests at the end of
    assert proto.handle(request(ID_B_LOW, "b"), 0) == []
    assert proto.pending == {"b": ID_B_LOW} and proto.received == {"b": location_of("b")}
    [broadcast, *answers] = proto.handle(ReqForCurrentTraj(ID_C_LOW, "c", c_way, others("c")), 1)
    assert isinstance(broadcast, Broadcast) and isinstance(broadcast.message, PlanProposal)
    plan = broadcast.message.trajectory  # flown once b and c hold it
    # the waiting peers are answered as I propose: with where I am, and the proposal, held by them too
    here = Trajectory.stationary(A, 1)
    assert set(answers) == {Send("b", CurrentTraj("a", here, ID_B_LOW, (), broadcast.message)),
                            Send("c", CurrentTraj("a", here, ID_C_LOW, (), broadcast.message))}
    assert proto.pending == {}
    assert proto.state is State.CONFIRMING and proto.handle(PlanAck("b", ID_A, location_of("b")), 1) == []
    actions = proto.handle(PlanAck("c", ID_A, c_way), 1)
    assert started(actions).psi == {"b": location_of("b"), "c": c_way} and started(actions).trajectory == plan
    # it starts executing, and tells every peer
    assert actions == [started(actions), Broadcast(PlanDecision("a", ID_A, plan, flown=True))]


def test_a_lower_priority_request_from_a_departed_drone_makes_it_a_member_and_is_its_answer() -> None:
    """Its request proves it alive: a member again, asked, and its request is its answer."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(PeerLeft("c"), 0)
    assert proto.handle(request(ID_C_LOW, "c"), 0) == [Present("c", Trajectory.stationary(A, 0), False),
                                                       Send("c", request(ID_A, "a", 0))]
    assert proto.pending == {"c": ID_C_LOW} and "c" in proto.members
    assert proto.received["c"] == request(ID_C_LOW, "c").trajectory


# ============================================ late requests of rounds that are over
B_PLAN = traj(1, (4, 4), (4, 3), (4, 2))  # what b flew since its first request, and rests at the end of


def test_a_late_request_of_a_round_that_is_over_is_not_taken_for_a_higher_priority() -> None:
    """The deadlock of the issue tracker: b's request from its round that is over (ranking above mine)
    came after its request for the next one (ranking below). Taken as current, I dropped b's answer and
    asked it again, while b took my request as my answer: both waited for good."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 2)
    assert proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 2) == []  # b waits for my plan
    assert proto.handle(request(ID_B_HIGH, "b"), 2) == []  # late: neither asked again nor answered
    assert proto.pending == {"b": ID_B_NEXT} and proto.received == {"b": B_PLAN}
    actions = confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 2), ID_A), 2))
    action = started(actions)
    assert action.psi["b"] == B_PLAN
    assert [a.message.in_reply_to for a in actions if isinstance(a, Send) and isinstance(a.message, CurrentTraj)
            and a.message.proposal is not None and a.message.proposal.trajectory == action.trajectory] == [ID_B_NEXT]


def test_a_late_request_of_a_round_that_is_over_replaces_neither_the_answer_nor_the_id_to_answer() -> None:
    """Ranking below mine too, it would put where b was before its last plan in Psi, and have my plan
    answer a request b no longer waits on (b ignores that answer and waits for good)."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 2)
    proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 2)
    assert proto.handle(request(ID_B_LOW, "b"), 2) == []  # carrying b at B, before it flew B_PLAN
    assert proto.pending == {"b": ID_B_NEXT} and proto.received == {"b": B_PLAN}
    actions = confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 2), ID_A), 2))
    action = started(actions)
    assert action.psi["b"] == B_PLAN
    [answer] = [a.message for a in actions if isinstance(a, Send) and a.to == "b"]
    assert isinstance(answer, CurrentTraj) and answer.in_reply_to == ID_B_NEXT and answer.proposal is not None
    assert answer.proposal.trajectory == action.trajectory


def test_the_newest_request_is_remembered_across_states_and_rounds() -> None:
    """Idle, I answered b's newest request; its late older one gets no answer (b would ignore it), and
    coordinating later it is not taken for a higher priority's after b answered me (nor asked again)."""
    proto = machine()
    assert len(proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 1)) == 1
    assert proto.handle(request(ID_B_LOW, "b"), 1) == []
    mine = TaskId(10, "a", 1)  # my clock saw b's stamp: b's newest task ranks above mine
    proto.handle(NewTask(Task(mine, GOAL)), 2)
    assert proto.handle(CurrentTraj("b", B_PLAN, mine), 2) == []
    assert proto.handle(request(ID_B_HIGH, "b"), 2) == []
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 2), mine), 2)))
    assert action.psi["b"] == B_PLAN
    assert proto.handle(request(ID_B_LOW, "b"), 3) == []  # executing: still late


def test_a_drone_that_rejoins_has_its_ids_count_afresh() -> None:
    """It may have restarted, and its hybrid clock with it: its requests rank by its new ids."""
    proto = machine()
    proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 1)
    proto.handle(PeerLeft("b"), 2)
    proto.handle(PeerJoined("b", (4, 2, 0)), 3)
    restarted = TaskId(4, "b", 1)
    assert proto.handle(request(restarted, "b"), 4) == [
        Send("b", CurrentTraj("a", Trajectory.stationary(A, 4), restarted))]


def test_a_restarted_drones_request_is_current_before_its_join_is_seen() -> None:
    """Found by the systematic tester with a crash: the new agent's first request came before its
    join, with a lower stamp than its old agent's last one (its clock counts afresh). Dropped as late,
    the new agent waited for my answer for good. Its epoch says it is newer."""
    proto = machine()
    proto.handle(ReqForCurrentTraj(ID_B_NEXT, "b", B_PLAN, others("b")), 1)
    proto.handle(PeerLeft("b"), 2)
    restarted = TaskId(4, "b", 1, epoch=1)
    actions = proto.handle(request(restarted, "b"), 4)
    assert Send("b", CurrentTraj("a", Trajectory.stationary(A, 4), restarted)) in actions
    assert proto.handle(request(ID_B_LOW, "b"), 5) == []  # its old agent's: late


def test_a_request_that_does_not_wait_for_me_is_not_my_answer() -> None:
    """Found by the systematic tester with a crash and restart: b saw me leave and plans without me,
    so what its request carries may change before I plan. Taken as its answer, I planned with b's
    old location while b flew a new plan. I ask b instead (it admits me and answers)."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    without_me = ReqForCurrentTraj(ID_B_LOW, "b", location_of("b"), ("c",))
    assert proto.handle(without_me, 0) == [Send("b", request(ID_A, "a", 0))]
    assert "b" not in proto.received and proto.pending == {}
    proto.handle(CurrentTraj("c", location_of("c"), ID_A), 0)
    assert proto.state is State.COORDINATING  # still waits for b's own answer
    b_plan = traj(1, (4, 4), (4, 3))
    assert started(confirmed(proto, proto.handle(CurrentTraj("b", b_plan, ID_A), 1))).psi["b"] == b_plan


# ================================================= stale, duplicate and foreign replies
def test_a_reply_to_an_older_request_is_ignored() -> None:
    proto = machine({"a": A, "b": B})
    old = TaskId(1, "a", 0)
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    stale = traj(0, (4, 4), (4, 3), (4, 2), (4, 1), (4, 0))  # an old plan of b, ending on a's goal
    assert proto.handle(CurrentTraj("b", stale, old), 0) == []
    assert proto.state is State.COORDINATING and proto.received == {}
    action = started(confirmed(proto, proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)))
    assert action.psi == {"b": location_of("b")}


def test_a_reply_from_a_stranger_is_ignored() -> None:
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert proto.handle(CurrentTraj("z", Trajectory.stationary((2, 2, 0), 0), ID_A), 0) == []
    assert proto.state is State.COORDINATING


def test_a_duplicated_reply_is_harmless() -> None:
    reply_b = CurrentTraj("b", traj(1, (1, 2), (1, 1), (1, 0), (1, 1)), ID_A)
    reply_c = CurrentTraj("c", location_of("c"), ID_A)
    once, twice = machine(), machine()
    for proto in (once, twice):
        proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    once.handle(reply_b, 0)
    assert twice.handle(reply_b, 0) == [] and twice.handle(reply_b, 0) == []
    assert started(confirmed(twice, twice.handle(reply_c, 0))) == started(confirmed(once, once.handle(reply_c, 0)))
    assert twice.handle(reply_c, 0) == []  # late duplicate while executing
    assert twice.state is State.EXECUTING


# ========================================================== membership changes
def test_a_peer_leaving_is_no_longer_waited_for_but_its_whole_plan_stays_an_obstacle() -> None:
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    b_plan = traj(1, (4, 4), (4, 3), (4, 2), (4, 1))  # b answered, then lost its link
    proto.handle(CurrentTraj("b", b_plan, ID_A), 0)
    assert proto.handle(PeerLeft("b"), 1) == []  # still waiting for c
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 1)))
    # b may have stopped anywhere along its plan: each of its cells is held for good.
    held = {name: Trajectory.stationary(cell, 1) for name, cell in
            (("b#0", (4, 4, 0)), ("b#1", (4, 3, 0)), ("b#2", (4, 2, 0)), ("b", (4, 1, 0)))}
    assert action.psi == {**held, "c": location_of("c")}
    assert not set(action.trajectory.cells) & set(b_plan.cells)
    assert action.trajectory.last == GOAL
    assert check_trajectory(OPEN, action.trajectory, action.psi, 0) == []


def test_a_peer_leaving_long_after_its_plan_holds_only_where_it_ended() -> None:
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    b_plan = traj(1, (4, 4), (4, 3), (4, 2), (4, 1))  # done by step 4
    proto.handle(CurrentTraj("b", b_plan, ID_A), 0)
    assert proto.handle(PeerLeft("b"), 30) == []
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c"), ID_A), 30)))
    assert action.psi["b"].cells == ((4, 1, 0),)  # resting there, for good
    assert not any(name.startswith("b#") for name in action.psi)  # the cells it flew through are free again


def test_a_plan_heard_outside_a_round_is_where_a_departed_peer_may_have_stopped() -> None:
    proto = machine()
    b_plan = traj(10, (4, 4), (4, 3), (4, 2), (4, 1))
    proto.handle(PeerLeft("c"), 0)
    proto.heard("b", b_plan, 0)  # b announced it while this drone was idle
    proto.heard("b", traj(2, (0, 0)), 0)  # an older announcement, late: ignored
    proto.handle(PeerLeft("b", silent_since=11), 20)  # noticed at step 20, a lease after it went quiet
    proto.handle(NewTask(Task(ID_A, GOAL)), 20)
    held = {t.cells[0] for name, t in proto.ghost_obstacles().items() if name.startswith("b")}
    assert held == {(4, 4, 0), (4, 3, 0), (4, 2, 0), (4, 1, 0)}  # from step 11 - lead on: all of it


def test_a_drone_resting_where_a_departed_peer_flew_through_can_still_leave() -> None:
    """Seen in a fleet test: b flew through (2, 0); a came to rest there after it; b died and was
    noticed a lease later, so its whole plan was held for good, a's own cell included: a found
    no plan ever again. Had b stopped there, they would have met: a's cell is spared, the others not."""
    peers = {"a": (2, 0, 0), "b": (3, 1, 0), "c": C}
    proto = machine(peers)
    b_plan = traj(1, (3, 1), (2, 1), (2, 0), (1, 0), (1, 1))  # through a's cell at step 3, done by step 5
    proto.heard("b", b_plan, 0)
    proto.handle(PeerLeft("b", silent_since=0), 6)  # b's rest of plan: all of it
    proto.handle(NewTask(Task(ID_A, GOAL)), 6)
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", location_of("c", 6), ID_A), 6)))
    held = {t.cells[0] for name, t in action.psi.items() if name.startswith("b")}
    assert held == {(3, 1, 0), (2, 1, 0), (1, 0, 0), (1, 1, 0)}  # all of b's plan but a's own cell
    assert action.trajectory.cells[0] == (2, 0, 0) and action.trajectory.last == GOAL
    assert not set(action.trajectory.cells[1:]) & held
    assert check_trajectory(OPEN, action.trajectory, action.psi, action.trajectory.start_step) == []


def test_the_last_awaited_peer_leaving_lets_it_plan_with_its_last_known_trajectory() -> None:
    proto = machine({**STARTS, "d": (2, 4, 0)})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("d", Trajectory.stationary((2, 4, 0), 0), ID_A), 0)
    proto.handle(request(ID_C_LOW, "c"), 0)  # c waits for a's plan, its request its answer ...
    proto.handle(PeerLeft("c"), 1)  # ... then leaves
    actions = confirmed(proto, proto.handle(PeerLeft("b"), 1))  # b leaves before answering
    action = started(actions)
    # where they were last known, for good
    assert {p: action.psi[p] for p in "bc"} == {"b": Trajectory.stationary(B, 0), "c": Trajectory.stationary(C, 0)}
    assert not any(isinstance(a, Send) for a in actions)  # a departed drone is not answered
    assert proto.handle(PeerLeft("c"), 1) == []  # leaving twice changes nothing


@pytest.mark.parametrize(("fleet", "in_touch", "plans"), [
    ("abc", "a", False), ("abc", "ab", True), ("abc", "bc", True),
    ("ab", "a", True), ("ab", "b", False),  # half the fleet: the side with its first drone
    ("abcd", "ab", True), ("abcd", "cd", False), ("abcd", "abc", True),
])
def test_a_drone_plans_only_in_touch_with_most_of_the_fleet(fleet: str, in_touch: str, plans: bool) -> None:
    """Both sides of a partition see the other leave: were both to plan, each around where it last knew
    the other, they could plan into one cell. Only a majority (half, with the first drone) plans on."""
    cells = {d: (i, 4, 0) for i, d in enumerate(fleet)}
    me = in_touch[0]
    proto = machine(cells, me=me)
    for gone in set(fleet) - set(in_touch):
        proto.handle(PeerLeft(gone), 0)
    task = Task(TaskId(5, me, 1), (4, 0, 0))
    actions = confirmed(proto, proto.handle(NewTask(task), 0)
                        + [a for p in in_touch[1:]
                           for a in proto.handle(CurrentTraj(p, Trajectory.stationary(cells[p], 0), task.id), 0)])
    failed = [a for a in actions if isinstance(a, TaskFailed)]
    assert bool([a for a in actions if isinstance(a, StartExecuting)]) is plans
    assert [f.reason for f in failed] == ([] if plans else [f"in touch with {len(in_touch)} of the fleet's "
                                                           "drones: no majority"])


def test_a_peer_joining_during_coordination_is_asked_and_waited_for() -> None:
    proto = machine({"a": A, "b": B})
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    told = Present("c", Trajectory.stationary(A, 1), False)
    assert proto.handle(PeerJoined("c", C), 1) == [told, Send("c", request(ID_A, "a", 1))]
    assert proto.handle(PeerJoined("c", C), 1) == [told]  # already a member: told again, not asked
    assert proto.handle(CurrentTraj("b", location_of("b"), ID_A), 1) == []  # still waiting for c
    c_plan = traj(2, (0, 4), (0, 3), (1, 3))
    action = started(confirmed(proto, proto.handle(CurrentTraj("c", c_plan, ID_A), 2)))
    assert action.psi == {"b": location_of("b"), "c": c_plan}


def test_a_peer_joining_while_idle_is_asked_at_the_next_task() -> None:
    proto = machine({"a": A})
    assert proto.handle(PeerJoined("b", B), 0) == [Present("b", Trajectory.stationary(A, 0), False)]
    actions = proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    assert actions == [Broadcast(ReqForCurrentTraj(ID_A, "a", location_of("a"), ("b",)))]  # it waits for b now
    answered = proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)
    assert started(confirmed(proto, answered)).psi == {"b": location_of("b")}


def test_a_request_of_a_round_whose_plan_was_decided_is_late_even_after_a_rejoin() -> None:
    """Found by a partition sweep (seed 9201): b's decision made it a member again (and forgot its newest
    request, as a join does); b's request of that same round came after, was taken as current, and
    put where b was before that plan in my Psi."""
    proto = machine()
    proto.handle(PeerLeft("b"), 0)
    b_plan = traj(3, (4, 4), (3, 4), (2, 4))
    proto.handle(PlanDecision("b", ID_B_LOW, b_plan, flown=True), 1)
    assert "b" in proto.members and proto.known["b"] == b_plan
    proto.handle(NewTask(Task(ID_A, GOAL)), 1)
    proto.handle(CurrentTraj("b", b_plan, ID_A), 1)
    assert proto.handle(request(ID_B_LOW, "b"), 1) == []  # late: its plan is decided
    assert proto.received["b"] == b_plan and "b" not in proto.pending


def test_a_round_asks_again_twice_as_late_each_time_up_to_a_bound() -> None:
    """128 drones on two cores: answers came later than the round waited, every waiting drone asked
    every silent member again every 4 steps, and the asking took all the CPU (4 plans in 300 s). A
    round waiting still asks again, each time twice as late as the last, up to ASK_AGAIN_MOST_STEPS."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    asked = [step for step in range(1, 100) if proto.handle(NextStep(), step)]
    waits = [b - a for a, b in itertools.pairwise([0, *asked])]
    assert waits[:5] == [ASK_AGAIN_STEPS, 2 * ASK_AGAIN_STEPS, 4 * ASK_AGAIN_STEPS, ASK_AGAIN_MOST_STEPS,
                         ASK_AGAIN_MOST_STEPS]
    assert set(waits[3:]) == {ASK_AGAIN_MOST_STEPS}


def test_a_round_asks_again_the_members_that_have_not_answered() -> None:
    """Seen once over real processes: a round waited for good after a partition healed (most likely a
    request or answer lost while the link's routes came back). Every few steps the silent members are
    asked again."""
    proto = machine()
    proto.handle(NewTask(Task(ID_A, GOAL)), 0)
    proto.handle(CurrentTraj("b", location_of("b"), ID_A), 0)  # c's answer is lost
    assert [proto.handle(NextStep(), step) for step in range(1, ASK_AGAIN_STEPS)] == [[]] * (ASK_AGAIN_STEPS - 1)
    assert proto.handle(NextStep(), ASK_AGAIN_STEPS) == [Send("c", request(ID_A, "a", ASK_AGAIN_STEPS))]
    planned = proto.handle(CurrentTraj("c", location_of("c"), ID_A), ASK_AGAIN_STEPS)
    assert proto.state is State.CONFIRMING and isinstance(planned[0], Broadcast)
