"""Safety counterexamples the systematic tester found, replayed over the production protocol machines."""

from __future__ import annotations

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import CurrentTraj, Task
from drona_gcs.stack.protocol import NewTask, PeerAnnounced, PeerDown, PeerLeft, PeerLost
from tests.drona_gcs.stack.protocol_helpers import ID_C_LOW, B, confirmed, location_of, machine, started, traj

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
