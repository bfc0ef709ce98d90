"""Safety counterexamples the systematic tester found, replayed over the production protocol machines."""

from __future__ import annotations

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import CurrentTraj, Task
from drona_gcs.stack.protocol import (
    Braked,
    ClockBound,
    NewTask,
    NextStep,
    PeerAnnounced,
    PeerDown,
    PeerLeft,
    PeerLost,
    Threatened,
)
from tests.drona_gcs.stack.protocol_helpers import (
    ID_C_LOW,
    B,
    confirmed,
    flying_past_b,
    location_of,
    machine,
    started,
    traj,
)

B_OLD_PLAN = traj(8, (4, 4), (4, 3), (4, 2), (4, 1))  # b's plan, decided before its vehicle came down in B


def test_news_of_a_vehicle_down_across_a_heal_is_not_undone_by_an_older_announcement() -> None:
    """Found by sweep seed 30362 (seed 951743, a partition): c saw b leave across a cut; once it healed,
    b's vehicle came down in B and c heard so, then heard b's older announcement of the plan it had
    decided before, and an answer of that plan overtaken by its answer from B. That announcement, taken
    as b's first word since it was back, made c forget the vehicle down, and c planned around b leaving
    B at step 8 while b stays there for good. The news of a vehicle down is b's word (it proves b
    alive as any message of its does): what came from b before it cannot undo it."""
    proto = machine(me="c")
    proto.handle(PeerLeft("b", silent_since=0), 0)
    proto.handle(PeerDown("b", B), 1)
    proto.handle(PeerAnnounced("b", B_OLD_PLAN), 1)  # sent before its vehicle came down
    assert proto.peers_down == {"b": B}
    actions = proto.handle(NewTask(Task(ID_C_LOW, (4, 0, 0))), 2)
    actions += proto.handle(CurrentTraj("b", Trajectory.stationary(B, 1), ID_C_LOW), 2)
    actions += proto.handle(CurrentTraj("b", B_OLD_PLAN, ID_C_LOW), 2)  # its answer to an earlier ask, late
    actions += proto.handle(CurrentTraj("a", location_of("a"), ID_C_LOW), 2)
    psi = started(confirmed(proto, actions)).psi
    assert set(psi["b"].cells) == {B}
    assert set(psi["b!"].cells) == {B}


def test_news_of_a_vehicle_lost_across_a_heal_is_not_undone_by_an_older_announcement() -> None:
    """As above with b's vehicle lost: where it may be stays held, whatever older plan of b's comes late."""
    proto = machine(me="c")
    proto.handle(PeerLeft("b", silent_since=0), 0)
    proto.handle(PeerLost("b", (B, (4, 3, 0))), 1)
    proto.handle(PeerAnnounced("b", B_OLD_PLAN), 1)  # sent before its vehicle was lost
    assert proto.peers_lost == {"b": (B, (4, 3, 0))} and "b" in proto.members


def test_a_peer_off_that_says_it_rests_keeps_the_cells_of_the_plan_it_flew_held() -> None:
    """Found by sweep seed 30391 (--skews 1, seed 758944): d5 flew through a cell of the plan of d0, whose
    clock was found off; its rest could not be planned anew, so it flew on. d0 then said it rested at
    its plan's end; d5 took that for all d0 held, and entered the cell d0 had left one step before by
    d5's clock, in steps d0's clock does not keep with d5's. What a drone off flew stays held."""
    for gone_meanwhile in (False, True):  # found in review: b's word as it came back undid the hold too
        proto, plan = flying_past_b()
        assert plan.at(5) == (3, 0, 0)
        assert proto.handle(ClockBound(mine_off=False, outliers=frozenset({"b"})), 2) == [
            Threatened("b", ((3, 0, 0),))]
        if gone_meanwhile:
            proto.handle(PeerLeft("b", silent_since=2), 2)
        proto.handle(PeerAnnounced("b", Trajectory.stationary((3, 1, 0), 3)), 3)  # b rests, by its clock
        actions = proto.handle(NextStep(), 4)  # the step before (3, 0)
        assert [type(a) for a in actions] == [Braked], gone_meanwhile
        assert proto.trajectory is not None and (3, 0, 0) not in proto.trajectory.cells
