"""What the rest of the fleet needs from a vehicle link, as typing protocols.

The backends (pymavlink, MAVSDK) implement :class:`VehicleLink`; the setpoint
loop only needs the smaller :class:`SetpointSink`, so it can be driven and
tested without an autopilot. :class:`Telemetry` is what every backend reports,
in the same units, whatever the autopilot.
"""

from __future__ import annotations

import asyncio
import collections
import enum
import itertools
import logging
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

from drona_gcs.errors import VehicleError
from drona_gcs.geo import GeoPoint, Ned

log = logging.getLogger(__name__)

REOPEN_S = 1.0  #: how often a backend opens a lost TCP or serial link again


class StreamRequests:
    """A backend's telemetry streams asked for again, at each HEARTBEAT once :attr:`wanted` (after a
    silence or a stream opened again: a rebooted autopilot forgot them), until every request is
    acknowledged. ``ask`` makes the requests (VehicleError if one fails); ``name`` is for the log."""

    def __init__(self, ask: Callable[[], Awaitable[None]], name: str) -> None:
        self.ask, self.name = ask, name
        self.wanted = False
        self._asking: asyncio.Task[None] | None = None  #: the requests under way

    def on_heartbeat(self, after_silence: bool, tasks: list[asyncio.Task[None]]) -> None:
        """At a HEARTBEAT (on the loop): ask if wanted and not already asking; the task joins ``tasks``
        (the backend's, cancelled when it closes)."""
        self.wanted = self.wanted or after_silence
        if self.wanted and (self._asking is None or self._asking.done()):
            self._asking = asyncio.get_running_loop().create_task(self._again())
            tasks[:] = [*(task for task in tasks if not task.done()), self._asking]

    async def _again(self) -> None:
        try:
            await self.ask()
        except VehicleError as exc:  # asked again at the next HEARTBEAT
            log.info("%s: telemetry streams not acknowledged yet: %s", self.name, exc)
        else:
            self.wanted = False


class Share(float, enum.Enum):
    """Telemetry rates, as fractions of a link's ``stream_hz``. Positions come at the full rate (the
    setpoint loop and the record read them at every step boundary); the landed state at half (a
    take-off or a landing waits on it); battery and system status at a quarter (the battery monitor
    reads once a step, and a cell's worth of flight barely moves them); the GPS fix at a fifth.
    Every message asked for costs the ground station and the radio link, fleet-wide; one not read is
    asked OFF (an autopilot may stream it by default, as PX4 does LOCAL_POSITION_NED)."""

    POSITION = 1.0
    LANDED = 0.5
    STATUS = 0.25
    GPS = 0.2
    OFF = 0.0

    def interval_us(self, stream_hz: float) -> float:
        """MAV_CMD_SET_MESSAGE_INTERVAL's param2 at ``stream_hz``: -1 stops the stream."""
        return -1.0 if self is Share.OFF else 1e6 / (stream_hz * self.value)


@dataclass(frozen=True)
class Position:
    """The latest position the vehicle reported, with the link's clock time of the report."""

    ned: Ned
    at: float


TRAIL_SIZE = 256  #: positions a link keeps: seconds of them at any stream rate a link asks for


class Trail:
    """The last positions a link received, oldest first: where the vehicle went between two looks."""

    def __init__(self, size: int = TRAIL_SIZE) -> None:
        self._positions: collections.deque[Position] = collections.deque(maxlen=size)

    def add(self, position: Position | None) -> None:
        if position is not None and (not self._positions or self._positions[-1] != position):
            self._positions.append(position)

    def since(self, at: float) -> list[Position]:
        """The positions reported after link time ``at``."""
        newer = itertools.takewhile(lambda p: p.at > at, reversed(self._positions))
        return list(newer)[::-1]  # from the newest back: a look wants the few since the last

    def clear(self) -> None:
        self._positions.clear()


class Autopilot(enum.Enum):
    ARDUPILOT = "ardupilot"  #: MAV_AUTOPILOT_ARDUPILOTMEGA
    PX4 = "px4"  #: MAV_AUTOPILOT_PX4
    OTHER = "other"  #: anything else: no mode names known


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE, from EXTENDED_SYS_STATE."""

    UNDEFINED = 0  #: not reported (yet)
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


@dataclass(frozen=True)
class Telemetry:
    """A snapshot of what the vehicle last reported (None: not reported yet)."""

    autopilot: Autopilot | None
    armed: bool
    mode: str | None  #: the autopilot's mode name ("GUIDED", "OFFBOARD"), or "custom_mode=<n>" when unknown
    position: Position | None  #: in the link's frame (see the backend)
    velocity: Ned | None  #: m/s
    global_position: GeoPoint | None
    height_m: float | None  #: above home
    battery_pct: int | None
    battery_v: float | None
    gps_fix: int  #: GPS_FIX_TYPE: 3 is a 3D fix
    satellites: int
    landed: LandedState
    heartbeat_at: float | None  #: link clock time of the last HEARTBEAT
    #: the autopilot's own word on its position estimate (ArduPilot: EKF_STATUS_REPORT); None: it says nothing
    position_ok: bool | None = None
    prearm_ok: bool | None = None  #: SYS_STATUS's pre-arm checks, where reported: the vehicle may arm
    prearm_text: str = ""  #: the autopilot's last "PreArm: ..." text, which says what fails


GPS_3D_FIX = 3  #: GPS_FIX_TYPE_3D_FIX


def not_ready(t: Telemetry) -> str | None:
    """What keeps a vehicle from being ready to fly plans, first thing first (None: ready). The
    battery level too: the battery monitor keeps the drone above its safe threshold with it."""
    return next((text for _, text in _problems(t)), None)


def _problems(t: Telemetry) -> list[tuple[bool, str]]:
    """(a position problem, what it is) for everything that keeps the vehicle from flying plans."""
    prearm = "pre-arm checks failing" + (f" ({t.prearm_text})" if t.prearm_text else "")
    found = [(False, "no HEARTBEAT") if t.heartbeat_at is None else None,
             (True, "no position estimate (the autopilot says so)") if t.position_ok is False else None,
             (True, "no position") if t.position is None else None,
             (True, "no global position") if t.global_position is None else None,
             (True, f"GPS fix type {t.gps_fix}, need a 3D fix") if t.gps_fix < GPS_3D_FIX else None,
             (False, "no battery level (BATTERY_STATUS or SYS_STATUS)") if t.battery_pct is None else None,
             (False, prearm) if t.prearm_ok is False else None]
    return [problem for problem in found if problem is not None]


class Readiness(enum.Enum):
    """Whether a vehicle can fly plans, as its drone's state reports it."""

    READY = "ready"  #: position, GPS, battery and pre-arm checks good
    WAITING_FOR_POSITION = "waiting_for_position"  #: no position estimate or GPS fix yet
    NOT_READY = "not_ready"  #: something else (:func:`not_ready` says what)
    LOST = "lost"  #: no HEARTBEAT lately: the link is gone or the vehicle silent


def readiness(t: Telemetry, lost: bool = False) -> Readiness:
    """What keeps the vehicle from flying plans, in one word. Waiting for its position is told apart:
    ArduCopter SITL takes about 45 s from boot to its first estimate."""
    problems = _problems(t)
    if lost or t.heartbeat_at is None:
        return Readiness.LOST
    if not problems:
        return Readiness.READY
    return Readiness.WAITING_FOR_POSITION if problems[0][0] else Readiness.NOT_READY


STILL = Ned(0.0, 0.0, 0.0)
#: SET_POSITION_TARGET_* type_mask: x, y, z only (velocity, acceleration, yaw and yaw rate ignored)
POSITION_ONLY = 0b110111111000
#: x, y, z and the velocity to feed forward: between two messages the autopilot carries the target on at
#: it. Not its acceleration: fed forward on top of the autopilot's own, it overshoots where a sweep turns.
POSITION_VELOCITY = 0b110111000000


@dataclass(frozen=True)
class Motion:
    """A streamed target: where it is and how fast it moves (None: a still point, sent as a position only)."""

    where: Ned
    velocity: Ned | None = None


@dataclass(frozen=True)
class Sweep:
    """A target that moves: from where it was sent, at ``velocity`` (m/s, NED) changing at ``accel``
    (m/s²) for ``duration_s``; then still. The autopilot gets the velocity as feed-forward with each
    position along the way, as a trajectory is streamed to it: aimed at a point that moves, it keeps
    up, where aimed at a point that waits, it slows down to stop there."""

    velocity: Ned
    duration_s: float
    accel: Ned = STILL

    def at(self, start: Ned, elapsed: float) -> Motion:
        """The target ``elapsed`` s after it was sent from ``start``."""
        t, v, a = min(max(elapsed, 0.0), self.duration_s), self.velocity, self.accel
        where = Ned(start.north + v.north * t + a.north * t * t / 2, start.east + v.east * t + a.east * t * t / 2,
                    start.down + v.down * t + a.down * t * t / 2)
        if elapsed >= self.duration_s:
            return Motion(where, STILL)
        return Motion(where, Ned(v.north + a.north * t, v.east + a.east * t, v.down + a.down * t))


@dataclass(frozen=True)
class Aim:
    """The target a link streams: ``start``, or a sweep from it, as sent at link time ``sent_at``."""

    start: Ned
    sweep: Sweep | None
    sent_at: float

    def at(self, now: float) -> Motion:
        return Motion(self.start) if self.sweep is None else self.sweep.at(self.start, now - self.sent_at)


class SetpointSink(Protocol):
    """Where the setpoint loop sends targets and reads positions."""

    async def send_position_target(self, target: Ned, sweep: Sweep | None = None) -> None:
        """Fly to ``target``, or along ``sweep`` from it. The sink keeps streaming the target to the
        vehicle (PX4 leaves OFFBOARD without a stream; a sweep moves on with each message): the
        setpoint loop sends one only when the target changes."""
        ...

    def last_position(self) -> Position | None: ...

    def positions_since(self, at: float) -> list[Position]:
        """The positions reported after link time ``at``, oldest first (the last few hundred)."""
        ...


class VehicleLink(SetpointSink, Protocol):
    """The whole link: connection, readiness, commands and telemetry."""

    clock: Callable[[], float]  #: what :attr:`Position.at` and the other telemetry times are read on

    async def connect(self, timeout: float = ...) -> None: ...

    async def wait_ready(self, timeout: float) -> None: ...

    async def arm(self) -> None: ...

    async def disarm(self) -> None: ...

    async def set_mode(self, mode: str) -> None: ...

    async def follow_setpoints(self) -> None:
        """Enter the mode that follows setpoints (GUIDED, OFFBOARD), streaming one first where needed."""

    async def takeoff(self, altitude_m: float) -> None: ...

    async def land(self) -> None: ...

    async def close(self) -> None: ...

    async def read_parameters(self, names: Sequence[str]) -> dict[str, float]:
        """Each parameter of ``names`` the vehicle answers PARAM_REQUEST_READ for, with its value."""

    async def set_parameter(self, name: str, value: float) -> float | None:
        """PARAM_SET ``name`` to ``value``: what the vehicle answers it now holds (None: no answer)."""

    def parameters_heard(self) -> Mapping[str, float]:
        """The last value the vehicle sent of each parameter (PARAM_VALUE): read by us, or set by any
        ground station (the autopilot tells every one)."""

    def last_global(self) -> GeoPoint | None: ...

    def telemetry(self) -> Telemetry: ...

    def problem(self) -> str | None:
        """Why the link cannot carry commands now: closed, lost, or the vehicle silent (None: it can)."""

    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float,
                         what: str) -> Telemetry:
        """The first snapshot for which ``predicate`` holds; VehicleError naming ``what`` after ``timeout``."""
