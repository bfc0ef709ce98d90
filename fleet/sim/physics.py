"""Point-mass kinematics and a battery, both stepped by the caller with a time step (no clock here).

The local frame is NED in metres with its origin on the ground at the vehicle's home, as a
real autopilot's EKF origin: ``down`` is 0 on the ground and negative in the air.

The position controller is the one a multicopter's is shaped like: the commanded speed
towards a position target is ``min(max_speed, sqrt(2 * accel * distance), gain * distance)``
(cruise, then a braking curve, then a gentle final approach), and the velocity moves towards
it at most ``max_accel`` per second. Horizontal speed therefore never exceeds ``max_speed``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Integration step (s of simulated time); a longer step is split into these.
SUBSTEP_S = 0.02


@dataclass(frozen=True)
class Limits:
    """Motion limits; the defaults are ArduCopter's (WPNAV_SPEED 10 m/s, WPNAV_ACCEL 2.5 m/s², ...).

    A vehicle flies its parameters' (:mod:`fleet.sim.params`), which a ground station may change."""

    max_speed: float = 10.0  #: horizontal, m/s
    max_accel: float = 2.5  #: m/s², each of horizontal and vertical
    climb_rate: float = 2.5  #: m/s
    descent_rate: float = 1.5  #: m/s
    land_speed: float = 0.5  #: m/s, the final descent of a landing
    land_speed_high_alt: float = 10.0  #: m, above this a landing descends at descent_rate
    gain: float = 1.0  #: 1/s, position error to speed near a target (ArduCopter's jerk / (2 accel), PX4's MPC_XY_P)
    gain_z: float = 1.5  #: 1/s, the same vertically


@dataclass(frozen=True)
class Target:
    """What the controller flies to: a position on each axis group given, else a velocity."""

    north: float | None = None  #: horizontal position (with east), else fly (vn, ve)
    east: float | None = None
    down: float | None = None  #: vertical position, else fly vd
    vn: float = 0.0
    ve: float = 0.0
    vd: float = 0.0

    @property
    def has_horizontal_position(self) -> bool:
        return self.north is not None and self.east is not None


HOLD_STILL = Target()  #: zero velocity everywhere: stop and stay


class Body:
    """A multicopter as a point mass with a heading."""

    def __init__(self, limits: Limits) -> None:
        self.limits = limits
        self.north = self.east = self.down = 0.0
        self.vn = self.ve = self.vd = 0.0
        self.an = self.ae = 0.0  #: last horizontal acceleration (for the attitude)
        self.yaw = 0.0  #: rad, 0 north, clockwise

    @property
    def height(self) -> float:
        return -self.down

    @property
    def on_ground(self) -> bool:
        return self.down >= -0.01 and self.vd >= 0.0

    @property
    def ground_speed(self) -> float:
        return math.hypot(self.vn, self.ve)

    def distance_to(self, north: float, east: float, down: float) -> float:
        return math.dist((self.north, self.east, self.down), (north, east, down))

    def step(self, target: Target | None, dt: float) -> None:
        """Advance ``dt`` seconds flying ``target`` (None: motors off, the body stays or drops)."""
        steps = max(1, math.ceil(dt / SUBSTEP_S - 1e-9))
        for _ in range(steps):
            self._substep(target, dt / steps)

    def stop(self) -> None:
        self.vn = self.ve = self.vd = self.an = self.ae = 0.0

    # -------------------------------------------------------------- internals
    def _substep(self, target: Target | None, dt: float) -> None:
        lim = self.limits
        if target is None:  # unpowered: on the ground nothing moves; in the air it falls
            wn, we, wd = 0.0, 0.0, (0.0 if self.on_ground else lim.descent_rate * 4)
        else:
            wn, we = self._wanted_horizontal(target)
            wd = self._wanted_vertical(target)
        dvn, dve = wn - self.vn, we - self.ve
        dv = math.hypot(dvn, dve)
        step = lim.max_accel * dt
        if dv > step:
            dvn, dve = dvn * step / dv, dve * step / dv
        self.an, self.ae = dvn / dt, dve / dt
        self.vn += dvn
        self.ve += dve
        self.vd += max(-step, min(step, wd - self.vd))
        self.north += self.vn * dt
        self.east += self.ve * dt
        self.down += self.vd * dt
        if self.down >= 0.0:  # the ground
            self.down = 0.0
            self.vd = min(self.vd, 0.0)
            if self.vd == 0.0:
                self.vn = self.ve = 0.0

    def _wanted_horizontal(self, t: Target) -> tuple[float, float]:
        lim = self.limits
        if t.north is not None and t.east is not None:
            dn, de = t.north - self.north, t.east - self.east
            dist = math.hypot(dn, de)
            if dist < 1e-6:
                return 0.0, 0.0
            speed = min(lim.max_speed, math.sqrt(2 * lim.max_accel * dist), lim.gain * dist)
            return dn / dist * speed, de / dist * speed
        speed = math.hypot(t.vn, t.ve)
        scale = lim.max_speed / speed if speed > lim.max_speed else 1.0
        return t.vn * scale, t.ve * scale

    def _wanted_vertical(self, t: Target) -> float:
        lim = self.limits
        if t.down is None:
            return max(-lim.climb_rate, min(lim.descent_rate, t.vd))
        dd = t.down - self.down
        limit = lim.descent_rate if dd > 0 else lim.climb_rate
        speed = min(limit, math.sqrt(2 * lim.max_accel * abs(dd)), lim.gain_z * abs(dd))
        return math.copysign(speed, dd)


@dataclass
class Battery:
    """A LiPo pack: drains with the current drawn, charges with a negative current."""

    capacity_mah: float = 5000.0
    cells: int = 4
    remaining: float = 1.0  #: 0..1
    current_a: float = 0.0  #: positive draws, negative charges
    consumed_mah: float = 0.0
    energy_j: float = 0.0

    def step(self, dt: float, current_a: float) -> None:
        self.current_a = current_a
        mah = current_a * dt / 3.6
        self.consumed_mah = max(0.0, self.consumed_mah + mah)
        self.energy_j = max(0.0, self.energy_j + current_a * self.voltage * dt)
        self.remaining = max(0.0, min(1.0, self.remaining - mah / self.capacity_mah))

    @property
    def voltage(self) -> float:
        """Resting voltage from the charge state, minus a little sag under load."""
        return self.cells * (3.5 + 0.7 * self.remaining) - 0.01 * max(0.0, self.current_a)

    @property
    def percent(self) -> int:
        return round(self.remaining * 100)
