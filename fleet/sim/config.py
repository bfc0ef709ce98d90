"""How a fake vehicle is set up: its settings (:class:`VehicleConfig`) and where it stands (:class:`Placement`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from drona_gcs.geo import GeoFrame, Ned
from fleet.sim.personality import ARDUPILOT, Personality
from fleet.sim.physics import Limits


@dataclass(frozen=True)
class VehicleConfig:
    system_id: int = 1
    personality: Personality = ARDUPILOT
    limits: Limits = field(default_factory=Limits)
    ready_after_s: float = 2.0  #: boot to position estimate (arming and GUIDED possible)
    auto_disarm_s: float = 10.0  #: armed on the ground without takeoff: disarms after this
    min_arm_battery_pct: int = 20
    battery_pct: float = 100.0
    offboard_timeout_s: float = 0.5  #: PX4: no setpoint for this long leaves OFFBOARD (a stream under 2 Hz)
    guided_velocity_timeout_s: float = 3.0  #: ArduCopter: a velocity setpoint older than this stops
    rtl_alt_m: float = 15.0
    takeoff_alt_m: float = 2.5  #: PX4's MIS_TAKEOFF_ALT, when the command gives none
    hover_current_a: float = 15.0
    charge_current_a: float = 10.0


@dataclass(frozen=True)
class Placement:
    """Where the vehicle is in the world: home (on the ground) in the workspace frame, and chargers."""

    frame: GeoFrame
    home: Ned  #: workspace NED of home; the vehicle's local frame starts here
    chargers: frozenset[tuple[int, int]] = frozenset()  #: (x, y) of charging-station cells
