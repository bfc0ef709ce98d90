"""What a vehicle's autopilot lets it fly, read from its parameters, against the workspace's ``vehicle``.

Lambda, and so the window every plan keeps, is derived from the workspace's limits: a vehicle whose
autopilot is set slower comes later than lambda, and its peers' margin is gone. So an agent reads
them once connected and refuses a vehicle short of them, naming the parameter; and one set lower in
flight (an autopilot tells every ground station of a parameter set) puts the drone out of its bound.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from drona_gcs.workspace import VehicleLimits
from fleet.vehicle.link import Autopilot

GRAVITY = 9.80665
SPEEDUP = "SIM_SPEEDUP"  #: ArduPilot SITL's: its seconds are this many times shorter than the wall clock's
LEAN = "ANGLE_MAX"  #: ArduCopter's lean angle (cdeg): it bounds the acceleration to g tan(angle)
SLACK = 1e-6  #: a limit set from the workspace in other units (cm, a speedup) may come back rounded


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
    return [p.name for p in LIMIT_PARAMS[autopilot]] + [LEAN, SPEEDUP]


def shortfalls(autopilot: Autopilot, values: Mapping[str, float], wanted: VehicleLimits, *,
               unanswered: bool = True) -> list[str]:
    """Each way the vehicle, as its parameters ``values`` set it, flies less than ``wanted``: a limit
    below the workspace's, or (``unanswered``) a parameter that did not answer. A simulator's speedup
    (SIM_SPEEDUP, if it answered) counts: limits are in the fleet's seconds."""
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
    return short
