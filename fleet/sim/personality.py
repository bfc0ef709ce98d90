"""What differs between the ArduCopter and the PX4 fake: mode numbers, results, texts and default streams.

ArduCopter's ``custom_mode`` is the mode number itself (STABILIZE 0, GUIDED 4, LOITER 5,
RTL 6, LAND 9, BRAKE 17). PX4 packs a main and a sub mode:
``custom_mode = (main << 16) | (sub << 24)`` with main POSCTL 3, AUTO 4, OFFBOARD 6 and the
AUTO sub modes TAKEOFF 2, LOITER 3, RTL 5, LAND 6.

Every mode maps to one :class:`Behaviour`, which is all the model needs to know to fly it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from fleet.sim.mav import mavlink2


class Behaviour(enum.Enum):
    MANUAL = "manual"  #: no position control (STABILIZE): stays put, no takeoff
    FOLLOW = "follow"  #: follows SET_POSITION_TARGET_* setpoints (GUIDED, OFFBOARD)
    HOLD = "hold"  #: stops and holds its position (LOITER, BRAKE, POSCTL, AUTO.LOITER)
    TAKEOFF = "takeoff"  #: climbs to the takeoff altitude, then holds (PX4 AUTO.TAKEOFF)
    RTL = "rtl"  #: climbs to the return altitude, flies home, lands
    LAND = "land"  #: descends where it is, lands and disarms


def px4_mode(main: int, sub: int = 0) -> int:
    """PX4's packed custom mode."""
    return (main << 16) | (sub << 24)


@dataclass(frozen=True)
class Personality:
    name: str
    autopilot: int  #: MAV_AUTOPILOT_*
    modes: dict[str, tuple[int, Behaviour]]  #: mode name -> (custom_mode, behaviour)
    boot_mode: str
    follow_mode: str  #: the mode that follows setpoints
    hold_mode: str  #: where the vehicle goes when a takeoff completes or offboard is lost
    land_mode: str
    rtl_mode: str
    takeoff_mode: str | None  #: PX4 switches to AUTO.TAKEOFF on MAV_CMD_NAV_TAKEOFF; ArduCopter stays in GUIDED
    rejected: int  #: MAV_RESULT_* for a refused arm, takeoff or mode change
    flight_sw_version: int
    default_streams: dict[int, float] = field(default_factory=dict)  #: message id -> interval (s) at boot
    text_not_ready: str = ""
    text_low_battery: str = ""
    gps_fix_s: float = 10.0  #: boot to a GPS fix, by default
    ready_s: float = 15.0  #: boot to a position estimate (arming possible), by default
    gps_fix_type: int = mavlink2.GPS_FIX_TYPE_3D_FIX  #: what GPS_RAW_INT says once it has a fix
    spool_up_s: float = 1.0  #: an accepted take-off to leaving the ground
    #: every simulated vehicle has system id 1 (ArduPilot SITL's SYSID_THISMAV), not 1, 2, 3...
    one_system_id: bool = False
    #: GLOBAL_POSITION_INT before the position estimate: sent, at 0 degrees (ArduPilot), or not at all
    stale_position: bool = False
    banner: tuple[str, ...] = ()  #: STATUSTEXTs answering PARAM_REQUEST_LIST (ArduPilot's send_banner)

    def mode_name(self, custom_mode: int) -> str | None:
        return next((name for name, (number, _) in self.modes.items() if number == custom_mode), None)

    def custom_mode(self, name: str) -> int:
        return self.modes[name][0]

    def behaviour(self, name: str) -> Behaviour:
        return self.modes[name][1]

    def mode_from_command(self, param2: int, param3: int) -> int:
        """MAV_CMD_DO_SET_MODE's custom mode: param2 for ArduPilot, main param2 and sub param3 for PX4."""
        if self.autopilot == mavlink2.MAV_AUTOPILOT_PX4:
            return px4_mode(param2, param3)
        return param2


ARDUPILOT = Personality(
    name="ardupilot",
    autopilot=mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
    modes={
        "STABILIZE": (0, Behaviour.MANUAL),
        "GUIDED": (4, Behaviour.FOLLOW),
        "LOITER": (5, Behaviour.HOLD),
        "RTL": (6, Behaviour.RTL),
        "LAND": (9, Behaviour.LAND),
        "BRAKE": (17, Behaviour.HOLD),
    },
    boot_mode="STABILIZE",
    follow_mode="GUIDED",
    hold_mode="LOITER",
    land_mode="LAND",
    rtl_mode="RTL",
    takeoff_mode=None,
    rejected=mavlink2.MAV_RESULT_FAILED,
    flight_sw_version=(4 << 24) | (5 << 16) | (7 << 8) | 255,  # Copter 4.5.7 official
    text_not_ready="Arm: Need Position Estimate",
    text_low_battery="PreArm: Battery 1 below minimum arming capacity",
    # Measured on ArduCopter SITL V4.7.0-dev.
    gps_fix_s=10.0,
    ready_s=41.5,
    gps_fix_type=mavlink2.GPS_FIX_TYPE_RTK_FIXED,
    spool_up_s=3.5,
    one_system_id=True,
    stale_position=True,
    banner=("ArduCopter V4.5.7", "Frame: QUAD/X"),
)

PX4 = Personality(
    name="px4",
    autopilot=mavlink2.MAV_AUTOPILOT_PX4,
    modes={
        "POSCTL": (px4_mode(3), Behaviour.HOLD),
        "AUTO.TAKEOFF": (px4_mode(4, 2), Behaviour.TAKEOFF),
        "AUTO.LOITER": (px4_mode(4, 3), Behaviour.HOLD),
        "AUTO.RTL": (px4_mode(4, 5), Behaviour.RTL),
        "AUTO.LAND": (px4_mode(4, 6), Behaviour.LAND),
        "OFFBOARD": (px4_mode(6), Behaviour.FOLLOW),
    },
    boot_mode="AUTO.LOITER",
    follow_mode="OFFBOARD",
    hold_mode="AUTO.LOITER",
    land_mode="AUTO.LAND",
    rtl_mode="AUTO.RTL",
    takeoff_mode="AUTO.TAKEOFF",
    rejected=mavlink2.MAV_RESULT_TEMPORARILY_REJECTED,
    flight_sw_version=(1 << 24) | (15 << 16) | (0 << 8) | 255,  # v1.15.0 release
    default_streams={
        mavlink2.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
        mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
        mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
        mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
        mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 0.1,
        mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.2,
        mavlink2.MAVLINK_MSG_ID_ATTITUDE: 0.1,
    },
    text_not_ready="Arming denied: no position estimate",
    text_low_battery="Arming denied: low battery",
)

PERSONALITIES: dict[str, Personality] = {p.name: p for p in (ARDUPILOT, PX4)}
