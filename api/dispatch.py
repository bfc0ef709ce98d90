"""The dispatch policy, as plain functions of plain values (no I/O, no clock).

* Waiting mails are served in priority order (9 the most urgent), oldest first among equals.
* Each goes to the drone that can take it soonest, by the fleet's one rule
  (:func:`drona_gcs.dispatch.choose_drone`; ``drona mail`` goes down the same ranking,
  :func:`~drona_gcs.dispatch.rank_drones`, while drones refuse): the fewest
  unfinished mails, idle before busy, the nearest to the pickup by static distance,
  then by id. A drone takes at most ``per_drone`` unfinished mails from the service, so
  urgent mail that arrives later is not stuck behind long queues on board.
* A drone that refused a mail is not offered it again for a while (the caller's ``excluded``).
* A drone takes a mail on board only once the service cleared it for pickup (when the drone
  started it). A lost drone's mails not cleared go back to the queue; mail cleared or on board
  stays the drone's, which may be only cut off and deliver it, until it is back (and says what
  it did meanwhile) or the operator releases it.
* A mail whose drone has not mentioned it (in a report or its published state) by its
  deadline is requeued if not picked up yet, and failed if it was on board, or cleared and
  its drone lost since (a restarted agent forgets what its vehicle may carry).

:class:`api.dispatcher.Dispatcher` applies these decisions.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass

from api.gateway import DroneView
from api.lifecycle import Status
from drona_gcs.dispatch import Candidate, choose_drone
from drona_gcs.workspace import Cell

Distance = Callable[[Cell, Cell], int]
#: Phases (drona_gcs.stack.mail.Phase values) in which a drone with no mail is idle.
IDLE_PHASES = frozenset({"idle", "to_parking"})


@dataclass(frozen=True)
class Waiting:
    """A queued mail, as dispatch sees it."""

    id: str
    pickup: Cell
    priority: int
    seq: int  #: arrival order

    @property
    def rank(self) -> tuple[int, int]:
        return (-self.priority, self.seq)


@dataclass(frozen=True)
class Slot:
    """A drone that may take ``free`` more mails; ``load`` it already holds from the service."""

    drone: str
    cell: Cell
    load: int
    free: int
    idle: bool


@dataclass(frozen=True)
class Assignment:
    mail_id: str
    drone: str


@dataclass(frozen=True)
class InFlight:
    """A mail a drone holds, with the time by which the drone must mention it again."""

    mail_id: str
    drone: str
    status: Status  #: assigned or picked_up
    deadline: float


@dataclass(frozen=True)
class Requeue:
    mail_id: str
    drone: str
    reason: str


@dataclass(frozen=True)
class Fail:
    mail_id: str
    drone: str
    reason: str


Decision = Requeue | Fail


def slots(views: Mapping[str, DroneView], load: Mapping[str, int], per_drone: int) -> list[Slot]:
    """The live, healthy drones that can take more mail."""
    found = []
    for drone, view in views.items():
        held = load.get(drone, 0)
        if not view.alive or not view.health.ok or held >= per_drone:
            continue
        idle = held == 0 and not view.queue and view.carrying is None and view.phase in IDLE_PHASES
        found.append(Slot(drone, view.cell, held, per_drone - held, idle))
    return found


def assign(waiting: Iterable[Waiting], free: Sequence[Slot], distance: Distance,
           excluded: Mapping[str, Collection[str]] | None = None, no_path: int = 10**6) -> list[Assignment]:
    """Which drone gets which waiting mail, in dispatch order; ``excluded[mail]`` are drones not to offer it."""
    excluded = excluded or {}
    open_slots = {s.drone: s for s in free if s.free > 0}
    out: list[Assignment] = []
    for mail in sorted(waiting, key=lambda w: w.rank):
        if not open_slots:
            break
        barred = excluded.get(mail.id, ())
        ways = {d: distance(s.cell, mail.pickup) for d, s in open_slots.items() if d not in barred}
        ways = {d: w for d, w in ways.items() if w < no_path}
        if not ways:
            continue
        candidates = [Candidate(d, open_slots[d].cell, open_slots[d].load, not open_slots[d].idle) for d in ways]
        best = choose_drone(candidates, mail.pickup, distance)
        assert best is not None  # there was a candidate
        out.append(Assignment(mail.id, best))
        slot = open_slots[best]
        if slot.free > 1:
            open_slots[best] = Slot(best, slot.cell, slot.load + 1, slot.free - 1, False)
        else:
            del open_slots[best]
    return out


def on_drone_lost(in_flight: Iterable[InFlight], drone: str, cleared: Collection[str]) -> list[Decision]:
    """A lost drone's mails it was not cleared to pick up, back to the queue (the rest stays its own)."""
    return [Requeue(m.mail_id, drone, f"drone {drone} was lost before the pickup") for m in in_flight
            if m.drone == drone and m.status is Status.ASSIGNED and m.mail_id not in cleared]


def on_drone_released(in_flight: Iterable[InFlight], drone: str, cleared: Collection[str]) -> list[Decision]:
    """The operator saw ``drone``, gone, out of the air: mail that may be on board fails, the rest is
    requeued."""
    why = f"drone {drone} was released by the operator"
    return [_give_up(m, why, cleared) for m in in_flight if m.drone == drone]


def expired(in_flight: Iterable[InFlight], now: float, may_be_on_board: Collection[str] = ()) -> list[Decision]:
    """Mails whose drone has been silent about them past their deadline: failed if it may have them on
    board (picked up; or ``may_be_on_board``: cleared, and the drone lost since, so its agent may be a
    new one that forgot what its vehicle carries), else requeued."""
    return [_give_up(m, f"drone {m.drone} stopped reporting it", may_be_on_board) for m in in_flight
            if m.deadline <= now]


def _give_up(mail: InFlight, why: str, may_be_on_board: Collection[str]) -> Decision:
    if mail.status is Status.PICKED_UP:
        return Fail(mail.mail_id, mail.drone, f"{why} with the mail on board")
    if mail.mail_id in may_be_on_board:
        return Fail(mail.mail_id, mail.drone, f"{why}; it may have had the mail on board")
    return Requeue(mail.mail_id, mail.drone, f"{why} before the pickup")
