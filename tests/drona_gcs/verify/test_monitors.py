"""The systematic tester's monitors: what is a violation of order, consistency and separation,
and what is not (a drone that stops short of a held cell, mail on board answering a way asked).
"""

from __future__ import annotations

import contextlib

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.stack.mail import MailPickedUp, MailRequest, MailStarted
from drona_gcs.stack.messages import PlanAck, Task, TaskId
from drona_gcs.stack.protocol import Braked, Grounded, Present, Send, StartExecuting
from drona_gcs.verify.explore import Explorer, Scenario, Strategy
from drona_gcs.verify.monitors import Monitors, Violation
from drona_gcs.verify.world import WorldConfig
from drona_gcs.workspace import Cell, Workspace


def test_a_reversed_mail_rank_is_found_by_the_order_monitor(monkeypatch: pytest.MonkeyPatch) -> None:
    """Monitor (c) ranks mail in its own code: a mutant that reverses the production rank (least urgent
    first) is found, where an oracle using that rank would reverse with it."""
    monkeypatch.setattr(MailRequest, "rank", property(lambda r: (r.priority, -r.seq)))
    outcome = Explorer(Scenario(drones=2, requests=6, delta=1, seed=0)).run(Strategy.RANDOM, schedules=50,
                                                                          max_depth=4000, seed=1)
    assert outcome.violation is not None and outcome.violation.monitor == "c", str(outcome.violation)


def test_a_plan_made_without_a_peer_is_found_by_the_consistency_monitor(monkeypatch: pytest.MonkeyPatch) -> None:
    """Monitor (a) takes each drone's commitment from what it started executing, not from the protocol: a
    mutant that leaves a peer out of Psi (it plans as if that drone were not there) is found."""
    real = StartExecuting.__init__

    def forget_a_peer(self: StartExecuting, task: object, trajectory: object, psi: dict[str, object]) -> None:
        real(self, task, trajectory, dict(list(psi.items())[1:]))  # type: ignore[arg-type]

    monkeypatch.setattr(StartExecuting, "__init__", forget_a_peer)
    outcome = Explorer(Scenario(drones=3, requests=4, delta=1, seed=0)).run(Strategy.RANDOM, schedules=5,
                                                                          max_depth=4000, seed=1)
    assert outcome.violation is not None and outcome.violation.monitor == "a", str(outcome.violation)


@pytest.mark.parametrize("rests_on_pickup", [True, False])
def test_the_order_monitor_lets_urgent_mail_wait_while_a_drone_rests_on_its_pickup(rests_on_pickup: bool) -> None:
    """(c): no path is open to a pickup another drone rests on (a vehicle down, for good perhaps),
    so less urgent mail may go first; with the pickup free, it may not."""
    ws = Workspace.build(size=(5, 3, 1))
    urgent, later = MailRequest("u", (2, 2, 0), (4, 2, 0), 9), MailRequest("l", (1, 0, 0), (3, 0, 0), 1, seq=1)
    peer = (2, 2, 0) if rests_on_pickup else (0, 2, 0)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), peer), (urgent, later), ("d0", "d0"), delta=0)
    monitors = Monitors(config)
    monitors.given_mail("d0", urgent)
    monitors.given_mail("d0", later)
    start = MailStarted(later, (urgent,))
    if rests_on_pickup:
        monitors.action("d0", start)
    else:
        with pytest.raises(Violation, match=r"\(c\) d0 started mail l"):
            monitors.action("d0", start)


@pytest.mark.parametrize("asked", [True, False])
def test_mail_on_board_flies_off_a_way_only_when_asked_to(asked: bool) -> None:
    """(f): besides its drop-off and a charger, mail on board flies only off a way a peer asked the
    drone to leave, to a cell off that way."""
    ws = Workspace.build(size=(5, 3, 1))
    request = MailRequest("m", (0, 0, 0), (4, 2, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (4, 0, 0)), (request,), ("d0",), delta=0)
    monitors = Monitors(config)
    monitors.action("d0", MailPickedUp(request))
    if asked:
        monitors.asked_to_leave("d0", ((1, 0, 0), (0, 0, 0), (0, 1, 0)))
    off = Trajectory(3, ((0, 0, 0), (1, 0, 0), (1, 1, 0)))
    leave = StartExecuting(Task(TaskId(3, "d0", 2), (1, 1, 0)), off, {"d1": Trajectory(0, ((4, 0, 0),))})
    if asked:
        monitors.action("d0", leave)
    else:
        with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):
            monitors.action("d0", leave)


def test_mail_on_board_may_answer_any_way_asked_since_its_last_plan() -> None:
    """(f): a drone asked by two peers, that leaves the first one's way for a cell on the second's,
    still flies off a way it was asked to leave (sweep seed 5150, scenario 327244)."""
    ws = Workspace.build(size=(5, 3, 1))
    request = MailRequest("m", (0, 0, 0), (4, 2, 0), 5)
    config = WorldConfig(ws, ("d0", "d1", "d2"), ((0, 0, 0), (4, 0, 0), (4, 2, 0)), (request,), ("d0",), delta=0)
    monitors = Monitors(config)
    monitors.action("d0", MailPickedUp(request))
    monitors.asked_to_leave("d0", ((0, 0, 0), (0, 1, 0), (0, 2, 0)))
    monitors.asked_to_leave("d0", ((2, 0, 0), (1, 0, 0), (0, 0, 0)))
    off = Trajectory(3, ((0, 0, 0), (1, 0, 0)))
    others = {"d1": Trajectory(0, ((4, 0, 0),)), "d2": Trajectory(0, ((4, 2, 0),))}
    monitors.action("d0", StartExecuting(Task(TaskId(3, "d0", 2), (1, 0, 0)), off, others))
    with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):  # the ways asked end with the plan
        monitors.action("d0", StartExecuting(Task(TaskId(6, "d0", 3), (1, 1, 0)),
                                             Trajectory(6, ((1, 0, 0), (1, 1, 0))), others))


@pytest.mark.parametrize("rest_at", [(2, 0, 0), (1, 0, 0)])
def test_a_rest_said_at_the_end_of_a_plan_stands_for_that_plan_and_nowhere_else(rest_at: Cell) -> None:
    """(a): a drone whose clock is off says it rests once its plan ends (sweep 20182 with --skews 2); a
    plan made with that rest is made with what it is committed to. A rest said elsewhere is no such thing."""
    ws = Workspace.build(size=(5, 3, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 2, 0), (0, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    flown = Trajectory(1, ((0, 0, 0), (1, 0, 0), (2, 0, 0)))
    monitors.action("d1", StartExecuting(Task(TaskId(1, "d1", 1), (2, 0, 0)), flown,
                                         {"d0": Trajectory(0, ((0, 2, 0),))}))
    rest = Trajectory.stationary(rest_at, 3)
    if rest_at != flown.last:
        with pytest.raises(Violation, match=r"\(a\) d1 says it rests"):
            monitors.action("d1", Present("d0", rest, braked=False))
        return
    monitors.action("d1", Present("d0", rest, braked=False))
    monitors.action("d0", StartExecuting(Task(TaskId(2, "d0", 2), (4, 2, 0)),  # d0's clock behind d1's
                                         Trajectory(2, ((0, 2, 0), (1, 2, 0))), {"d1": rest}))


@pytest.mark.parametrize("told, collides", [(None, False), (1, False), (0, True)])
def test_a_drone_may_not_enter_a_vehicle_downs_cell_once_told(told: int | None, collides: bool) -> None:
    """(b): a vehicle that comes down where another drone's plan enters next is no protocol's to avoid
    before the news comes; told at its step s, a drone must not be in that cell at s + 1."""
    ws = Workspace.build(size=(5, 1, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (2, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    monitors.vehicle_down("d1", (2, 0, 0), 0)
    if told is not None:
        monitors.heard_news("d0", "d1", told)
    flown = {"d0": [(1, 0, 0), (2, 0, 0), (2, 0, 0), (2, 0, 0)], "d1": [(2, 0, 0)] * 4}
    steps = {"d0": 0, "d1": 0}
    with pytest.raises(Violation, match=r"\(b\) d0 and d1: collision") if collides else contextlib.nullcontext():
        for step in range(4):
            for drone in ("d0", "d1"):
                steps[drone] = step
                monitors.position(drone, step, flown[drone][step], steps, flies=False)


def test_a_drone_that_stops_where_it_stands_short_of_a_held_cell_is_no_violation() -> None:
    """Found by sweep 9914: d0, carrying mail, had not left its first cell when a departed peer came to
    hold a cell of its plan; it stopped where it stood. Monitor (f) compared the plans only as long as
    the new one, a single cell, so it saw nothing made new and called the stop a detour."""
    scenario = Scenario(drones=6, requests=8, delta=1, seed=625805, grid=(8, 8, 1), obstacles=0.0, crashes=1,
                        partitions=1, max_delay=2)
    outcome = Explorer(scenario).run(Strategy.PCT, schedules=20, max_depth=5000, seed=625805)
    assert outcome.violation is None, str(outcome.violation)


def test_a_drone_that_stops_short_of_a_plan_it_last_knew_of_a_departed_peer_is_no_violation() -> None:
    """Found by sweep 10012: d4, cut off, braked short of a cell, and nobody heard; d1 then saw d4 leave
    and stopped short of the plan of d4's it knew. Monitor (f) judged the stop against d4's brake, which
    d1 could not know, and called it a detour."""
    scenario = Scenario(drones=5, requests=6, delta=2, seed=76641, grid=(8, 8, 1), obstacles=0.2, crashes=1,
                        partitions=1)
    outcome = Explorer(scenario).run(Strategy.PCT, schedules=80, max_depth=5000, seed=76641)
    assert outcome.violation is None, str(outcome.violation)


@pytest.mark.parametrize("d1_flies", [
    ((5, 1, 0), (5, 0, 0)),  # rests in (5, 0, 0), on d0's way, from step 6 (found in a sweep, seed 20072)
    ((5, 0, 0), (5, 1, 0)),  # crossed (5, 0, 0) at step 5, then silent (found in a sweep, seed 20092)
], ids=["rests-on-the-way", "crossed-the-way"])
def test_a_stop_short_of_a_cell_a_departed_drone_may_hold_is_no_detour(d1_flies: tuple[Cell, ...]) -> None:
    """Found by the tester under a partition: d1 was cut off, and d0 stopped short of a cell of d1's last
    plan, which d1 may hold for good. Monitor (f) took d1's cells only from shortly before the step where
    d0's new plan parts from the old one to d1's plan's end: it missed the cell d1 rests in after that end,
    and the cells d1's plan crossed before, and called the stop a detour."""
    ws = Workspace.build(size=(8, 8, 1))
    request = MailRequest("m", (0, 0, 0), (7, 0, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (5, 1, 0)), (request,), ("d0",), delta=1, liveness_steps=0)
    short = StartExecuting(Task(TaskId(12, "d0", 2), (7, 0, 0)), Trajectory(10, tuple((x, 0, 0) for x in range(4))),
                           {})  # parts from the old plan at step 14, in (3, 0, 0)

    def judged(saw_d1_leave: bool) -> None:
        monitors = Monitors(config)
        monitors.committed["d0"] = Trajectory(10, tuple((x, 0, 0) for x in range(8)))  # to the drop-off
        monitors.committed["d1"] = Trajectory(5, d1_flies)
        monitors.carrying["d0"] = request
        if saw_d1_leave:
            monitors.left("d0", "d1")
        monitors._carried_to_its_dropoff("d0", short)

    judged(saw_d1_leave=True)
    with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):  # nothing held for good on the way
        judged(saw_d1_leave=False)


@pytest.mark.parametrize("news", ["braked", "grounded", "off", "none"])
def test_a_stop_short_of_where_a_peer_braked_or_grounded_itself_is_no_detour(news: str) -> None:
    """Found by sweeps 20191 and 20201 with --skews 1: d1 braked (or, its battery spent, grounded itself)
    on the way to d0's drop-off, or was found off with a plan there before its last; d0 stopped short of
    it. Monitor (f) held only vehicles down, departed drones and the last plans of clocks off, and
    called the stop a detour."""
    ws = Workspace.build(size=(8, 8, 1))
    request = MailRequest("m", (0, 0, 0), (7, 0, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (5, 1, 0)), (request,), ("d0",), delta=1, liveness_steps=0)
    monitors = Monitors(config)
    monitors.committed["d0"] = Trajectory(10, tuple((x, 0, 0) for x in range(8)))  # to the drop-off
    monitors.committed["d1"] = Trajectory(5, ((5, 1, 0), (5, 0, 0)))
    monitors.carrying["d0"] = request
    if news == "braked":
        monitors.action("d1", Braked(Trajectory(5, ((5, 1, 0), (5, 0, 0), (5, 0, 0))), (5, 1, 0)))
    elif news == "grounded":
        monitors.action("d1", Grounded(Trajectory.stationary((5, 0, 0), 6)))
    elif news == "off":  # found off after a plan since (sweep 20201): d0 may not know of that one yet
        later = Trajectory(7, ((5, 1, 0), (5, 2, 0)))
        psi = {"d0": monitors.committed["d0"]}
        monitors.action("d1", StartExecuting(Task(TaskId(6, "d1", 2), (5, 0, 0)), monitors.committed["d1"], psi))
        monitors.action("d1", StartExecuting(Task(TaskId(7, "d1", 3), (5, 2, 0)), later, psi))
        monitors.clock_verdict("d0", frozenset({"d1"}))
    monitors.heard_news("d0", "d1", 11)
    short = StartExecuting(Task(TaskId(12, "d0", 2), (7, 0, 0)), Trajectory(10, tuple((x, 0, 0) for x in range(4))),
                           {})  # parts from the old plan at step 14, in (3, 0, 0)
    if news == "none":
        with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):
            monitors._carried_to_its_dropoff("d0", short)
    else:
        monitors._carried_to_its_dropoff("d0", short)


@pytest.mark.parametrize("braked", [False, True])
def test_a_plan_made_against_a_proposal_counts_until_its_drone_flies_something_else(braked: bool) -> None:
    """(a): d0 planned against d1's proposal, held besides where d1 was; d1's plan, started after,
    was made with d0 where it was: it keeps clear of d0's plan, which was made against it. Once d0
    flies something else (it braked) and d1 has heard of it, that no longer holds, and d1 planned with
    a stale d0."""
    ws = Workspace.build(size=(5, 3, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 2, 0), (0, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    d1_plan = Trajectory(3, ((0, 0, 0), (1, 0, 0), (2, 0, 0)))
    d0_plan = Trajectory(3, ((0, 2, 0), (1, 2, 0), (2, 2, 0)))
    monitors.action("d0", StartExecuting(Task(TaskId(1, "d0", 1), (2, 2, 0)), d0_plan,
                                         {"d1": Trajectory(0, ((0, 0, 0),)), "d1?": d1_plan}))
    if braked:
        monitors.action("d0", Braked(Trajectory(3, ((0, 2, 0), (1, 2, 0))), (2, 2, 0)))
        monitors.heard_news("d1", "d0", 3)
    start_d1 = StartExecuting(Task(TaskId(2, "d1", 1), (2, 0, 0)), d1_plan, {"d0": Trajectory(0, ((0, 2, 0),))})
    with pytest.raises(Violation, match=r"\(a\) d1 planned task .* with a stale trajectory of d0") if braked \
            else contextlib.nullcontext():
        monitors.action("d1", start_d1)


@pytest.mark.parametrize("anew", ["the same plan", "another plan"])
def test_a_plan_made_against_a_peers_answer_counts_while_that_peer_flies_it(anew: str) -> None:
    """(a), found by the tester (sweep 30630, a clock off): d1 planned anew the plan it flew and came to
    that very plan, which it had answered d0 with (no proposal held apart: the two were one). d0's plan,
    made against it, counts as made against d1's plan; against another plan, d1 used a stale d0."""
    ws = Workspace.build(size=(5, 3, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 2, 0), (0, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    d0_start = Trajectory(0, ((0, 2, 0),))
    d1_plan = Trajectory(3, ((0, 0, 0), (1, 0, 0), (2, 0, 0)))
    monitors.action("d1", StartExecuting(Task(TaskId(1, "d1", 1), (2, 0, 0)), d1_plan, {"d0": d0_start}))
    d0_plan = Trajectory(4, ((0, 2, 0), (1, 2, 0), (2, 2, 0)))
    monitors.action("d0", StartExecuting(Task(TaskId(2, "d0", 1), (2, 2, 0)), d0_plan, {"d1": d1_plan}))
    d1_new = d1_plan if anew == "the same plan" else Trajectory(3, ((0, 0, 0), (0, 1, 0), (1, 1, 0)))
    start_d1 = StartExecuting(Task(TaskId(2, "d1", 2), d1_new.last, hovering_since=2), d1_new, {"d0": d0_start})
    with pytest.raises(Violation, match=r"\(a\) d1 planned task .* with a stale trajectory of d0") \
            if anew == "another plan" else contextlib.nullcontext():
        monitors.action("d1", start_d1)


@pytest.mark.parametrize("held_at", [(2, 0, 0), (1, 0, 0)])
def test_a_rest_held_from_another_step_is_the_same_rest(held_at: Cell) -> None:
    """(a): found by sweep 30513 (--skews 1): d1, its clock ahead, said it rests from its step 3; d0 heard
    of it at its own step 1 and held d1 there from then. The same positions: no stale trajectory. A rest
    held elsewhere is one."""
    ws = Workspace.build(size=(5, 3, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 2, 0), (0, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    monitors.action("d1", StartExecuting(Task(TaskId(1, "d1", 1), (2, 0, 0)),
                                         Trajectory(1, ((0, 0, 0), (1, 0, 0), (2, 0, 0))),
                                         {"d0": Trajectory(0, ((0, 2, 0),))}))
    monitors.action("d1", Present("d0", Trajectory.stationary((2, 0, 0), 3), braked=False))
    start_d0 = StartExecuting(Task(TaskId(2, "d0", 2), (4, 2, 0)), Trajectory(2, ((0, 2, 0), (1, 2, 0))),
                              {"d1": Trajectory.stationary(held_at, 1)})
    with pytest.raises(Violation, match=r"\(a\) d0 planned task .* with a stale trajectory of d1") \
            if held_at != (2, 0, 0) else contextlib.nullcontext():
        monitors.action("d0", start_d0)


@pytest.mark.parametrize("case", ["views met", "not held as gone", "held before", "plans meet"])
def test_a_plan_held_by_a_peer_that_planned_it_gone_is_checked_where_the_views_met(case: str) -> None:
    """(a): found by sweep 30522 (--partitions 1 --crashes 1). d1 saw d0 leave and planned without it; d0,
    which still had d1 in line, planned with where d1 asked from, and flew once d1 held its plan while
    flying its own: the views met at d1, and the two plans keep clear. Stale, though, if d1 planned with
    d0 in view, if it held d0's plan before it made its own, or if the plans meet."""
    ws = Workspace.build(size=(5, 3, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 2, 0), (0, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    d0_task = TaskId(1, "d0", 1)
    d1_plan = Trajectory(3, ((0, 0, 0), (1, 0, 0), (2, 0, 0)))
    on_to_d1 = ((2, 1, 0), (2, 0, 0)) if case == "plans meet" else ()
    d0_plan = Trajectory(3, ((0, 2, 0), (1, 2, 0), (2, 2, 0), *on_to_d1))
    ack = Send("d0", PlanAck("d1", d0_task, d1_plan))
    if case != "not held as gone":
        monitors.left("d1", "d0")
    if case == "held before":
        monitors.action("d1", ack)
    monitors.action("d1", StartExecuting(Task(TaskId(1, "d1", 1), (2, 0, 0)), d1_plan,
                                         {"d0": Trajectory(0, ((0, 2, 0),))}))
    if case != "held before":
        monitors.action("d1", ack)
    start_d0 = StartExecuting(Task(d0_task, (2, 2, 0)), d0_plan, {"d1": Trajectory(0, ((0, 0, 0),))})
    with pytest.raises(Violation, match=r"\(a\) d0 planned task .* with a stale trajectory of d1") \
            if case != "views met" else contextlib.nullcontext():
        monitors.action("d0", start_d0)


@pytest.mark.parametrize("told", [False, True])
@pytest.mark.parametrize("used", ["its proposal", "made against mine"])
def test_a_plan_a_peer_cut_short_since_counts_until_the_news_comes(used: str, told: bool) -> None:
    """(a): found by sweep 30524 (--skews 1). d1 flew a plan and braked (its clock went off) before d0 heard
    of it. d0's plan held d1's proposal of that plan besides where d1 was, or d1's plan had been made
    against d0's proposal: either was fine until the news of the brake reached d0, not after."""
    ws = Workspace.build(size=(5, 3, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 2, 0), (0, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    d0_plan = Trajectory(3, ((0, 2, 0), (1, 2, 0), (2, 2, 0)))
    d1_plan = Trajectory(3, ((0, 0, 0), (1, 0, 0), (2, 0, 0)))
    held = {"d1?": d1_plan} if used == "its proposal" else {}
    made_against = {"d0?": d0_plan} if used == "made against mine" else {}
    monitors.action("d1", StartExecuting(Task(TaskId(1, "d1", 1), (2, 0, 0)), d1_plan,
                                         {"d0": Trajectory(0, ((0, 2, 0),)), **made_against}))
    monitors.action("d1", Braked(Trajectory(3, ((0, 0, 0), (1, 0, 0))), (2, 0, 0)))
    if told:
        monitors.heard_news("d0", "d1", 3)
    start_d0 = StartExecuting(Task(TaskId(1, "d0", 1), (2, 2, 0)), d0_plan,
                              {"d1": Trajectory(0, ((0, 0, 0),)), **held})
    with pytest.raises(Violation, match=r"\(a\) d0 planned task .* with a stale trajectory of d1") \
            if told else contextlib.nullcontext():
        monitors.action("d0", start_d0)
