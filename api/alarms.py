"""The fleet's alarms: what each means, when it was raised and cleared, and who acknowledged it.

An alarm is one kind of trouble on one drone: at most one of each kind is open per drone. The
kinds come from the texts in a drone's state (``health.alarms``; the agent writes most as
``KIND: what``), and one is the service's own: ``left``, the drone's link or agent went.
An alarm opens when its kind appears in the drone's state, and clears when a state comes
without it. Opening, clearing and every acknowledgement are stored (table ``alarm``, see
:data:`api.schema.MIGRATIONS`): an operator's acknowledgement is part of the audit trail.
"""

from __future__ import annotations

import asyncio
import logging
import sqlite3
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from typing import Any

from api.errors import ApiError
from api.store import Store

log = logging.getLogger(__name__)

#: Everything that names an alarm lives here: text prefix -> (kind, what it means to an operator).
#: The first prefix a text starts with wins; see fleet/agent/drone.py, tracking.py and peers.py for the texts.
KINDS: tuple[tuple[str, str, str], ...] = (
    ("lag:", "lag", "the vehicle trails the cell its plan puts it in; separation assumes it is there"),
    ("vehicle: came down", "down", "the vehicle came down by itself (a failsafe or a pilot); its mail was "
                                   "handed back and it takes no task until its agent restarts"),
    ("vehicle:", "vehicle", "the vehicle refused a command or did not answer in time"),
    ("catching up", "behind", "the drone is behind its plan: a stalled process, or a vehicle too slow at a turn"),
    ("vehicle_lost:", "vehicle_lost", "no telemetry from the vehicle: its drone holds every cell it may be in "
                                      "and takes no task"),
    ("placement:", "placement", "the vehicle is not where its drone started: out of service until landed by hand"),
    ("leg_not_flown:", "leg", "a leg ended with the vehicle short of its goal; the leg is flown again"),
    ("limits:", "limits", "the vehicle's autopilot was set in flight out of the workspace's vehicle limits "
                          "(lambda does not hold): its drone holds where its plan ends and takes no task"),
    ("clock skew:", "clock", "a peer's clock is beyond beta from this drone's: it plans nothing until back within"),
)
LEFT = "left"
_MEANINGS = {kind: meaning for _, kind, meaning in KINDS} | {
    LEFT: "the drone left the fleet (its link or its agent went): shown where it was last seen"}
_COLUMNS = "n, drone, kind, text, raised_at, cleared_at, acked_at, acked_by"


class AlarmNotFound(ApiError):
    def __init__(self, n: int) -> None:
        super().__init__(f"no alarm {n}")
        self.n = n


def kind_of(text: str) -> str:
    """The kind of an alarm text: a known prefix's, else the text before its colon."""
    for prefix, kind, _ in KINDS:
        if text.startswith(prefix):
            return kind
    head, colon, _ = text.partition(":")
    return head.strip()[:32] if colon and head.strip() else "alarm"


def meaning_of(kind: str) -> str:
    return _MEANINGS.get(kind, "reported by the drone")


@dataclass(frozen=True)
class Alarm:
    n: int
    drone: str
    kind: str
    text: str  #: as the drone first said it
    raised_at: float
    cleared_at: float | None
    acked_at: float | None
    acked_by: str | None

    @classmethod
    def from_row(cls, row: Any) -> Alarm:
        return cls(*row)

    @property
    def meaning(self) -> str:
        return meaning_of(self.kind)


def recent(reader: sqlite3.Connection, limit: int, open_only: bool = False) -> list[Alarm]:
    """Newest first."""
    where = "WHERE cleared_at IS NULL" if open_only else ""
    rows = reader.execute(f"SELECT {_COLUMNS} FROM alarm {where} ORDER BY n DESC LIMIT ?", (limit,))
    return [Alarm.from_row(r) for r in rows]


def _raise(conn: sqlite3.Connection, drone: str, kind: str, text: str, at: float) -> Alarm:
    cur = conn.execute(f"INSERT INTO alarm (drone, kind, text, raised_at) VALUES (?, ?, ?, ?) RETURNING {_COLUMNS}",
                       (drone, kind, text, at))
    return Alarm.from_row(cur.fetchone())


def _clear(conn: sqlite3.Connection, drone: str, kind: str, at: float) -> Alarm | None:
    row = conn.execute(f"UPDATE alarm SET cleared_at = ? WHERE drone = ? AND kind = ? AND cleared_at IS NULL "
                       f"RETURNING {_COLUMNS}", (at, drone, kind)).fetchone()
    return Alarm.from_row(row) if row else None


def _ack(conn: sqlite3.Connection, n: int, by: str, at: float) -> Alarm:
    """The first acknowledgement stands; acknowledging again changes nothing."""
    conn.execute("UPDATE alarm SET acked_at = ?, acked_by = ? WHERE n = ? AND acked_at IS NULL", (at, by, n))
    row = conn.execute(f"SELECT {_COLUMNS} FROM alarm WHERE n = ?", (n,)).fetchone()
    if row is None:
        raise AlarmNotFound(n)
    return Alarm.from_row(row)


#: A write the book queues: run in the store's writer, it gives the alarm it changed (None: none).
_Op = Callable[[sqlite3.Connection], Alarm | None]
#: Told of each stored change: the alarm, and raised, cleared or acknowledged.
ChangeListener = Callable[[Alarm, str], None]


class AlarmBook:
    """Open alarms by drone and kind; changes are written in order by :meth:`run`, then ``on_change`` hears."""

    def __init__(self, store: Store, on_change: ChangeListener) -> None:
        self.store = store
        self.on_change = on_change
        open_now = store.read(lambda c: recent(c, 10_000, open_only=True))
        self._open: set[tuple[str, str]] = {(a.drone, a.kind) for a in open_now}
        self._ops: asyncio.Queue[tuple[str, _Op]] = asyncio.Queue()

    def observe(self, drone: str, texts: Iterable[str], at: float) -> None:
        """A state of ``drone`` with these alarm texts: open the kinds new to it, clear the ones gone."""
        now = {kind_of(t): t for t in texts}
        for kind, text in now.items():
            if (drone, kind) not in self._open:
                self._open.add((drone, kind))
                self._queue("raised", partial(_raise, drone=drone, kind=kind, text=text, at=at))
        for key in [k for k in self._open if k[0] == drone and k[1] not in now]:
            self._open.discard(key)
            self._queue("cleared", partial(_clear, drone=drone, kind=key[1], at=at))

    def left(self, drone: str, at: float) -> None:
        if (drone, LEFT) not in self._open:
            self._open.add((drone, LEFT))
            self._queue("raised", lambda c: _raise(c, drone, LEFT, "left: no state and no liveliness token", at))

    async def acknowledge(self, n: int, by: str, at: float) -> Alarm:
        """Record ``by``'s acknowledgement of alarm ``n`` (raises :class:`AlarmNotFound`)."""
        alarm = await self.store.write(lambda c: _ack(c, n, by, at))
        if alarm.acked_at == at and alarm.acked_by == by:  # this one's: not an earlier acknowledgement
            self.on_change(alarm, "acknowledged")
        return alarm

    def _queue(self, what: str, op: _Op) -> None:
        self._ops.put_nowait((what, op))

    async def run(self) -> None:
        """Write the changes in the order they came, until cancelled."""
        while True:
            what, op = await self._ops.get()
            try:
                alarm = await self.store.write(op)
                if alarm is not None:
                    self.on_change(alarm, what)
            except ApiError as exc:  # the alarm is still shown on its drone
                log.error("an alarm change was not stored: %s", exc)
            finally:
                self._ops.task_done()

    async def settled(self) -> None:
        """Until every change queued so far is written (for tests)."""
        await self._ops.join()
