"""The one error tree of drona-gcs.

Every error class of drona-gcs is a :class:`DronaError` (arguments of the wrong kind are still
``ValueError``, as in Python itself). The edges map a library's errors into it in
one place each, with ``raise ... from exc``: Zenoh's in ``fleet.transport.node.zenoh_errors``,
SQLite's in ``api.store.sqlite_errors``. The whole tree (``tests/drona_gcs/test_errors.py`` keeps it whole)::

    DronaError
    ├── WorkspaceError            a workspace file or object is invalid
    ├── ProblemError              a planning problem is malformed
    ├── NoPlanFound               no safe plan exists within L_max
    │   ├── GoalCutOff            the goal is walled off for good
    │   └── SmtTimeout            the Z3 generator ran out of time (drona_gcs.planner.smt)
    ├── BudgetExceeded            internal to the planner: a search used its budget (planner.result)
    ├── UnsafeTrajectory          the safety checker rejected a trajectory
    ├── ProtocolViolation         a state machine got an event it cannot take
    ├── Violation                 a monitor of the systematic tester found a bug (verify.monitors)
    ├── VehicleError              the vehicle link failed
    │   └── VehicleCommandRejected(result, reason)
    ├── VehicleLimitsError        a vehicle is set to fly less than the workspace's vehicle limits
    ├── LinkUrlError              a vehicle connection string is wrong (fleet.vehicle.urls)
    ├── SigningKeyError           a MAVLink signing key is unusable (fleet.vehicle.signing)
    ├── TransportError            Zenoh failed: configure, open, declare, put, ask (fleet.transport.node)
    ├── WireError                 a message is malformed or foreign (fleet.transport.wire)
    ├── IdentityError             certificates or hosts.json are unusable (fleet.transport.identity)
    ├── FleetUnavailable          no fleet to talk to (fleet.transport.fleet_client)
    ├── BenchError                a benchmark could not run (fleet.bench)
    │   └── PlotError             --plot cannot be honoured
    └── ApiError                  the service refused or could not do something (api.errors)
        ├── AssignRefused         a drone refused a mail or could not be reached
        ├── IllegalTransition     a mail cannot go from its status to the one asked
        ├── MailNotFound          no mail has that id (for this caller)
        ├── IdempotencyConflict   an Idempotency-Key was reused with another request
        ├── AlarmNotFound         no alarm has that number (api.alarms)
        ├── StoreError            the database could not be opened, read or written (answered 503)
        └── ConfigError           the settings cannot run a service
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence


class DronaError(Exception):
    """Base class of every error raised by drona-gcs."""


@contextlib.contextmanager
def mapped(library_error: type[Exception], to: type[DronaError], what: str) -> Iterator[None]:
    """A library's ``library_error`` raised inside as ``to``, saying ``what`` was being done: each edge maps
    its library's errors with this, in one place per library."""
    try:
        yield
    except library_error as exc:
        raise to(f"{what}: {exc}") from exc


class WorkspaceError(DronaError):
    """A workspace is invalid. The message names the source, the field and the problem."""

    def __init__(self, problem: str, *, field: str = "", source: str = "") -> None:
        self.source = source
        self.field = field
        self.problem = problem
        where = ": ".join(part for part in (source, field) if part)
        super().__init__(f"{where}: {problem}" if where else problem)


class ProblemError(DronaError):
    """A planning problem (for example one line of ``drona plan``) is malformed."""


class NoPlanFound(DronaError):
    """No safe plan reaches the goal within the maximum plan length."""


class GoalCutOff(NoPlanFound):
    """No path at all joins start and goal: obstacles, and drones resting for good, wall one off."""


class UnsafeTrajectory(DronaError):
    """The safety checker found violations; ``violations`` lists them."""

    def __init__(self, violations: Sequence[object]) -> None:
        self.violations = list(violations)
        shown = "; ".join(str(v) for v in violations[:5])
        more = f" (+{len(violations) - 5} more)" if len(violations) > 5 else ""
        super().__init__(f"unsafe trajectory: {shown}{more}")


class ProtocolViolation(DronaError):
    """A state machine received an event that its current state does not accept."""


class VehicleError(DronaError):
    """The link to a vehicle failed (timeout, lost heartbeat, transport error)."""


class VehicleLimitsError(DronaError):
    """A vehicle's autopilot is set to fly less than the workspace's ``vehicle`` limits."""


class VehicleCommandRejected(VehicleError):
    """The autopilot refused a command; ``result`` is the MAV_RESULT code."""

    def __init__(self, command: str, result: int, reason: str = "") -> None:
        self.command = command
        self.result = result
        self.reason = reason
        detail = f": {reason}" if reason else ""
        super().__init__(f"{command} rejected with result {result}{detail}")
