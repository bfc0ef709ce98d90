"""What a vehicle's autopilot lets it fly, read from its parameters, against the workspace's ``vehicle``.

Lambda, and so the window every plan keeps, is derived from the workspace's limits: a vehicle whose
autopilot is set slower comes later than lambda, and its peers' margin is gone. So an agent reads
them once connected and refuses a vehicle short of them, naming the parameter; and one set lower in
flight (an autopilot tells every ground station of a parameter set) puts the drone out of its bound.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

from drona_gcs.workspace import VehicleLimits
from fleet.vehicle.link import Autopilot, VehicleLink

log = logging.getLogger(__name__)

GRAVITY = 9.80665
SPEEDUP = "SIM_SPEEDUP"  #: ArduPilot SITL's: its seconds are this many times shorter than the wall clock's
LEAN = "ANGLE_MAX"  #: ArduCopter's lean angle (cdeg): it bounds the acceleration to g tan(angle)
SLACK = 1e-6  #: a limit set from the workspace in other units (cm, a speedup) may come back rounded
#: ArduCopter's: how long it flies on along its last GUIDED setpoint's velocity once setpoints stop (s)
GUIDED_TIMEOUT = "GUID_TIMEOUT"


@dataclass(frozen=True)
class LimitParam:
    """Parameter ``name`` gives limit ``field`` in its units times ``scale``; a vehicle sped up S times
    flies S ** ``per_second`` times more of it."""

    name: str
    field: str
    scale: float = 1.0
    per_second: int = 1


LIMIT_PARAMS = {
    Autopilot.ARDUPILOT: (LimitParam("WPNAV_SPEED", "speed_m_s", 0.01),
                          LimitParam("WPNAV_ACCEL", "accel_m_s2", 0.01, 2),
                          LimitParam("PSC_JERK_XY", "jerk_m_s3", 1.0, 3),
                          LimitParam("WPNAV_SPEED_UP", "climb_m_s", 0.01),
                          LimitParam("WPNAV_SPEED_DN", "descent_m_s", 0.01),
                          LimitParam("WPNAV_ACCEL_Z", "accel_z_m_s2", 0.01, 2),
                          LimitParam("PSC_JERK_Z", "jerk_z_m_s3", 1.0, 3)),
    Autopilot.PX4: (LimitParam("MPC_XY_VEL_MAX", "speed_m_s"), LimitParam("MPC_ACC_HOR", "accel_m_s2", 1.0, 2),
                    LimitParam("MPC_Z_VEL_MAX_UP", "climb_m_s"), LimitParam("MPC_Z_VEL_MAX_DN", "descent_m_s"),
                    LimitParam("MPC_ACC_UP_MAX", "accel_z_m_s2", 1.0, 2),
                    LimitParam("MPC_ACC_DOWN_MAX", "accel_z_m_s2", 1.0, 2)),
}


def parameters_to_read(autopilot: Autopilot) -> list[str]:
    """The parameters :func:`shortfalls` judges ``autopilot`` by (none for an autopilot it does not know)."""
    if autopilot is not Autopilot.ARDUPILOT:
        return [p.name for p in LIMIT_PARAMS.get(autopilot, ())]
    return [p.name for p in LIMIT_PARAMS[autopilot]] + [LEAN, GUIDED_TIMEOUT, SPEEDUP]


def flying_on_s(tau_s: float) -> float:
    """The longest a vehicle may fly on along its last setpoint once its agent stops (killed, its host
    down): half a period. A sweep moves at most a cell per tau, along the plan, so the vehicle ends at
    most half a cell on, in the cell its plan flies next: one its peers hold, as they hold every cell of
    a departed drone's plans. ArduCopter's default (GUID_TIMEOUT 3 s) flew a killed drone's vehicle
    four cells on, across its peers' paths."""
    return tau_s / 2


def shortfalls(autopilot: Autopilot, values: Mapping[str, float], wanted: VehicleLimits, tau_s: float, *,
               unanswered: bool = True) -> list[str]:
    """Each way the vehicle, as its parameters ``values`` set it, flies less than ``wanted``, or flies on
    longer than :func:`flying_on_s` once its agent stops: a limit short of the workspace's, or
    (``unanswered``) a parameter that did not answer. A simulator's speedup (SIM_SPEEDUP, if it answered)
    counts: limits are in the fleet's seconds."""
    speedup = values.get(SPEEDUP, 1.0)
    short = []
    for param in LIMIT_PARAMS.get(autopilot, ()):
        needs = getattr(wanted, param.field)
        if param.name not in values:
            if unanswered:
                short.append(f"{param.name} did not answer (the workspace's vehicle.{param.field} is {needs:g})")
            continue
        flies = values[param.name] * param.scale * speedup**param.per_second
        if flies < needs * (1 - SLACK):
            short.append(f"{param.name} {values[param.name]:g} gives {flies:.3g}, under the workspace's "
                         f"vehicle.{param.field} {needs:g}")
    if autopilot is Autopilot.ARDUPILOT and LEAN in values:
        leans = GRAVITY * math.tan(math.radians(values[LEAN] / 100)) * speedup**2
        if leans < wanted.accel_m_s2 * (1 - SLACK):
            short.append(f"{LEAN} {values[LEAN]:g} leans to {leans:.3g} m/s² at most, under the workspace's "
                         f"vehicle.accel_m_s2 {wanted.accel_m_s2:g}")
    return short + _flying_on(autopilot, values, tau_s, speedup, unanswered)


async def bound_flying_on(link: VehicleLink, autopilot: Autopilot, values: dict[str, float],
                          tau_s: float, drone: str) -> dict[str, float]:
    """An ArduCopter set to fly on longer than :func:`flying_on_s` once its agent stops is set to that
    (GUID_TIMEOUT, in a simulator's own seconds; ArduPilot keeps it); ``values`` with what it then holds."""
    speedup = values.get(SPEEDUP, 1.0)
    if not _flying_on(autopilot, values, tau_s, speedup, unanswered=False):
        return values
    held = await link.set_parameter(GUIDED_TIMEOUT, flying_on_s(tau_s) * speedup)
    log.info("drone %s: its vehicle's %s set from %g to %s: once its agent stops it flies on half a period at most",
             drone, GUIDED_TIMEOUT, values[GUIDED_TIMEOUT], held)
    return values if held is None else {**values, GUIDED_TIMEOUT: held}


def _flying_on(autopilot: Autopilot, values: Mapping[str, float], tau_s: float, speedup: float,
               unanswered: bool) -> list[str]:
    if autopilot is not Autopilot.ARDUPILOT:
        return []  # not judged: PX4 takes no position on, and leaves OFFBOARD COM_OF_LOSS_T after the last setpoint
    if GUIDED_TIMEOUT not in values:
        return [f"{GUIDED_TIMEOUT} did not answer (a vehicle may fly on {flying_on_s(tau_s):g} s at most once its "
                "agent stops)"] if unanswered else []
    on = values[GUIDED_TIMEOUT] / speedup
    if on <= flying_on_s(tau_s) * (1 + SLACK):
        return []
    return [f"{GUIDED_TIMEOUT} {values[GUIDED_TIMEOUT]:g} flies it on {on:.3g} s along its last setpoint once its "
            f"agent stops, over half a period ({flying_on_s(tau_s):g} s)"]
