"""The mail lifecycle: every status and every allowed transition, in one table.

    queued ──> assigned ──> picked_up ──> delivered
      │  ^        │  │          │
      │  └────────┘  │          └──> failed
      │  (requeued)  ├──> delivered, failed, cancelled
      └──> cancelled, failed

A drone lost with a mail on board fails it; one lost before the pickup gives it
back to the queue. Each transition is stored with its time, drone and reason
(the audit trail).
"""

from __future__ import annotations

import enum

from api.errors import IllegalTransition


class Status(enum.Enum):
    QUEUED = "queued"  #: waiting for a drone
    ASSIGNED = "assigned"  #: handed to a drone, not picked up yet
    PICKED_UP = "picked_up"  #: on board its drone
    DELIVERED = "delivered"  #: at its drop-off (final)
    FAILED = "failed"  #: given up, with a reason (final)
    CANCELLED = "cancelled"  #: cancelled by an operator (final)


#: Everything that affects the lifecycle lives here: status -> statuses it may become.
TRANSITIONS: dict[Status, frozenset[Status]] = {
    Status.QUEUED: frozenset({Status.ASSIGNED, Status.CANCELLED, Status.FAILED}),
    Status.ASSIGNED: frozenset({Status.QUEUED, Status.PICKED_UP, Status.DELIVERED, Status.FAILED, Status.CANCELLED}),
    Status.PICKED_UP: frozenset({Status.DELIVERED, Status.FAILED}),
    Status.DELIVERED: frozenset(),
    Status.FAILED: frozenset(),
    Status.CANCELLED: frozenset(),
}

FINAL = frozenset(s for s, nxt in TRANSITIONS.items() if not nxt)
#: A drone holds these (the dispatcher tracks them).
IN_FLIGHT = frozenset({Status.ASSIGNED, Status.PICKED_UP})


def check_transition(mail_id: str, current: Status, wanted: Status) -> None:
    """Raise :class:`IllegalTransition` naming both statuses unless ``current -> wanted`` is allowed."""
    if wanted not in TRANSITIONS[current]:
        raise IllegalTransition(mail_id, current.value, wanted.value)
