"""Battery: the energy model and the battery monitor (sense and infer).

The monitor turns readings into two events for the task planner, with
hysteresis so a level hovering at the threshold does not chatter: ``BatteryLow``
once the level drops below ``low``, then ``BatteryRecharged`` once it is back
at ``recharged`` or more.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from drona_gcs.errors import ProblemError
from drona_gcs.stack.transitions import lookup

#: the planning drain of a second of flight, in percent: about four times a 5 Ah pack hovering at
#: 15 A (the fake vehicle's), so a plan budgets for a worn pack and headwind
DRAIN_PERCENT_PER_S = 0.33


@dataclass(frozen=True)
class BatteryModel:
    """Percent per step flying (moving or hovering) and charging at a station, and the safe floor."""

    drain_per_step: float = 1.0
    charge_per_step: float = 5.0
    safe_threshold: float = 20.0
    margin_steps: int = 8  #: slack for waiting and coordination, in steps of drain

    def __post_init__(self) -> None:
        if self.drain_per_step <= 0 or self.charge_per_step <= 0:
            raise ProblemError("battery drain and charge rates must be > 0")
        if not 0 <= self.safe_threshold < 100:
            raise ProblemError(f"safe threshold must be within [0, 100), got {self.safe_threshold}")

    @classmethod
    def for_period(cls, tau_s: float, drain_per_step: float | None = None,
                   safe_threshold: float = 20.0) -> BatteryModel:
        """The planning model of a fleet stepping every ``tau_s`` seconds: a battery drains per
        second of flight, so a step's drain scales with tau unless ``drain_per_step`` is given."""
        drain = drain_per_step if drain_per_step is not None else DRAIN_PERCENT_PER_S * tau_s
        return cls(drain_per_step=drain, safe_threshold=safe_threshold)

    def steps_affordable(self, level: float) -> int:
        """How many flying steps ``level`` allows before reaching the safe threshold."""
        return max(0, int((level - self.safe_threshold) / self.drain_per_step))


class BatteryState(enum.Enum):
    OK = "ok"  #: above the low mark
    LOW = "low"  #: dropped below the low mark; waiting to be recharged


@dataclass(frozen=True)
class BatteryLow:
    level: float


@dataclass(frozen=True)
class BatteryRecharged:
    level: float


BatteryEvent = BatteryLow | BatteryRecharged

#: Every change of a monitor's state: TRANSITIONS[state][event it reports] -> the state it leads to.
TRANSITIONS: dict[BatteryState, dict[type[BatteryEvent], BatteryState]] = {
    BatteryState.OK: {BatteryLow: BatteryState.LOW},
    BatteryState.LOW: {BatteryRecharged: BatteryState.OK},
}


@dataclass
class BatteryMonitor:
    low: float = 40.0
    recharged: float = 95.0
    _state: BatteryState = field(default=BatteryState.OK, init=False)  #: read as :attr:`state`

    def __post_init__(self) -> None:
        if not self.low < self.recharged:
            raise ProblemError(f"low mark {self.low} must be below recharged mark {self.recharged}")

    @property
    def state(self) -> BatteryState:
        """Changed only by :meth:`_report`, as :data:`TRANSITIONS` allows."""
        return self._state

    def reading(self, level: float) -> list[BatteryEvent]:
        if not 0 <= level <= 100:
            raise ProblemError(f"battery reading must be a percentage, got {level}")
        if self.state is BatteryState.OK and level < self.low:
            return self._report(BatteryLow(level))
        if self.state is BatteryState.LOW and level >= self.recharged:
            return self._report(BatteryRecharged(level))
        return []

    def _report(self, event: BatteryEvent) -> list[BatteryEvent]:
        """The one place the state changes: to where :data:`TRANSITIONS` says ``event`` leads."""
        self._state = lookup(TRANSITIONS, "battery monitor", self._state, type(event))
        return [event]
