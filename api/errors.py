"""The service's errors, a branch of the one tree :class:`drona_gcs.errors.DronaError`::

    DronaError
    └── ApiError                  the service refused or could not do something
        ├── AssignRefused         a drone refused a mail or could not be reached (``drone``, ``reason``)
        ├── IllegalTransition     a mail cannot go from its status to the one asked (names both)
        ├── MailNotFound          no mail has that id (for this caller)
        ├── IdempotencyConflict   an Idempotency-Key was reused with another request
        ├── StoreError            the database could not be opened, read or written (answered 503)
        └── ConfigError           the settings cannot run a service (no token, bad token file, ...)
"""

from __future__ import annotations

from drona_gcs.errors import DronaError


class ApiError(DronaError):
    """Base of the service's errors."""


class AssignRefused(ApiError):
    """The gateway could not hand ``mail_id`` to ``drone``: refused, unreachable or timed out."""

    def __init__(self, drone: str, mail_id: str, reason: str) -> None:
        self.drone = drone
        self.mail_id = mail_id
        self.reason = reason
        super().__init__(f"drone {drone} did not take mail {mail_id}: {reason}")


class IllegalTransition(ApiError):
    """A mail in status ``current`` cannot become ``wanted``."""

    def __init__(self, mail_id: str, current: str, wanted: str) -> None:
        self.mail_id = mail_id
        self.current = current
        self.wanted = wanted
        super().__init__(f"mail {mail_id} is {current}: it cannot become {wanted}")


class MailNotFound(ApiError):
    def __init__(self, mail_id: str) -> None:
        self.mail_id = mail_id
        super().__init__(f"no mail {mail_id!r}")


class IdempotencyConflict(ApiError):
    def __init__(self, key: str, mail_id: str) -> None:
        self.key = key
        self.mail_id = mail_id
        super().__init__(f"Idempotency-Key {key!r} was already used for mail {mail_id} with another request")


class StoreError(ApiError):
    """SQLite failed (the message names the file and what SQLite said): a full disk, a file that is not
    a database, a lock held too long. Mapped from ``sqlite3.Error`` in one place, :mod:`api.store`."""


class ConfigError(ApiError):
    """The settings cannot run a service; the message says which setting and why."""
