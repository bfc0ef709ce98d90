"""How a fake vehicle is set up: its settings (:class:`VehicleConfig`) and where it stands (:class:`Placement`)."""

from __future__ import annotations

from dataclasses import dataclass

from drona_gcs.geo import GeoFrame, Ned
from fleet.sim.personality import ARDUPILOT, Personality
from fleet.sim.physics import Limits


@dataclass(frozen=True)
class VehicleConfig:
    """A fake vehicle's settings. Those that are autopilot parameters (:mod:`fleet.sim.params`) default to
    None: the personality's parameter default (ArduCopter WPNAV_SPEED 10 m/s, PX4 MPC_XY_VEL_MAX 12 m/s,
    ...); a value given is the parameter's starting value, which a ground station may then change."""

    system_id: int = 1
    instance: int = 0  #: which vehicle of its simulator (SITL's -I): its telemetry keeps its own time
    personality: Personality = ARDUPILOT
    #: motion limits (WPNAV_* or MPC_*, LAND_SPEED or MPC_LAND_SPEED): every field of a Limits given starts them
    limits: Limits | None = None
    #: boot to a position estimate (arming possible); None: the personality's, as measured on its SITL. It
    #: may be shortened, never switched off: a ground station must wait for it as for a real autopilot.
    ready_after_s: float | None = None
    gps_after_s: float | None = None  #: boot to a GPS fix (at most ready_after_s); None: the personality's
    spool_up_s: float | None = None  #: an accepted take-off to leaving the ground; None: the personality's
    #: armed on the ground without a take-off (or after a touchdown) it disarms after this: DISARM_DELAY
    #: (whole seconds, 0 never), PX4's COM_DISARM_PRFLT and COM_DISARM_LAND
    auto_disarm_s: float | None = None
    min_arm_battery_pct: int = 20
    battery_pct: float = 100.0
    offboard_timeout_s: float | None = None  #: PX4's COM_OF_LOSS_T: no setpoint for this long leaves OFFBOARD
    guided_velocity_timeout_s: float | None = None  #: ArduCopter's GUID_TIMEOUT: a velocity setpoint older stops
    rtl_alt_m: float | None = None  #: RTL_ALT, PX4's RTL_RETURN_ALT
    takeoff_alt_m: float | None = None  #: PX4's MIS_TAKEOFF_ALT, when the command gives none
    #: parameters by name with their starting values (after the fields above), as a vehicle tuned by hand
    params: tuple[tuple[str, float], ...] = ()
    #: simulated seconds per second of the ground station's clock (the fleet's speedup): the velocities it
    #: sends are per second of its clock, as the schedule it streams them along runs
    speedup: float = 1.0
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
