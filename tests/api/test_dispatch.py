"""The pure dispatch policy (api.dispatch): no I/O, plain values in, decisions out."""

from __future__ import annotations

from api.dispatch import (
    Assignment,
    Fail,
    InFlight,
    Requeue,
    Slot,
    Waiting,
    assign,
    expired,
    on_drone_lost,
    on_drone_released,
    slots,
)
from api.gateway import DroneView, Health, Position
from api.lifecycle import Status
from drona_gcs.workspace import Cell


def manhattan(a: Cell, b: Cell) -> int:
    return sum(abs(p - q) for p, q in zip(a, b, strict=True))


def slot(drone: str, cell: Cell, load: int = 0, free: int = 2, idle: bool | None = None) -> Slot:
    return Slot(drone, cell, load, free, load == 0 if idle is None else idle)


def view(drone: str, cell: Cell, *, queue: tuple[str, ...] = (), phase: str = "idle", ok: bool = True,
         alive: bool = True) -> DroneView:
    return DroneView(drone, cell, Position(0, 0, 0), 90.0, "GUIDED", phase, None, None, queue, None,
                     Health(ok, () if ok else ("battery",)), 0, alive)


def test_most_urgent_first_then_oldest() -> None:
    waiting = [Waiting("old-low", (0, 0, 0), 1, 1), Waiting("new-high", (0, 0, 0), 9, 5),
               Waiting("old-high", (0, 0, 0), 9, 2), Waiting("mid", (0, 0, 0), 5, 3)]
    chosen = assign(waiting, [slot("a", (0, 0, 0), free=3)], manhattan)
    assert [c.mail_id for c in chosen] == ["old-high", "new-high", "mid"]  # the fourth waits: no room


def test_idle_first_then_shortest_queue_then_nearest_then_id() -> None:
    mail = [Waiting("m", (5, 0, 0), 5, 1)]
    busy_near = slot("a", (5, 0, 0), load=1)
    idle_far = slot("b", (0, 0, 0))
    assert assign(mail, [busy_near, idle_far], manhattan) == [Assignment("m", "b")]
    short_far, long_near = slot("c", (0, 0, 0), load=1), slot("d", (5, 0, 0), load=2, free=1)
    assert assign(mail, [long_near, short_far], manhattan) == [Assignment("m", "c")]
    near, far = slot("e", (4, 0, 0)), slot("f", (0, 0, 0))
    assert assign(mail, [far, near], manhattan) == [Assignment("m", "e")]
    assert assign(mail, [slot("z", (4, 0, 0)), slot("y", (6, 0, 0))], manhattan) == [Assignment("m", "y")]


def test_each_drone_takes_no_more_than_its_room_and_spreads_the_load() -> None:
    waiting = [Waiting(f"m{i}", (0, 0, 0), 5, i) for i in range(5)]
    chosen = assign(waiting, [slot("a", (0, 0, 0), free=2), slot("b", (9, 0, 0), free=1)], manhattan)
    assert [(c.mail_id, c.drone) for c in chosen] == [("m0", "a"), ("m1", "b"), ("m2", "a")]


def test_excluded_and_unreachable_drones_are_passed_over() -> None:
    mail = [Waiting("m", (1, 0, 0), 5, 1), Waiting("n", (1, 0, 0), 4, 2)]

    def far_for_b(a: Cell, b: Cell) -> int:
        return 10**6 if a == (9, 9, 0) else manhattan(a, b)

    chosen = assign(mail, [slot("a", (0, 0, 0), free=1), slot("b", (9, 9, 0))], far_for_b, {"m": {"a"}})
    assert chosen == [Assignment("n", "a")]  # m: a excluded, b cannot reach it


def test_slots_skip_dead_unhealthy_and_full_drones() -> None:
    views = {"a": view("a", (0, 0, 0)), "b": view("b", (1, 0, 0), alive=False), "c": view("c", (2, 0, 0), ok=False),
             "d": view("d", (3, 0, 0)), "e": view("e", (4, 0, 0), queue=("x",), phase="to_pickup")}
    found = {s.drone: s for s in slots(views, {"d": 2, "e": 1}, per_drone=2)}
    assert set(found) == {"a", "e"}
    assert found["a"].idle and found["a"].free == 2
    assert not found["e"].idle and found["e"].free == 1


def test_a_lost_drone_gives_back_only_what_it_was_not_cleared_to_pick_up() -> None:
    held = [InFlight("m1", "a", Status.ASSIGNED, 10.0), InFlight("m2", "a", Status.PICKED_UP, 10.0),
            InFlight("m3", "b", Status.ASSIGNED, 10.0), InFlight("m4", "a", Status.ASSIGNED, 10.0)]
    decisions = on_drone_lost(held, "a", cleared={"m4"})
    assert [(type(d), d.mail_id) for d in decisions] == [(Requeue, "m1")]
    released = on_drone_released(held, "a", cleared={"m4"})
    assert [(type(d), d.mail_id) for d in released] == [(Requeue, "m1"), (Fail, "m2"), (Fail, "m4")]
    assert "on board" in released[1].reason and "released by the operator" in released[1].reason
    assert "may have had the mail on board" in released[2].reason


def test_only_mail_past_its_deadline_expires() -> None:
    held = [InFlight("m1", "a", Status.ASSIGNED, 5.0), InFlight("m2", "a", Status.PICKED_UP, 4.0),
            InFlight("m3", "b", Status.ASSIGNED, 6.0)]
    decisions = expired(held, now=5.0)
    assert [(type(d), d.mail_id) for d in decisions] == [(Requeue, "m1"), (Fail, "m2")]
    assert "stopped reporting" in decisions[0].reason


def test_mail_that_may_be_on_board_fails_when_it_expires() -> None:
    """A crashed agent's vehicle may carry what it was cleared for, its pickup report lost with it:
    given to a second drone, the mail would have two owners."""
    held = [InFlight("m1", "a", Status.ASSIGNED, 5.0), InFlight("m2", "a", Status.ASSIGNED, 5.0)]
    decisions = expired(held, now=5.0, may_be_on_board={"m2"})
    assert [(type(d), d.mail_id) for d in decisions] == [(Requeue, "m1"), (Fail, "m2")]
    assert "may have had the mail on board" in decisions[1].reason
