"""How a fake vehicle is set up: its settings (:class:`VehicleConfig`) and where it stands (:class:`Placement`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from drona_gcs.geo import GeoFrame, Ned
from fleet.sim.personality import ARDUPILOT, Personality
from fleet.sim.physics import Limits


@dataclass(frozen=True)
class VehicleConfig:
    system_id: int = 1
    instance: int = 0  #: which vehicle of its simulator (SITL's -I): its telemetry keeps its own time
    personality: Personality = ARDUPILOT
    limits: Limits = field(default_factory=Limits)
    #: boot to a position estimate (arming possible); None: the personality's, as measured on its SITL. It
    #: may be shortened, never switched off: a ground station must wait for it as for a real autopilot.
    ready_after_s: float | None = None
    gps_after_s: float | None = None  #: boot to a GPS fix (at most ready_after_s); None: the personality's
    spool_up_s: float | None = None  #: an accepted take-off to leaving the ground; None: the personality's
    auto_disarm_s: float = 10.0  #: armed on the ground without takeoff: disarms after this
    min_arm_battery_pct: int = 20
    battery_pct: float = 100.0
    offboard_timeout_s: float = 0.5  #: PX4: no setpoint for this long leaves OFFBOARD (a stream under 2 Hz)
    guided_velocity_timeout_s: float = 3.0  #: ArduCopter: a velocity setpoint older than this stops
    rtl_alt_m: float = 15.0
    takeoff_alt_m: float = 2.5  #: PX4's MIS_TAKEOFF_ALT, when the command gives none
    hover_current_a: float = 15.0
    charge_current_a: float = 10.0

    def __post_init__(self) -> None:
        for name in ("ready_after_s", "gps_after_s", "spool_up_s"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"{name} must be > 0 (shortened, never switched off), got {value}")

    @property
    def ready_s(self) -> float:
        return self.ready_after_s if self.ready_after_s is not None else self.personality.ready_s

    @property
    def gps_s(self) -> float:
        return min(self.gps_after_s if self.gps_after_s is not None else self.personality.gps_fix_s, self.ready_s)

    @property
    def spool_s(self) -> float:
        return self.spool_up_s if self.spool_up_s is not None else self.personality.spool_up_s


@dataclass(frozen=True)
class Placement:
    """Where the vehicle is in the world: home (on the ground) in the workspace frame, and chargers."""

    frame: GeoFrame
    home: Ned  #: workspace NED of home; the vehicle's local frame starts here
    chargers: frozenset[tuple[int, int]] = frozenset()  #: (x, y) of charging-station cells
