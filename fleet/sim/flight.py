"""The flight rules of the fake vehicle, stepped with ``now``: what it flies to, and what time does.

Every step: a vehicle armed on the ground without a takeoff disarms after its auto-disarm delay
(PX4: one before its first take-off since arming, another after a touchdown; 0 or less: never);
PX4 leaves OFFBOARD for AUTO.LOITER once the setpoints stop; an ArduCopter GUIDED velocity
setpoint not renewed for GUID_TIMEOUT stops (a position given with it stops moving on). Then the
body moves towards the mode's target within the live motion limits, touchdown and takeoff
completion are noticed (LAND and RTL disarm on touchdown), and the battery drains (in the air,
armed) or charges (landed, disarmed, on a charging station). Every delay, limit and height is a
parameter's live value (:mod:`fleet.sim.params`).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

from fleet.sim.mav import mavlink2
from fleet.sim.params import Setting
from fleet.sim.personality import ARDUPILOT, Behaviour
from fleet.sim.physics import HOLD_STILL, Target

if TYPE_CHECKING:
    from fleet.sim.model import VehicleModel


def advance(m: VehicleModel, now: float, dt: float) -> None:
    """Apply the rules at ``now``, then fly and drain (or charge) for ``dt`` seconds."""
    _rules(m, now)
    m.body.limits = m.params.limits  # a PARAM_SET takes effect from the next step
    m.body.step(_motion_target(m, now), dt)
    _carry_on(m, dt)
    _after_motion(m, now)
    m.battery.capacity_mah = m.params.setting(Setting.BATTERY_CAPACITY)  # the monitor counts down from it
    m.battery.step(dt, _current(m))


def _rules(m: VehicleModel, now: float) -> None:
    p = m.personality
    delay = m.params.setting(Setting.LANDED_DISARM if m.flown else Setting.PREFLIGHT_DISARM)
    if m.armed and not m.airborne and m.takeoff_point is None and 0 < delay < now - m.landed_since:
        m.text(mavlink2.MAV_SEVERITY_INFO, "Disarming motors" if p is ARDUPILOT else "Auto disarmed")
        m.disarm(now)
    if m.mode == p.follow_mode and p is not ARDUPILOT and not m.streaming(now):
        m.text(mavlink2.MAV_SEVERITY_CRITICAL, "Offboard signal lost: holding")
        m.enter_mode(p.hold_mode, now)
    if (p is ARDUPILOT and m.setpoint is not None and m.setpoint.moving
            and m.setpoint_times and now - m.setpoint_times[-1] > m.params.setting(Setting.GUIDED_TIMEOUT)):
        # GUIDED velocity control times out: stop; a moving position stays where it got to
        m.setpoint = None if not m.setpoint.has_horizontal_position else replace(m.setpoint, vn=0.0, ve=0.0, vd=0.0,
                                                                                  an=0.0, ae=0.0)


def _carry_on(m: VehicleModel, dt: float) -> None:
    """ArduCopter moves a GUIDED position target given with a velocity (and an acceleration) on at that
    velocity (its position controller integrates the target); PX4 takes them as feed-forward only."""
    sp = m.setpoint
    if m.personality is not ARDUPILOT or sp is None or not sp.moving or m.behaviour is not Behaviour.FOLLOW:
        return
    if sp.north is not None and sp.east is not None:
        sp = replace(sp, north=sp.north + sp.vn * dt + sp.an * dt * dt / 2,
                     east=sp.east + sp.ve * dt + sp.ae * dt * dt / 2, vn=sp.vn + sp.an * dt, ve=sp.ve + sp.ae * dt)
    if sp.down is not None:
        sp = replace(sp, down=sp.down + sp.vd * dt)
    m.setpoint = sp


def _motion_target(m: VehicleModel, now: float) -> Target | None:
    if not m.armed:
        return None
    behaviour, b, lim = m.behaviour, m.body, m.params.limits
    if not m.airborne and m.takeoff_point is None and not (
            behaviour is Behaviour.FOLLOW and m.personality is not ARDUPILOT):
        return None  # armed on the ground, idle
    if not m.airborne and now < m.climb_at:
        return None  # the motors spool up
    if behaviour is Behaviour.TAKEOFF:
        return m.takeoff_point or HOLD_STILL
    if behaviour is Behaviour.FOLLOW:
        return m.setpoint or HOLD_STILL
    if behaviour is Behaviour.LAND:
        return Target(vd=lim.descent_rate if b.height > lim.land_speed_high_alt else lim.land_speed)
    if behaviour is Behaviour.RTL:
        return _rtl_target(m)
    return HOLD_STILL  # HOLD, and MANUAL in the air (no sticks: it hovers)


def _rtl_target(m: VehicleModel) -> Target:
    """Climb to the return height (RTL_ALT, or higher if already higher), fly home, land."""
    b, lim = m.body, m.params.limits
    far = math.hypot(b.north, b.east) > 0.5
    height = max(m.params.setting(Setting.RTL_ALT), b.height)
    if far and b.height < height - 0.5:
        return Target(down=-height)  # climb first
    if far:
        return Target(0.0, 0.0, -height)
    return Target(0.0, 0.0, vd=lim.descent_rate if b.height > lim.land_speed_high_alt else lim.land_speed)


def _after_motion(m: VehicleModel, now: float) -> None:
    b = m.body
    if not m.airborne and b.height > 0.2:
        m.airborne = m.flown = True
    if m.takeoff_point is not None and m.takeoff_point.down is not None \
            and b.down <= m.takeoff_point.down + 0.3:
        m.takeoff_point = None
        if m.personality.takeoff_mode and m.mode == m.personality.takeoff_mode:
            m.enter_mode(m.personality.hold_mode, now)
    if m.airborne and b.down >= 0.0:  # touchdown
        m.airborne = False
        m.landed_since = now
        b.stop()
        if m.behaviour in (Behaviour.LAND, Behaviour.RTL) and m.armed:
            m.text(mavlink2.MAV_SEVERITY_INFO, "Landed, disarming")
            m.disarm(now)


def _current(m: VehicleModel) -> float:
    if m.airborne or (m.takeoff_point is not None and m.last_step >= m.climb_at):
        return m.config.hover_current_a + 0.8 * m.body.ground_speed
    if m.armed:
        return 2.0
    if m.battery.remaining < 1.0 and m.on_charger():
        return -m.config.charge_current_a
    return 0.3
