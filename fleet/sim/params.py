"""The fake vehicle's parameters: each autopilot's small table, their live values, and MAVLink's
parameter protocol (PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET, each answered with PARAM_VALUE).

The values drive the model: the motion limits, the auto-disarm delays, the return and take-off
heights and the offboard and GUIDED timeouts are read from them (:class:`Setting`), so a PARAM_SET of
WPNAV_SPEED changes how fast the vehicle flies from the next step on. A :class:`VehicleConfig` value
given explicitly (``limits``, ``auto_disarm_s``, ...) is a parameter's starting value instead of its
default. As the real autopilots:

* ArduPilot (GCS_Param.cpp, Copter 4.5; 4.7 renames SYSID_THISMAV to MAV_SYSID) sends its firmware
  banner on PARAM_REQUEST_LIST, then streams every parameter a few per loop; values go as floats
  whatever their type (an INT16 of 50 as 50.0), an integer one set is truncated (+0.01, AP_Param's
  ``set_float``); a read or set of an unknown name or index, or of a NaN value, gets no answer;
* PX4 (mavlink_parameters.cpp, v1.15) numbers its parameters in name order, sends ``_HASH_CHECK``
  (index -1: 65535 in PARAM_VALUE's uint16) first and stops when a PARAM_SET of ``_HASH_CHECK``
  says the ground station's cache matched; an INT32 travels bytewise (its 4 bytes as the float); an
  unknown name set, or an unknown index read, gets a STATUSTEXT. (Unlike PX4, the fake takes no
  NaN or infinite float either: a limit of NaN would stall the physics.)
"""

from __future__ import annotations

import enum
import math
import struct
import zlib
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

from drona_gcs.workspace import VehicleLimits
from fleet.sim import telemetry
from fleet.sim.mav import ENC, Message, mavlink2
from fleet.sim.personality import ARDUPILOT, Personality
from fleet.sim.physics import Limits

if TYPE_CHECKING:
    from fleet.sim.config import VehicleConfig
    from fleet.sim.model import VehicleModel

REAL32: int = mavlink2.MAV_PARAM_TYPE_REAL32
INT8: int = mavlink2.MAV_PARAM_TYPE_INT8
INT16: int = mavlink2.MAV_PARAM_TYPE_INT16
INT32: int = mavlink2.MAV_PARAM_TYPE_INT32
_INT_RANGE = {INT8: (-(2**7), 2**7 - 1), INT16: (-(2**15), 2**15 - 1), INT32: (-(2**31), 2**31 - 1)}
CM = 0.01  #: metres per centimetre: ArduCopter's speeds and heights are in cm
GRAVITY = 9.80665  #: m/s²
PARAMS_PER_STEP = 5  #: PARAM_VALUEs streamed per step (the runner steps at 50 Hz: 250 a second)
HASH_CHECK = "_HASH_CHECK"
NO_INDEX = 0xFFFF  #: PARAM_VALUE's param_index (uint16) of PX4's _HASH_CHECK: C's -1
MIN_LIMIT = 0.05  #: a motion limit set to 0 or less flies at this (the autopilots clamp theirs too)


class Setting(enum.Enum):
    """A quantity of the model that a parameter sets, in SI units."""

    MAX_SPEED = "max_speed"  #: m/s horizontal (Limits.max_speed)
    MAX_ACCEL = "max_accel"  #: m/s² (Limits.max_accel)
    MAX_ACCEL_UP = "max_accel_up"  #: m/s², vertical (Limits.max_accel_up)
    MAX_ACCEL_DOWN = "max_accel_down"  #: m/s², vertical (Limits.max_accel_down)
    CLIMB_RATE = "climb_rate"  #: m/s (Limits.climb_rate)
    DESCENT_RATE = "descent_rate"  #: m/s (Limits.descent_rate)
    LAND_SPEED = "land_speed"  #: m/s, a landing's final descent (Limits.land_speed)
    PREFLIGHT_DISARM = "preflight_disarm"  #: s armed on the ground, not yet flown, before it disarms
    LANDED_DISARM = "landed_disarm"  #: s armed on the ground after a touchdown before it disarms
    RTL_ALT = "rtl_alt"  #: m, the return height
    TAKEOFF_ALT = "takeoff_alt"  #: m, PX4's take-off height when the command gives none
    OFFBOARD_TIMEOUT = "offboard_timeout"  #: s without a setpoint before PX4 leaves OFFBOARD
    GUIDED_TIMEOUT = "guided_timeout"  #: s before an ArduCopter GUIDED velocity setpoint stops
    SYSTEM_ID = "system_id"  #: reported only: both autopilots take a new id at their next boot
    SHAPING_JERK = "shaping_jerk"  #: m/s³, ArduCopter's PSC_JERK_XY: its position gain is jerk / (2 accel)
    SHAPING_JERK_Z = "shaping_jerk_z"  #: m/s³, ArduCopter's PSC_JERK_Z: its vertical shaping
    BATTERY_CAPACITY = "battery_capacity"  #: mAh, the pack the battery monitor counts down from
    SPEEDUP = "speedup"  #: reported only: simulated seconds per wall-clock second (ArduPilot SITL's SIM_SPEEDUP)


LIMIT_SETTINGS = (Setting.MAX_SPEED, Setting.MAX_ACCEL, Setting.MAX_ACCEL_UP, Setting.MAX_ACCEL_DOWN,
                  Setting.CLIMB_RATE, Setting.DESCENT_RATE, Setting.LAND_SPEED)

#: Settings one autopilot has no parameter for (it never uses them), unless the config gives them.
FALLBACK = {Setting.TAKEOFF_ALT: 2.5, Setting.OFFBOARD_TIMEOUT: 1.0, Setting.GUIDED_TIMEOUT: 3.0,
            Setting.BATTERY_CAPACITY: 5000.0}


@dataclass(frozen=True)
class Param:
    name: str
    default: float
    type: int = REAL32
    drives: tuple[Setting, ...] = ()
    scale: float = 1.0  #: SI units per unit of the parameter (0.01 for cm)


#: ArduCopter 4.5's defaults, in its own order (ArduPilot numbers them as it stores them).
ARDUCOPTER_PARAMS = (
    Param("SYSID_THISMAV", 1, INT16, (Setting.SYSTEM_ID,)),
    Param("WPNAV_SPEED", 1000, REAL32, (Setting.MAX_SPEED,), CM),
    Param("WPNAV_SPEED_UP", 250, REAL32, (Setting.CLIMB_RATE,), CM),
    Param("WPNAV_SPEED_DN", 150, REAL32, (Setting.DESCENT_RATE,), CM),
    Param("WPNAV_ACCEL", 250, REAL32, (Setting.MAX_ACCEL,), CM),
    Param("WPNAV_ACCEL_Z", 100, REAL32, (Setting.MAX_ACCEL_UP, Setting.MAX_ACCEL_DOWN), CM),
    Param("PSC_JERK_XY", 5.0, REAL32, (Setting.SHAPING_JERK,)),
    Param("PSC_JERK_Z", 5.0, REAL32, (Setting.SHAPING_JERK_Z,)),
    Param("LAND_SPEED", 50, INT16, (Setting.LAND_SPEED,), CM),
    Param("RTL_ALT", 1500, INT32, (Setting.RTL_ALT,), CM),
    Param("DISARM_DELAY", 10, INT8, (Setting.PREFLIGHT_DISARM, Setting.LANDED_DISARM)),
    Param("GUID_TIMEOUT", 3, REAL32, (Setting.GUIDED_TIMEOUT,)),
    Param("ANGLE_MAX", 3000, INT16),  # cdeg: its lean angle bounds WPNAV_ACCEL
    Param("ATC_ACCEL_R_MAX", 110000, REAL32),  # cdeg/s²: the attitude controller's bounds PSC_JERK_XY
    Param("ATC_ACCEL_P_MAX", 110000, REAL32),
    Param("FENCE_ENABLE", 0, INT8),
    Param("FENCE_TYPE", 7, INT8),  # max altitude, circle and polygon
    Param("ARMING_CHECK", 1, INT32),
    Param("BATT_CAPACITY", 5000, INT32, (Setting.BATTERY_CAPACITY,)),  # the fake's pack (ArduCopter's: 3300)
    Param("SIM_SPEEDUP", 1.0, REAL32, (Setting.SPEEDUP,)),  # SITL's: a ground station reads its speedup there
)

#: PX4 v1.15's defaults, numbered in name order as PX4 does.
PX4_PARAMS = tuple(sorted((
    Param("MAV_SYS_ID", 1, INT32, (Setting.SYSTEM_ID,)),
    Param("MPC_XY_VEL_MAX", 12.0, REAL32, (Setting.MAX_SPEED,)),
    Param("MPC_XY_CRUISE", 5.0),  # AUTO missions' speed; offboard setpoints fly up to MPC_XY_VEL_MAX
    Param("MPC_ACC_HOR", 3.0, REAL32, (Setting.MAX_ACCEL,)),
    Param("MPC_ACC_UP_MAX", 4.0, REAL32, (Setting.MAX_ACCEL_UP,)),
    Param("MPC_ACC_DOWN_MAX", 3.0, REAL32, (Setting.MAX_ACCEL_DOWN,)),
    Param("MPC_Z_VEL_MAX_UP", 3.0, REAL32, (Setting.CLIMB_RATE,)),
    Param("MPC_Z_VEL_MAX_DN", 1.5, REAL32, (Setting.DESCENT_RATE,)),
    Param("MPC_LAND_SPEED", 0.7, REAL32, (Setting.LAND_SPEED,)),
    Param("MIS_TAKEOFF_ALT", 2.5, REAL32, (Setting.TAKEOFF_ALT,)),
    Param("RTL_RETURN_ALT", 60.0, REAL32, (Setting.RTL_ALT,)),
    Param("COM_DISARM_LAND", 2.0, REAL32, (Setting.LANDED_DISARM,)),
    Param("COM_DISARM_PRFLT", 10.0, REAL32, (Setting.PREFLIGHT_DISARM,)),
    Param("COM_OF_LOSS_T", 1.0, REAL32, (Setting.OFFBOARD_TIMEOUT,)),
    Param("GF_ACTION", 1, INT32),  # warning only
    Param("BAT1_CAPACITY", 5000.0, REAL32, (Setting.BATTERY_CAPACITY,)),  # the fake's pack (PX4's: -1, unknown)
), key=lambda p: p.name))

TABLES: dict[str, tuple[Param, ...]] = {"ardupilot": ARDUCOPTER_PARAMS, "px4": PX4_PARAMS}


def starting_settings(config: VehicleConfig) -> dict[Setting, float]:
    """The settings a config gives explicitly (each the starting value of its parameter)."""
    start: dict[Setting, float] = {Setting.SYSTEM_ID: config.system_id, Setting.SPEEDUP: config.speedup}
    if config.limits is not None:
        start.update({s: getattr(config.limits, s.value) for s in LIMIT_SETTINGS})
    given = {Setting.PREFLIGHT_DISARM: config.auto_disarm_s, Setting.LANDED_DISARM: config.auto_disarm_s,
             Setting.RTL_ALT: config.rtl_alt_m, Setting.TAKEOFF_ALT: config.takeoff_alt_m,
             Setting.OFFBOARD_TIMEOUT: config.offboard_timeout_s,
             Setting.GUIDED_TIMEOUT: config.guided_velocity_timeout_s}
    start.update({s: v for s, v in given.items() if v is not None})
    return start


def arducopter_shaping(wpnav_accel: float, psc_jerk: float, angle_max_cdeg: float, roll_accel_cdeg: float,
                       pitch_accel_cdeg: float) -> tuple[float, float]:
    """The horizontal acceleration and jerk ArduCopter shapes with: WPNAV_ACCEL, at most what its lean
    angle gives; PSC_JERK_XY, at most what its attitude controller's angular acceleration gives
    (``AC_PosControl::set_max_speed_accel_NE_m``; 0: not limited)."""
    accel = max(MIN_LIMIT, min(wpnav_accel, GRAVITY * math.tan(math.radians(angle_max_cdeg / 100))))
    jerk = max(MIN_LIMIT, psc_jerk)
    snap = min(roll_accel_cdeg, pitch_accel_cdeg) / 100 * math.pi / 180 * GRAVITY
    return accel, min(jerk, 0.5 * math.sqrt(accel * snap)) if snap > 0 else jerk


def limit_params(limits: VehicleLimits, personality: Personality) -> tuple[tuple[str, float], ...]:
    """The parameters, in ``personality``'s names and units, that set a workspace's vehicle limits
    (those its table has: PX4's has no jerk)."""
    wanted = {Setting.MAX_SPEED: limits.speed_m_s, Setting.MAX_ACCEL: limits.accel_m_s2,
              Setting.SHAPING_JERK: limits.jerk_m_s3, Setting.CLIMB_RATE: limits.climb_m_s,
              Setting.DESCENT_RATE: limits.descent_m_s, Setting.MAX_ACCEL_UP: limits.accel_z_m_s2,
              Setting.MAX_ACCEL_DOWN: limits.accel_z_m_s2, Setting.SHAPING_JERK_Z: limits.jerk_z_m_s3}
    tuned = list({p.name: wanted[s] / p.scale for p in TABLES[personality.name] for s in p.drives
                  if s in wanted}.items())
    if personality is ARDUPILOT:  # the lean angle and the attitude controller must allow them
        lean = math.degrees(math.atan(limits.accel_m_s2 / GRAVITY))
        tuned.append(("ANGLE_MAX", float(max(3000, math.ceil(lean) * 100))))
        if arducopter_shaping(limits.accel_m_s2, limits.jerk_m_s3, 9000, 110000, 110000)[1] < limits.jerk_m_s3:
            tuned += [("ATC_ACCEL_R_MAX", 0.0), ("ATC_ACCEL_P_MAX", 0.0)]
    return tuple(tuned)


def starting_limits(config: VehicleConfig) -> Limits:
    """The motion limits a vehicle so configured starts with (its parameters' starting values)."""
    return ParamStore(config).limits


class ParamStore:
    """One vehicle's parameter values (its table's order is their index), and the list being streamed."""

    def __init__(self, config: VehicleConfig) -> None:
        self.personality: Personality = config.personality
        self.table = TABLES[config.personality.name]
        self._index = {p.name: i for i, p in enumerate(self.table)}
        start = starting_settings(config)
        self._values = [_starting_value(p, start) for p in self.table]
        for name, value in config.params:
            if name not in self._index:
                raise ValueError(f"--param: {config.personality.name} has no parameter {name}")
            self._values[self._index[name]] = _stored(self.table[self._index[name]], value)
        self._driver = {s: i for i, p in enumerate(self.table) for s in p.drives}
        self._fixed = {s: start.get(s, FALLBACK.get(s, 0.0)) for s in Setting if s not in self._driver}
        self._shape = config.limits or Limits()  #: gain and land_speed_high_alt: no parameter sets them
        self._queue: deque[int] = deque()  #: indices still to stream (-1: PX4's _HASH_CHECK)
        self.limits = self._limits()

    def __len__(self) -> int:
        return len(self.table)

    def __contains__(self, name: str) -> bool:
        return name in self._index

    def value(self, name: str) -> float:
        return self._values[self._index[name]]

    def setting(self, setting: Setting) -> float:
        """A setting's live value, in SI units."""
        i = self._driver.get(setting)
        return self._fixed[setting] if i is None else self._values[i] * self.table[i].scale

    # -------------------------------------------------------------- protocol
    def request_list(self) -> list[Message]:
        """Start streaming every parameter (again, from the first, if a stream is under way)."""
        self._queue = deque(range(len(self.table)))
        if self.personality is ARDUPILOT:  # "requesting parameters is a convenient way to get extra information"
            return [telemetry.statustext(mavlink2.MAV_SEVERITY_INFO, text) for text in self.personality.banner]
        self._queue.appendleft(-1)
        return []

    def stream(self) -> list[Message]:
        """The next few PARAM_VALUEs of a list being streamed."""
        out: list[Message] = []
        while self._queue and len(out) < PARAMS_PER_STEP:
            i = self._queue.popleft()
            out.append(self._hash() if i < 0 else self.value_message(i))
        return out

    def read(self, name: str, index: int) -> list[Message]:
        if index >= 0:  # by index; the name is not looked at
            if index < len(self.table):
                return [self.value_message(index)]
            return [] if self.personality is ARDUPILOT else [_info(f"[pm] unknown param ID: {index}")]
        if name == HASH_CHECK and self.personality is not ARDUPILOT:
            return [self._hash()]
        i = self._index.get(name)
        return [] if i is None else [self.value_message(i)]

    def set(self, name: str, sent: float) -> list[Message]:
        """PARAM_SET: store and answer the new value; unknown names and non-finite values change nothing."""
        i = self._index.get(name)
        if i is None:
            if self.personality is ARDUPILOT:
                return []
            if name == HASH_CHECK:  # the ground station's cache matched: stop streaming
                self._queue.clear()
                return []
            return [_info(f"[pm] unknown param: {name}")]
        value = self._received(self.table[i], sent)
        if value is None:
            return []
        self._values[i] = value
        self.limits = self._limits()
        return [self.value_message(i)]

    def value_message(self, i: int) -> Message:
        p = self.table[i]
        return ENC.param_value_encode(p.name.encode(), self._sent(p, self._values[i]), p.type, len(self.table), i)

    # ------------------------------------------------------------- internals
    def _limits(self) -> Limits:
        values = {s.value: max(MIN_LIMIT, self.setting(s)) for s in LIMIT_SETTINGS}
        gain, jerk = self._shape.gain, math.inf
        if Setting.SHAPING_JERK in self._driver:  # ArduCopter: a higher WPNAV_ACCEL makes it slower to close in
            accel, jerk = arducopter_shaping(values[Setting.MAX_ACCEL.value], self.setting(Setting.SHAPING_JERK),
                                             self.value("ANGLE_MAX"), self.value("ATC_ACCEL_R_MAX"),
                                             self.value("ATC_ACCEL_P_MAX"))
            values[Setting.MAX_ACCEL.value] = accel
            gain = jerk / (2 * accel)
        jerk_z = math.inf
        if Setting.SHAPING_JERK_Z in self._driver:  # ArduCopter shapes its vertical target too
            jerk_z = max(MIN_LIMIT, self.setting(Setting.SHAPING_JERK_Z))
        return Limits(**values, land_speed_high_alt=self._shape.land_speed_high_alt, gain=gain,
                      gain_z=self._shape.gain_z, jerk=jerk, jerk_z=jerk_z)

    def _bytewise(self, p: Param) -> bool:
        return p.type != REAL32 and self.personality is not ARDUPILOT

    def _sent(self, p: Param, value: float) -> float:
        """The PARAM_VALUE float: PX4 sends an integer's bytes, ArduPilot casts it."""
        return _int_bits_as_float(round(value)) if self._bytewise(p) else value

    def _received(self, p: Param, sent: float) -> float | None:
        """A PARAM_SET's value as stored (None: refused); PX4 takes an integer's bytes."""
        if self._bytewise(p):
            return float(struct.unpack("<i", struct.pack("<f", sent))[0])
        return _stored(p, sent) if math.isfinite(sent) else None

    def _hash(self) -> Message:
        """PX4's _HASH_CHECK: a CRC-32 of every name and value, which a ground station compares with its cache."""
        crc = 0
        for p, value in zip(self.table, self._values, strict=True):
            data = struct.pack("<i", round(value)) if p.type != REAL32 else struct.pack("<f", value)
            crc = zlib.crc32(p.name.encode() + data, crc)
        return ENC.param_value_encode(HASH_CHECK.encode(), _int_bits_as_float(crc, "<I"),
                                      mavlink2.MAV_PARAM_TYPE_UINT32, len(self.table), NO_INDEX)


def _starting_value(p: Param, start: dict[Setting, float]) -> float:
    given = next((start[s] for s in p.drives if s in start), None)
    return float(p.default) if given is None else _stored(p, given / p.scale)


def _stored(p: Param, value: float) -> float:
    """A value as the parameter holds it: an integer type truncates within its range (+0.01 against a
    float just under a whole number, as AP_Param's ``set_float``)."""
    if p.type == REAL32:
        return value
    low, high = _INT_RANGE[p.type]
    return float(max(low, min(high, math.trunc(value + math.copysign(0.01, value)))))


def _int_bits_as_float(value: int, fmt: str = "<i") -> float:
    return float(struct.unpack("<f", struct.pack(fmt, value))[0])


def _info(text: str) -> Message:
    return telemetry.statustext(mavlink2.MAV_SEVERITY_INFO, text)


def _name(param_id: str | bytes) -> str:
    """A PARAM_* message's param_id (up to 16 characters, NUL-padded) as text."""
    raw = param_id.encode("latin-1") if isinstance(param_id, str) else param_id
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


# ------------------------------------------------------------ the handlers (model.VehicleModel answers with these)
def on_request_list(m: VehicleModel, msg: Message, now: float) -> list[Message]:
    return m.params.request_list()


def on_request_read(m: VehicleModel, msg: Message, now: float) -> list[Message]:
    return m.params.read(_name(msg.param_id), msg.param_index)


def on_set(m: VehicleModel, msg: Message, now: float) -> list[Message]:
    return m.params.set(_name(msg.param_id), msg.param_value)
