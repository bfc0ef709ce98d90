"""The one error tree of drona-gcs.

Every error the core raises is a :class:`DronaError`; the edges (``fleet/``,
``api/``) map library errors into it with ``raise ... from exc``::

    DronaError
    ├── WorkspaceError          a workspace file or object is invalid
    ├── ProblemError            a planning problem is malformed
    ├── NoPlanFound             no safe plan exists within L_max
    ├── UnsafeTrajectory        the safety checker rejected a trajectory
    ├── ProtocolViolation       a state machine got an event it cannot take
    └── VehicleError            the vehicle link failed
        └── VehicleCommandRejected(result, reason)
"""

from __future__ import annotations

from collections.abc import Sequence


class DronaError(Exception):
    """Base class of every error raised by drona-gcs."""


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


class VehicleCommandRejected(VehicleError):
    """The autopilot refused a command; ``result`` is the MAV_RESULT code."""

    def __init__(self, command: str, result: int, reason: str = "") -> None:
        self.command = command
        self.result = result
        self.reason = reason
        detail = f": {reason}" if reason else ""
        super().__init__(f"{command} rejected with result {result}{detail}")
