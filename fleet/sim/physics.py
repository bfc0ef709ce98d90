"""Point-mass kinematics and a battery, both stepped by the caller with a time step (no clock here).

The local frame is NED in metres with its origin on the ground at the vehicle's home, as a
real autopilot's EKF origin: ``down`` is 0 on the ground and negative in the air.

The position controller is the one a multicopter's is shaped like: the commanded speed
towards a position target is ``min(max_speed, sqrt(2 * accel * distance), gain * distance)``
(cruise, then a braking curve, then a gentle final approach), and the velocity moves towards
it at most ``max_accel`` per second. Horizontal speed therefore never exceeds ``max_speed``.

With a jerk limit (ArduCopter's PSC_JERK_XY) the horizontal target is shaped as ArduCopter
shapes it (AP_Math/control.cpp ``shape_pos_vel_accel_xy``: square-root controllers on the
position and velocity errors, the acceleration jerk-limited), and the body trails the shaped
target by :data:`BODY_LAG_S`. Against a real ArduCopter SITL at its defaults: a 1 m step from
rest crosses 0.5 m after 1.28 s there, 1.24 s here (0.87 s without the shaping); each metre of
a staircase of one a second is crossed 1.24-1.30 s after it is set there, 1.22-1.30 s here.
Its vertical target is shaped the same way (PSC_JERK_Z, at WPNAV_ACCEL_Z both ways): 1 m up from a
hover is half climbed after 1.18 s there, 1.22 s here (0.72 s unshaped at 2.5 m/s²).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Integration step (s of simulated time); a longer step is split into these.
SUBSTEP_S = 0.02
#: How far the body trails its shaped target (its attitude and thrust responses): fits a real SITL.
BODY_LAG_S = 0.1


@dataclass(frozen=True)
class Limits:
    """Motion limits; the defaults are ArduCopter's (WPNAV_SPEED 10 m/s, WPNAV_ACCEL 2.5 m/s², ...).

    A vehicle flies its parameters' (:mod:`fleet.sim.params`), which a ground station may change."""

    max_speed: float = 10.0  #: horizontal, m/s
    max_accel: float = 2.5  #: m/s², horizontal (an unpowered fall too)
    max_accel_up: float = 1.0  #: m/s², vertical, upwards (ArduCopter's WPNAV_ACCEL_Z)
    max_accel_down: float = 1.0  #: m/s², vertical, downwards
    climb_rate: float = 2.5  #: m/s
    descent_rate: float = 1.5  #: m/s
    land_speed: float = 0.5  #: m/s, the final descent of a landing
    land_speed_high_alt: float = 10.0  #: m, above this a landing descends at descent_rate
    gain: float = 1.0  #: 1/s, position error to speed near a target (ArduCopter's jerk / (2 accel), PX4's MPC_XY_P)
    gain_z: float = 1.5  #: 1/s, the same vertically
    jerk: float = math.inf  #: m/s³, horizontal: finite, the target is shaped as ArduCopter's (PSC_JERK_XY)
    jerk_z: float = math.inf  #: m/s³, vertical: the same (PSC_JERK_Z), at max_accel_up both ways (WPNAV_ACCEL_Z)


@dataclass(frozen=True)
class Target:
    """What the controller flies to: a position on each axis group given, else a velocity; given both,
    the velocity is fed forward (the position controller adds it to what it flies to close in)."""

    north: float | None = None  #: horizontal position (with east), else fly (vn, ve)
    east: float | None = None
    down: float | None = None  #: vertical position, else fly vd
    vn: float = 0.0
    ve: float = 0.0
    vd: float = 0.0
    an: float = 0.0  #: horizontal acceleration fed forward with a position and a velocity (m/s²)
    ae: float = 0.0

    @property
    def has_horizontal_position(self) -> bool:
        return self.north is not None and self.east is not None

    @property
    def moving(self) -> bool:
        """Whether a velocity is given (flown, or fed forward)."""
        return (self.vn, self.ve, self.vd, self.an, self.ae) != (0.0, 0.0, 0.0, 0.0, 0.0)


HOLD_STILL = Target()  #: zero velocity everywhere: stop and stay


class Body:
    """A multicopter as a point mass with a heading."""

    def __init__(self, limits: Limits) -> None:
        self.limits = limits
        self.north = self.east = self.down = 0.0
        self.vn = self.ve = self.vd = 0.0
        self.an = self.ae = 0.0  #: last horizontal acceleration (for the attitude)
        self.yaw = 0.0  #: rad, 0 north, clockwise
        self.shaped = Shaped()  #: the shaped horizontal target, with a jerk limit
        self.shaped_z = Shaped()  #: the shaped vertical target (its ``north`` is down)

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
        self.shaped.reset(self.north, self.east, 0.0, 0.0)
        self.shaped_z.reset(self.down, 0.0, 0.0, 0.0)

    # -------------------------------------------------------------- internals
    def _substep(self, target: Target | None, dt: float) -> None:
        lim = self.limits
        if target is None:  # unpowered: on the ground nothing moves; in the air it falls
            wn, we, wd = 0.0, 0.0, (0.0 if self.on_ground else lim.descent_rate * 4)
        else:
            wn, we = self._wanted_horizontal(target)
            wd = self._wanted_vertical(target)
        shaped = target if target is not None and not self.on_ground else None
        if shaped is not None and math.isfinite(lim.jerk):
            self._trail_shaped(shaped, dt)
        else:
            self._accelerate(wn, we, dt)
            self.shaped.reset(self.north, self.east, self.vn, self.ve)
        if shaped is not None and math.isfinite(lim.jerk_z):
            self._trail_shaped_z(shaped, dt)
        else:
            up, down = (lim.max_accel_up, lim.max_accel_down) if target is not None else (lim.max_accel,) * 2
            self.vd += max(-up * dt, min(down * dt, wd - self.vd))
            self.down += self.vd * dt
            self.shaped_z.reset(self.down, 0.0, self.vd, 0.0)
        if self.down >= 0.0:  # the ground
            self.down = 0.0
            self.vd = min(self.vd, 0.0)
            if self.vd == 0.0:
                self.vn = self.ve = 0.0

    def _accelerate(self, wn: float, we: float, dt: float) -> None:
        """Towards the wanted horizontal velocity ``(wn, we)``, at most ``max_accel``."""
        an, ae = _clipped((wn - self.vn) / dt, (we - self.ve) / dt, self.limits.max_accel)
        self.an, self.ae = an, ae
        self.vn += an * dt
        self.ve += ae * dt
        self.north += self.vn * dt
        self.east += self.ve * dt

    def _trail_shaped(self, target: Target, dt: float) -> None:
        """Shape the horizontal target as ArduCopter does, and trail it by BODY_LAG_S."""
        lim = self.limits
        position = (target.north, target.east) if target.north is not None and target.east is not None else None
        self.shaped.chase(position, (target.vn, target.ve), (target.an, target.ae), lim.max_speed,
                          lim.max_accel, lim.jerk, dt)
        pull = min(1.0, dt / BODY_LAG_S)
        north = self.north + (self.shaped.north - self.north) * pull
        east = self.east + (self.shaped.east - self.east) * pull
        vn, ve = (north - self.north) / dt, (east - self.east) / dt
        self.an, self.ae = (vn - self.vn) / dt, (ve - self.ve) / dt
        self.north, self.east, self.vn, self.ve = north, east, vn, ve

    def _trail_shaped_z(self, target: Target, dt: float) -> None:
        """The same vertically: climbing at most ``climb_rate``, descending at most ``descent_rate``."""
        lim, shaped = self.limits, self.shaped_z
        heading_down = (target.down - shaped.north if target.down is not None else target.vd) > 0
        position = None if target.down is None else (target.down, 0.0)
        shaped.chase(position, (target.vd, 0.0), (0.0, 0.0), lim.descent_rate if heading_down else lim.climb_rate,
                     lim.max_accel_up, lim.jerk_z, dt)
        down = self.down + (shaped.north - self.down) * min(1.0, dt / BODY_LAG_S)
        self.vd, self.down = (down - self.down) / dt, down

    def _wanted_horizontal(self, t: Target) -> tuple[float, float]:
        lim = self.limits
        if t.north is not None and t.east is not None:
            dn, de = t.north - self.north, t.east - self.east
            dist = math.hypot(dn, de)
            if dist >= 1e-6:
                speed = min(lim.max_speed, math.sqrt(2 * lim.max_accel * dist), lim.gain * dist)
                return _clipped(dn / dist * speed + t.vn, de / dist * speed + t.ve, lim.max_speed)
        return _clipped(t.vn, t.ve, lim.max_speed)

    def _wanted_vertical(self, t: Target) -> float:
        lim = self.limits
        if t.down is None:
            return max(-lim.climb_rate, min(lim.descent_rate, t.vd))
        dd = t.down - self.down
        limit, brake = (lim.descent_rate, lim.max_accel_up) if dd > 0 else (lim.climb_rate, lim.max_accel_down)
        speed = math.copysign(min(limit, math.sqrt(2 * brake * abs(dd)), lim.gain_z * abs(dd)), dd)
        return max(-lim.climb_rate, min(lim.descent_rate, speed + t.vd))


@dataclass
class Shaped:
    """A shaped target on two axes: where it is, how fast it moves and accelerates."""

    north: float = 0.0
    east: float = 0.0
    vn: float = 0.0
    ve: float = 0.0
    an: float = 0.0
    ae: float = 0.0

    def reset(self, north: float, east: float, vn: float, ve: float) -> None:
        """At the body, as it moves (on the ground, or flown without shaping)."""
        self.north, self.east, self.vn, self.ve, self.an, self.ae = north, east, vn, ve, 0.0, 0.0

    def chase(self, position: tuple[float, float] | None, velocity: tuple[float, float],
              accel_ahead: tuple[float, float], speed: float, accel: float, jerk: float, dt: float) -> None:
        """Towards ``position`` (None: fly ``velocity``; given both, the velocity is fed forward, as is
        ``accel_ahead``), as ArduCopter shapes it (``shape_pos_vel_accel_xy``), then ``dt`` on."""
        if position is not None:
            error = (position[0] - self.north, position[1] - self.east)
            wanted = _clipped(*_sqrt_controller(error, 0.5 * jerk / accel, 0.5 * accel, dt), speed)
            wanted = (wanted[0] + velocity[0], wanted[1] + velocity[1])
        else:
            wanted = _clipped(*velocity, speed)
        error_v = (wanted[0] - self.vn, wanted[1] - self.ve)
        push = _clipped(*_sqrt_controller(error_v, jerk / accel, jerk, dt), accel)
        self.step((push[0] + accel_ahead[0], push[1] + accel_ahead[1]), jerk, dt)

    def step(self, accel: tuple[float, float], jerk: float, dt: float) -> None:
        """Towards ``accel`` at most ``jerk`` per second, then ``dt`` on."""
        dan, dae = _clipped(accel[0] - self.an, accel[1] - self.ae, jerk * dt)
        self.an, self.ae = self.an + dan, self.ae + dae
        self.north += self.vn * dt + self.an * dt * dt / 2
        self.east += self.ve * dt + self.ae * dt * dt / 2
        self.vn += self.an * dt
        self.ve += self.ae * dt


def _sqrt_controller(error: tuple[float, float], p: float, limit: float, dt: float) -> tuple[float, float]:
    """ArduPilot's sqrt_controller on a vector: linear near zero, sqrt(2 limit x) beyond, never past the
    error in one step."""
    length = math.hypot(*error)
    if length <= 0.0:
        return 0.0, 0.0
    linear = limit / (p * p)
    rate = math.sqrt(2 * limit * (length - linear / 2)) if length > linear else length * p
    rate = min(rate, length / dt)
    return error[0] * rate / length, error[1] * rate / length


def _clipped(x: float, y: float, most: float) -> tuple[float, float]:
    """``(x, y)`` shortened to length ``most`` if longer."""
    length = math.hypot(x, y)
    return (x, y) if length <= most else (x * most / length, y * most / length)


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
