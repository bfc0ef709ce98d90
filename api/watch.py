"""``FleetWatch``: what the service remembers of the fleet for its operators.

It stands between the gateway and the dispatcher: it is the gateway's listener and passes
every event on. It stamps each drone state with the time it came (``seen_at``), keeps the last
known state of a drone that left (``alive`` false: the dashboard shows it where it was last
seen rather than dropping it), opens and clears alarms (:mod:`api.alarms`), and keeps the
event log (drones joining and leaving, alarms, the mail lifecycle) and the short series the
dashboard's charts draw (battery per drone, coordination latency). The log and the series
are in memory and bounded; the alarms and the mail's audit trail are in the store.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

from api.alarms import Alarm, AlarmBook
from api.events import EventBus
from api.gateway import DroneView, FleetListener, MailStatusReport
from api.lifecycle import Status
from api.store import Change, MailRecord, Store

#: Seconds between two battery samples of one drone.
BATTERY_SAMPLE_S = 2.0


@dataclass(frozen=True)
class LogEntry:
    at: float  #: Unix seconds
    kind: str  #: drone, alarm or mail
    text: str
    drone: str | None = None
    mail_id: str | None = None


@dataclass(frozen=True)
class Sample:
    at: float
    drone: str
    value: float


class FleetWatch:
    def __init__(self, listener: FleetListener, store: Store, bus: EventBus, *,
                 clock: Callable[[], float] = time.time, log_size: int = 500, series_size: int = 300) -> None:
        self.listener = listener
        self.bus = bus
        self.clock = clock
        self.alarms = AlarmBook(store, self._alarm_changed)
        self.live: dict[str, DroneView] = {}
        self.lost: dict[str, DroneView] = {}
        self.entries: deque[LogEntry] = deque(maxlen=log_size)
        self.battery: dict[str, deque[Sample]] = {}
        self.coordination: deque[Sample] = deque(maxlen=series_size)
        self._series_size = series_size
        #: Told of each log entry and alarm change (api.main publishes them as server-sent events).
        self.on_entry: Callable[[LogEntry], None] = lambda entry: None
        self.on_alarm: Callable[[Alarm], None] = lambda alarm: None

    # ------------------------------------------------------ the gateway's events
    def on_drone_state(self, view: DroneView) -> None:
        now = self.clock()
        stamped = replace(view, seen_at=now, alive=True)
        previous = self.live.get(view.id)
        if previous is None:
            self._log("drone", f"{view.id} {'is back' if view.id in self.lost else 'joined'}", drone=view.id)
        self.live[view.id] = stamped
        self.lost.pop(view.id, None)
        self.alarms.observe(view.id, view.health.alarms, now)
        self._sample(previous, stamped, now)
        self.listener.on_drone_state(stamped)

    def on_drone_lost(self, drone: str) -> None:
        now = self.clock()
        view = self.live.pop(drone, None)
        if view is not None:
            self.lost[drone] = replace(view, alive=False)
        self._log("drone", f"{drone} left: last seen {_ago(view, now)}", drone=drone)
        self.alarms.left(drone, now)
        self.listener.on_drone_lost(drone)

    def on_mail_status(self, report: MailStatusReport) -> None:
        self.listener.on_mail_status(report)

    # ---------------------------------------------------------- the store's
    def on_commit(self, change: Change) -> None:
        """A committed mail change (a commit listener of the store): its line in the log."""
        if not change.replayed:
            r = change.record
            self._log("mail", _mail_text(r, change.before), drone=r.drone, mail_id=r.id)

    # -------------------------------------------------------------- reads
    def known(self) -> list[DroneView]:
        """Every drone seen: live ones, and the last known state of those that left; by id."""
        views = {**self.lost, **self.live}
        return [views[d] for d in sorted(views)]

    def recent(self, limit: int) -> list[LogEntry]:
        """The log, newest first."""
        return list(self.entries)[-limit:][::-1]

    # ------------------------------------------------------------ inside
    def _log(self, kind: str, text: str, *, drone: str | None = None, mail_id: str | None = None) -> None:
        entry = LogEntry(self.clock(), kind, text, drone, mail_id)
        self.entries.append(entry)
        self.on_entry(entry)

    def _alarm_changed(self, alarm: Alarm, what: str) -> None:
        who = f" by {alarm.acked_by}" if what == "acknowledged" else ""
        self._log("alarm", f"{alarm.drone}: alarm {alarm.kind} {what}{who}: {alarm.text}", drone=alarm.drone)
        self.on_alarm(alarm)

    def _sample(self, previous: DroneView | None, view: DroneView, now: float) -> None:
        series = self.battery.setdefault(view.id, deque(maxlen=self._series_size))
        if not series or now - series[-1].at >= BATTERY_SAMPLE_S:
            series.append(Sample(now, view.id, view.battery_pct))
        ms = view.coordination_ms
        if ms is not None and (previous is None or previous.coordination_ms != ms):
            self.coordination.append(Sample(now, view.id, ms))


def _ago(view: DroneView | None, now: float) -> str:
    return "never" if view is None else f"{now - view.seen_at:.0f} s ago"


def _mail_text(r: MailRecord, before: Status | None) -> str:
    """One line about a mail's new status, as an operator reads it."""
    if before is None:
        return f"{r.id} submitted by {r.owner}, priority {r.priority}: {list(r.pickup)} → {list(r.dropoff)}"
    texts = {Status.QUEUED: f"back in the queue: {r.reason}", Status.ASSIGNED: f"assigned to {r.drone}",
             Status.PICKED_UP: f"picked up by {r.drone}", Status.DELIVERED: f"delivered by {r.drone}",
             Status.FAILED: f"failed: {r.reason}", Status.CANCELLED: f"cancelled: {r.reason}"}
    return f"{r.id} {texts[r.status]}"
