"""The in-memory network shared by the systematic tester and ProtocolCluster: how it holds and hands out messages."""

from __future__ import annotations

from drona_gcs.verify.network import Joined, Left, Network


def test_any_message_may_come_next_and_each_comes_once() -> None:
    net: Network[str] = Network()
    first, second = net.post("a", "b", "hello"), net.post("b", "a", "hi")
    assert (first.seq, second.seq, net.sent) == (1, 2, 2)
    assert net.deliverable() == [first, second]
    assert net.take(second.seq) == second  # the newest first: a bag, not a queue
    assert list(net) == [first] and len(net) == 1


def test_a_leave_comes_after_what_its_sender_sent_before_it_and_before_what_it_sent_after() -> None:
    net: Network[object] = Network()
    before = net.post("a", "b", "plan")
    other = net.post("c", "b", "plan")
    leave = net.post("a", "b", Left(3))
    after = net.post("a", "b", "late")
    assert net.deliverable() == [before, other]
    net.take(before.seq)
    assert net.deliverable() == [other, leave]
    net.take(leave.seq)
    assert net.deliverable() == [other, after]


def test_a_duplicate_keeps_its_originals_place_before_a_leave() -> None:
    net: Network[object] = Network()
    original = net.post("a", "b", "plan")
    leave = net.post("a", "b", Left(0))
    copy = net.duplicate(original.seq)
    assert (copy.seq, copy.sent_as, copy.message) == (3, original.seq, "plan")
    net.take(original.seq)
    assert net.deliverable() == [copy]  # the leave waits for the copy too
    net.take(copy.seq)
    assert net.deliverable() == [leave]


def test_liveliness_changes_come_in_order() -> None:
    net: Network[object] = Network()
    leave, join = net.post("a", "b", Left(0)), net.post("a", "b", Joined())
    assert net.deliverable() == [leave]
    net.take(leave.seq)
    assert net.deliverable() == [join]


def test_what_is_dropped_is_lost_and_the_key_forgets_numbers_and_order() -> None:
    net: Network[str] = Network()
    for to in "bcd":
        net.post("a", to, "plan", deadline=4)
    lost = net.drop(lambda m: m.to == "d")
    assert [m.to for m in lost] == ["d"] and [m.to for m in net] == ["b", "c"]
    other: Network[str] = Network()
    other.take(other.post("x", "y", "noise").seq)
    for to in "cb":
        other.post("a", to, "plan", deadline=4)
    copy = other.copy()
    copy.take(copy.inflight[0].seq)
    assert other.key() == net.key() != copy.key()  # and a copy is a network of its own
