"""The figures behind the dashboard's charts, from the store's audit trail and :class:`api.watch.FleetWatch`.

* deliveries per time bucket (the audit rows ``delivered``, by time: index ``audit_status_at``);
* how long mail waited, by priority: from submitted to picked up, for mail picked up within
  the window.
"""

from __future__ import annotations

import math
import sqlite3
from collections import defaultdict
from dataclasses import dataclass

#: Most mails one chart reads (a window of a busy service holds more: the newest are taken).
MAX_ROWS = 100_000


@dataclass(frozen=True)
class Waiting:
    priority: int
    count: int
    p50_s: float
    p90_s: float
    max_s: float


def deliveries(reader: sqlite3.Connection, now: float, window_s: float, bucket_s: float) -> list[int]:
    """Deliveries in each bucket of the window, oldest first; the last bucket ends ``now``."""
    buckets = [0] * math.ceil(window_s / bucket_s)
    start = now - len(buckets) * bucket_s
    rows = reader.execute("SELECT at FROM audit WHERE status = 'delivered' AND at > ? ORDER BY at DESC LIMIT ?",
                          (start, MAX_ROWS))
    for (at,) in rows:
        buckets[min(len(buckets) - 1, int((at - start) // bucket_s))] += 1
    return buckets


def waiting(reader: sqlite3.Connection, now: float, window_s: float) -> list[Waiting]:
    """Per priority (most urgent first): the waits of mail picked up in the window."""
    rows = reader.execute(
        "SELECT m.priority, a.at - m.created_at FROM audit a JOIN mail m ON m.seq = a.mail_seq "
        "WHERE a.status = 'picked_up' AND a.at > ? ORDER BY a.at DESC LIMIT ?",
        (now - window_s, MAX_ROWS))
    by_priority: dict[int, list[float]] = defaultdict(list)
    for priority, wait in rows:
        by_priority[priority].append(max(0.0, wait))
    return [_summary(p, sorted(w)) for p, w in sorted(by_priority.items(), reverse=True)]


def _summary(priority: int, waits: list[float]) -> Waiting:
    def quantile(q: float) -> float:
        return round(waits[min(len(waits) - 1, int(q * len(waits)))], 3)

    return Waiting(priority, len(waits), quantile(0.5), quantile(0.9), round(waits[-1], 3))
