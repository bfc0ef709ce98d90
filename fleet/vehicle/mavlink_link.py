"""The pymavlink backend of :class:`~fleet.vehicle.link.VehicleLink`: asyncio transports, pymavlink as a codec.

pymavlink only encodes (``MAVLink(None, srcSystem=...)``) and decodes (``parse_buffer``); the
bytes move on asyncio transports (UDP, TCP, serial via pyserial-asyncio). Every incoming message
goes through one table, :attr:`PymavlinkLink._handlers`; the types we ignore are listed there too.

Commands never set-and-poll. Each one registers a future that the COMMAND_ACK handler resolves,
waits for it with a timeout (resending a lost command with ``confirmation`` + 1), raises
:class:`~drona_gcs.errors.VehicleCommandRejected` with the STATUSTEXT that explains a refusal
(ArduCopter sends it right after the ACK, so a refusal waits ``text_grace`` seconds for it), and
confirms from the next HEARTBEAT what an autopilot may ACK without doing: ArduCopter ACKs a mode
change before its position estimate yet stays in STABILIZE. A vehicle silent for
``heartbeat_timeout`` seconds fails every pending wait with a VehicleError.

A TCP or serial stream that is lost (SITL restarted, a USB adapter pulled out, a flight
controller on USB rebooted) fails every command at once, and is opened again every
:data:`REOPEN_S` seconds until it comes back, by its name (a ``/dev/serial/by-id/...`` link finds
the adapter wherever it comes back). UDP and a UART that stays connected lose nothing to reopen:
the vehicle only goes silent. Either way, at the first HEARTBEAT after the stream came back or
the silence ended, the telemetry streams are asked for again (a rebooted autopilot forgot them),
at each HEARTBEAT until the requests are acknowledged.

Positions: without ``frame`` they are in the autopilot's local NED frame (origin at its EKF origin,
usually home). With a :class:`~drona_gcs.geo.GeoFrame` they are in that workspace's frame: targets go
out as SET_POSITION_TARGET_GLOBAL_INT and positions come from GLOBAL_POSITION_INT, so vehicles
with different homes share one frame. No ArduPilot parameter is read or written.

Whom it listens to: the first HEARTBEAT of an autopilot component (MAV_COMP_ID_AUTOPILOT1, not of
MAV_TYPE_GCS, naming an autopilot) fixes the vehicle's system id (``target_system``, if given, must
match), and only messages from that system's autopilot component count. Over udpin the link
answers the address that HEARTBEAT came from and hears no other while the vehicle is alive (see
:mod:`fleet.vehicle.urls`). With ``signing_key`` (MAVLink 2 signing, :mod:`fleet.vehicle.signing`)
everything sent is signed and only messages signed with the key are heard. Bytes are framed by
:class:`~fleet.vehicle.frames.Deframer`: noise and truncated frames cost their own bytes, never
the real frames behind them, and never raise.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import math
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from drona_gcs.errors import VehicleCommandRejected, VehicleError
from drona_gcs.geo import GeoFrame, GeoPoint, Ned
from fleet.clock import cancel_all, periodic
from fleet.vehicle.frames import Deframer
from fleet.vehicle.link import REOPEN_S, Autopilot, LandedState, Position, Share, StreamRequests, Telemetry, not_ready
from fleet.vehicle.modes import CONFIRM_HEARTBEATS, FOLLOW_MODE, LAND_MODE, ModeDoubt, mode_command, mode_name
from fleet.vehicle.policy import DEFAULT_TIMEOUTS, Timeouts, ekf_has_position, may_stream_setpoints, takeoff_started
from fleet.vehicle.signing import accept_signed_only, sign_outgoing, stamp_now
from fleet.vehicle.urls import LinkUrl, Scheme, Transport, open_transport, parse_link_url

log = logging.getLogger(__name__)

Message = Any  # pymavlink's MAVLink_message: untyped
#: Streams requested with MAV_CMD_SET_MESSAGE_INTERVAL: message id -> rate as a fraction of ``stream_hz``.
STREAMS = {mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: Share.POSITION,
           mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: Share.POSITION,
           mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: Share.STATUS, mavlink2.MAVLINK_MSG_ID_SYS_STATUS: Share.STATUS,
           mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: Share.LANDED, mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: Share.GPS}
#: With a workspace frame, positions and velocities come from GLOBAL_POSITION_INT alone: the local
#: position is asked for at the status rate only (a GCS sharing the vehicle may still want it). At
#: the position rate it was a third of the messages a vehicle sent, each decoded in pure Python.
FRAMED_STREAMS = {**STREAMS, mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: Share.STATUS}
#: ArduPilot's own word on its position estimate (see fleet.vehicle.policy); PX4 does not know the message.
ARDUPILOT_STREAMS = {mavlink2.MAVLINK_MSG_ID_EKF_STATUS_REPORT: Share.STATUS}
POSITION_ONLY = 0b110111111000  #: type_mask: use x, y, z; ignore velocity, acceleration, yaw and yaw rate
GCS_COMPONENT = mavlink2.MAV_COMP_ID_MISSIONPLANNER
_UNKNOWN_U16 = 0xFFFF
SETPOINT_SENT = "(setpoint sent)"  #: a pseudo message type: waiters on it are resolved as setpoints go out
_SERIOUS = mavlink2.MAV_SEVERITY_WARNING  #: texts at this severity or worse explain a refusal
REOPEN_TIMEOUT_S = 5.0  #: how long one attempt may take (a TCP connect to a host that does not answer)


def _command_name(command: int) -> str:
    entry = mavlink2.enums["MAV_CMD"].get(command)
    return entry.name.removeprefix("MAV_CMD_") if entry is not None else f"command {command}"


# ------------------------------------------------------------------ the link
class PymavlinkLink:
    """One vehicle over one MAVLink connection; see the module docstring."""

    def __init__(self, url: str | LinkUrl, *, target_system: int | None = None, source_system: int = 255,
                 frame: GeoFrame | None = None, heartbeat_timeout: float = 3.0, ack_timeout: float = 1.0,
                 retries: int = 2, text_grace: float = 0.3, stream_hz: float = 10.0, setpoint_hz: float = 20.0,
                 timeouts: Timeouts = DEFAULT_TIMEOUTS, clock: Callable[[], float] = time.monotonic,
                 signing_key: bytes | None = None) -> None:
        self.url = parse_link_url(url) if isinstance(url, str) else url
        self.frame, self.clock = frame, clock
        self.heartbeat_timeout, self.ack_timeout, self.retries = heartbeat_timeout, ack_timeout, retries
        self.text_grace, self.stream_hz, self.setpoint_hz = text_grace, stream_hz, setpoint_hz
        self.timeouts = timeouts
        self.sysid, self.compid = target_system, mavlink2.MAV_COMP_ID_AUTOPILOT1
        self._locked = False  #: sysid is the vehicle's, from its first HEARTBEAT
        self.signing_key = signing_key
        self._enc = mavlink2.MAVLink(None, srcSystem=source_system, srcComponent=GCS_COMPONENT)
        if signing_key is not None:
            sign_outgoing(self._enc, signing_key)
        self._frames = self._deframer()
        self._transport: Transport | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._waiters: dict[asyncio.Future[Message], tuple[str | None, Callable[[Message], bool]]] = {}
        self._dead: VehicleError | None = None  #: closed, or the stream is gone (until it is opened again)
        self._lost_at: float | None = None  #: when the stream was lost (None: not lost, or closed by us)
        self._tried_at = -math.inf  #: the last attempt to open a lost stream again
        self._closed = False  #: closed by us: a stream lost now is not opened again
        self._streams = StreamRequests(self._ask_for_streams, str(self.url))
        self._silent: VehicleError | None = None  #: no heartbeat lately: cleared by the next one
        self._started = clock()
        self._setpoint: Message | None = None  #: repeated at setpoint_hz (PX4 leaves OFFBOARD without it)
        self._setpoints_sent = 0
        self.autopilot: Autopilot | None = None
        self.custom_mode: int | None = None
        self.armed = False
        self._mode_doubt = ModeDoubt()
        self.heartbeats = 0
        self.heartbeat_at: float | None = None
        self._ack_heartbeats: dict[int, int] = {}  #: command -> heartbeats seen when its ACK came
        self._latest: dict[str, tuple[float, Message]] = {}  #: telemetry: type -> (clock time, last message)
        #: telemetry() as of the last message: read several times per drone at every step boundary
        self._snapshot: Telemetry | None = None
        self.texts: collections.deque[tuple[float, int, str]] = collections.deque(maxlen=32)
        self.unhandled: collections.Counter[str] = collections.Counter()
        self._handlers: dict[str, Callable[[Message], None]] = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_ACK": self._on_command_ack,
            "STATUSTEXT": self._on_statustext,
            **dict.fromkeys(("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "SYS_STATUS", "BATTERY_STATUS",
                             "GPS_RAW_INT", "EXTENDED_SYS_STATE", "EKF_STATUS_REPORT"), self._keep),  # telemetry()
            # Ignored on purpose:
            **dict.fromkeys(("ATTITUDE", "ATTITUDE_QUATERNION", "HOME_POSITION", "TIMESYNC", "SYSTEM_TIME",
                             "AUTOPILOT_VERSION", "PARAM_VALUE", "RADIO_STATUS", "VFR_HUD",
                             "ESTIMATOR_STATUS", "VIBRATION", "POWER_STATUS", "MEMINFO", "MISSION_CURRENT",
                             "NAV_CONTROLLER_OUTPUT", "POSITION_TARGET_LOCAL_NED", "POSITION_TARGET_GLOBAL_INT",
                             "ALTITUDE", "UTM_GLOBAL_POSITION"), _ignore),
        }

    # ------------------------------------------------------------ connection
    async def connect(self, timeout: float = 10.0) -> None:
        """Open the link, wait for an autopilot's HEARTBEAT and ask for the telemetry streams."""
        self._transport = await self._open()
        self._tasks = [asyncio.create_task(self._housekeeping()), asyncio.create_task(self._stream_setpoint())]
        self._send_heartbeat()
        try:
            await self._await_or_fail(self._expect("HEARTBEAT", _any), timeout, "a HEARTBEAT from a vehicle")
            await self._ask_for_streams()
        except BaseException:
            await self.close()
            raise

    async def _ask_for_streams(self) -> None:
        """The telemetry at our rates (every stream's request acknowledged, or VehicleError)."""
        for msg_id, share in self.streams.items():
            await self.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / (self.stream_hz * share))

    async def close(self) -> None:
        self._closed, self._lost_at = True, None
        await cancel_all(self._tasks)
        if self._transport is not None:
            self._transport.close()
        self._fail(VehicleError(f"{self.url}: link closed"), final=True)

    async def wait_ready(self, timeout: float) -> None:
        """:func:`~fleet.vehicle.link.not_ready`, and a healthy GPS; VehicleError after ``timeout``."""
        if self._not_ready() is not None:
            await self._await_or_fail(self._expect(None, lambda m: self._not_ready() is None), timeout,
                                      "readiness", lambda: f" ({self._not_ready()})")

    def _not_ready(self) -> str | None:
        status, gps = self._msg("SYS_STATUS"), mavlink2.MAV_SYS_STATUS_SENSOR_GPS
        gps_sick = status is not None and status.onboard_control_sensors_present \
            & status.onboard_control_sensors_enabled & ~status.onboard_control_sensors_health & gps
        return not_ready(self.telemetry()) or ("SYS_STATUS reports the GPS unhealthy" if gps_sick else None)

    # ------------------------------------------------------------ commands
    async def command(self, command: int, *params: float, name: str = "") -> int:
        """COMMAND_LONG, acknowledged: returns the heartbeat count at the ACK; raises VehicleCommandRejected."""
        label = name or _command_name(command)
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        since, me = self.clock(), self._enc.srcSystem
        for confirmation in range(self.retries + 1):
            self._check_alive()
            ack = self._expect("COMMAND_ACK", lambda m: m.command == command and m.target_system in (0, me)
                               and m.result != mavlink2.MAV_RESULT_IN_PROGRESS)
            self._send(self._enc.command_long_encode(self.sysid or 0, self.compid, command, confirmation, *p))
            try:
                msg = await self._await(ack, self.ack_timeout)
            except TimeoutError:
                continue
            if msg.result != mavlink2.MAV_RESULT_ACCEPTED:
                raise VehicleCommandRejected(label, int(msg.result), await self._reason_since(since))
            return self._ack_heartbeats.get(command, self.heartbeats)
        raise VehicleError(f"{label}: no COMMAND_ACK from vehicle {self.sysid} after {self.retries + 1} tries "
                           f"of {self.ack_timeout} s")

    async def arm(self) -> None:
        await self._confirmed(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "ARM", lambda: self.armed,
                              lambda: "is still disarmed")

    async def disarm(self) -> None:
        await self._confirmed(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (0.0,), "DISARM", lambda: not self.armed,
                              lambda: "is still armed")

    async def set_mode(self, mode: str) -> None:
        """Switch to ``mode`` (ArduCopter or PX4 name) and confirm it from the next HEARTBEAT."""
        custom, params = mode_command(self.autopilot, mode, f"vehicle {self.sysid}")
        flag = float(mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        await self._mode_doubt.around(self._confirmed(
            mavlink2.MAV_CMD_DO_SET_MODE, (flag, *params), f"DO_SET_MODE {mode}",
            lambda: self.custom_mode == custom, lambda: f"stayed in {self.mode}"))

    async def follow_setpoints(self) -> None:
        """GUIDED on ArduPilot; on PX4 stream the current position as the setpoint, then OFFBOARD."""
        mode = FOLLOW_MODE.get(self.autopilot or Autopilot.OTHER)
        if mode is None or (self.mode == mode and not self._mode_doubt.in_doubt):
            return
        if self.autopilot is Autopilot.PX4 and self._setpoint is None:
            here = self.last_position()
            if here is None:
                raise VehicleError(f"vehicle {self.sysid}: no position to hold while entering OFFBOARD")
            await self.send_position_target(here.ned)
        if self.autopilot is Autopilot.PX4:  # PX4 refuses OFFBOARD until setpoints arrive: stream a few first
            sent = self._setpoints_sent
            await self._await_or_fail(self._expect(SETPOINT_SENT, lambda m: self._setpoints_sent >= sent + 3),
                                      10 / self.setpoint_hz, "the setpoint stream")
        await self.set_mode(mode)

    async def takeoff(self, altitude_m: float) -> None:
        """Climb to ``altitude_m`` above home (ArduPilot: in GUIDED, switched to first); returns once climbing."""
        if not altitude_m > 0:
            raise ValueError(f"takeoff altitude must be > 0, got {altitude_m}")
        if self.autopilot is Autopilot.ARDUPILOT:
            if self.mode != "GUIDED":
                await self.set_mode("GUIDED")
            await self.command(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m)
        else:  # PX4 wants AMSL; home's altitude is GLOBAL_POSITION_INT's alt - relative_alt
            t = self.telemetry()
            if t.global_position is None or t.height_m is None:
                raise VehicleError(f"vehicle {self.sysid}: no global position, cannot take off")
            amsl = t.global_position.alt_m - t.height_m + altitude_m
            await self.command(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, amsl)
        await self.wait_until(takeoff_started, self.timeouts.takeoff_start_s, "the takeoff to start")

    async def land(self) -> None:
        """Land where it is (stops the setpoint stream); confirmed from the next HEARTBEAT's mode."""
        self._setpoint = None
        mode = LAND_MODE.get(self.autopilot or Autopilot.OTHER)
        await self._mode_doubt.around(self._confirmed(mavlink2.MAV_CMD_NAV_LAND, (), "LAND",
                                                      lambda: mode is None or self.mode == mode,
                                                      lambda: f"stayed in {self.mode}"))

    async def _confirmed(self, command: int, params: tuple[float, ...], label: str,
                         effect: Callable[[], bool], failure: Callable[[], str]) -> None:
        """Send, await the ACK, then want ``effect`` in one of the CONFIRM_HEARTBEATS HEARTBEATs after the ACK."""
        since = self.clock()
        seen = await self.command(command, *params, name=label)
        for n in range(1, CONFIRM_HEARTBEATS + 1):
            if self.heartbeats < seen + n:
                await self._await_or_fail(self._expect("HEARTBEAT", _any), self.heartbeat_timeout,
                                          f"a HEARTBEAT after {label}")
            if effect():
                return
        texts = "; ".join(t for at, sev, t in self.texts if sev <= _SERIOUS and at >= since)
        reason = f"acknowledged, but the vehicle {failure()}" + (f" ({texts})" if texts else "")
        raise VehicleCommandRejected(label, mavlink2.MAV_RESULT_ACCEPTED, reason)

    async def _reason_since(self, since: float) -> str:
        """The serious STATUSTEXT since ``since``, waiting ``text_grace`` for one if none came yet."""
        texts = [t for at, sev, t in self.texts if at >= since and sev <= _SERIOUS]
        if texts:
            return texts[-1]
        with contextlib.suppress(TimeoutError):
            msg = await self._await(self._expect("STATUSTEXT", lambda m: m.severity <= _SERIOUS), self.text_grace)
            return str(msg.text)
        return ""

    # ------------------------------------------------------------ setpoints
    async def send_position_target(self, target: Ned) -> None:
        """Fly to ``target`` (local NED, or the workspace frame's with ``frame``); repeated at ``setpoint_hz``."""
        ms = round((self.clock() - self._started) * 1000) & 0xFFFFFFFF
        if self.frame is None:
            self._setpoint = self._enc.set_position_target_local_ned_encode(
                ms, self.sysid or 0, self.compid, mavlink2.MAV_FRAME_LOCAL_NED, POSITION_ONLY,
                target.north, target.east, target.down, 0, 0, 0, 0, 0, 0, 0, 0)
        else:
            g = self.frame.ned_to_global(target)
            self._setpoint = self._enc.set_position_target_global_int_encode(
                ms, self.sysid or 0, self.compid, mavlink2.MAV_FRAME_GLOBAL_INT, POSITION_ONLY,
                round(g.lat * 1e7), round(g.lon * 1e7), g.alt_m, 0, 0, 0, 0, 0, 0, 0, 0)
        self._check_alive()
        self._send_setpoint()

    def _send_setpoint(self) -> None:
        if self._setpoint is not None and may_stream_setpoints(self.telemetry()):
            self._send(self._setpoint)
            self._setpoints_sent += 1
            self._resolve(SETPOINT_SENT, self._setpoint)

    async def _stream_setpoint(self) -> None:
        async for _ in periodic(1 / self.setpoint_hz):
            if self._dead is None and self._silent is None:
                self._send_setpoint()

    # ------------------------------------------------------------ telemetry
    @property
    def mode(self) -> str | None:
        return mode_name(self.autopilot, self.custom_mode)

    def last_position(self) -> Position | None:
        """LOCAL_POSITION_NED; with ``frame``, GLOBAL_POSITION_INT in the workspace frame."""
        return self.telemetry().position

    def _position(self) -> Position | None:
        kind = "LOCAL_POSITION_NED" if self.frame is None else "GLOBAL_POSITION_INT"
        if (entry := self._latest.get(kind)) is None:
            return None
        at, msg = entry
        if self.frame is None:
            return Position(Ned(msg.x, msg.y, msg.z), at)
        if msg.lat == msg.lon == 0:  # ArduPilot before its first estimate: stale zeros
            return None
        return Position(self.frame.global_to_ned(_geo(msg)), at)

    def last_global(self) -> GeoPoint | None:
        msg = self._msg("GLOBAL_POSITION_INT")
        return None if msg is None or msg.lat == msg.lon == 0 else _geo(msg)

    @property
    def streams(self) -> dict[int, Share]:
        """The telemetry asked for: message id -> rate as a share of ``stream_hz``."""
        common = STREAMS if self.frame is None else FRAMED_STREAMS
        return {**common, **ARDUPILOT_STREAMS} if self.autopilot is Autopilot.ARDUPILOT else common

    def telemetry(self) -> Telemetry:
        if self._snapshot is None:
            self._snapshot = self._read_telemetry()
        return self._snapshot

    def _read_telemetry(self) -> Telemetry:
        local, glob, gps = self._msg("LOCAL_POSITION_NED"), self._msg("GLOBAL_POSITION_INT"), self._msg("GPS_RAW_INT")
        battery, status, state = self._msg("BATTERY_STATUS"), self._msg("SYS_STATUS"), self._msg("EXTENDED_SYS_STATE")
        pct, volts = None, None
        if status is not None:
            pct = status.battery_remaining if status.battery_remaining >= 0 else None
            volts = status.voltage_battery / 1000 if status.voltage_battery != _UNKNOWN_U16 else None
        if battery is not None:  # per-cell voltages, better than SYS_STATUS's
            pct = battery.battery_remaining if battery.battery_remaining >= 0 else pct
            volts = sum(v for v in battery.voltages if v != _UNKNOWN_U16) / 1000 or volts
        landed = LandedState.UNDEFINED
        if state is not None and state.landed_state in iter(LandedState):
            landed = LandedState(state.landed_state)
        return Telemetry(self.autopilot, self.armed, self.mode, self._position(),
                         _velocity(local, glob, self.frame), self.last_global(),
                         None if glob is None else glob.relative_alt / 1000, pct, volts,
                         0 if gps is None else gps.fix_type, 0 if gps is None else gps.satellites_visible,
                         landed, self.heartbeat_at, self._position_ok(), _prearm_ok(status), self._prearm_text())

    def _position_ok(self) -> bool | None:
        """ArduPilot's EKF on its position (not reported yet: not ok); None for autopilots that do not say."""
        if self.autopilot is not Autopilot.ARDUPILOT:
            return None
        ekf = self._msg("EKF_STATUS_REPORT")
        return ekf is not None and ekf_has_position(int(ekf.flags), self.armed)

    def _prearm_text(self) -> str:
        return next((text for _, _, text in reversed(self.texts) if text.startswith("PreArm")), "")

    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float, what: str) -> Telemetry:
        if not predicate(self.telemetry()):
            await self._await_or_fail(self._expect(None, lambda m: predicate(self.telemetry())), timeout, what)
        return self.telemetry()

    # ------------------------------------------------------------ inbound
    def _on_bytes(self, data: bytes) -> None:
        for msg in self._frames.feed(data):
            self._dispatch(msg)

    def _dispatch(self, msg: Message) -> None:
        kind, ids = msg.get_type(), (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT" and not _autopilot_heartbeat(msg):
            return  # a ground station's or a camera's: never the vehicle's state
        if not self._locked and kind == "HEARTBEAT" and ids[1] == self.compid and self.sysid in (None, ids[0]):
            self.sysid, self._locked = ids[0], True  # the first autopilot that speaks is ours
        if not self._locked or ids != (self.sysid, self.compid):
            return
        self._snapshot = None  # whatever it says may change the telemetry
        handler = self._handlers.get(kind)
        if handler is None:
            self.unhandled[kind] += 1
            if self.unhandled[kind] == 1:
                log.debug("vehicle %s: no handler for %s", self.sysid, kind)
            return
        handler(msg)
        self._resolve(kind, msg)

    def _resolve(self, kind: str, msg: Message) -> None:
        """Hand ``msg`` to the waiters on ``kind`` whose predicate holds (a predicate's error goes to its waiter)."""
        for future, (wanted, predicate) in list(self._waiters.items()):
            if future.done() or (wanted != kind and (wanted is not None or kind == SETPOINT_SENT)):
                continue
            try:
                if predicate(msg):
                    future.set_result(msg)
            except Exception as exc:  # the waiter's own bug: it raises there, not in the protocol callback
                future.set_exception(exc)

    def _on_heartbeat(self, msg: Message) -> None:
        if self._transport is not None:
            self._transport.vouch()  # udpin answers this datagram's sender, and hears only it
        if not self._closed:  # back from a silence: maybe rebooted, its streams forgotten
            self._streams.on_heartbeat(self._silent is not None, self._tasks)
        self.autopilot = {mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA: Autopilot.ARDUPILOT,
                          mavlink2.MAV_AUTOPILOT_PX4: Autopilot.PX4}.get(msg.autopilot, Autopilot.OTHER)
        self.custom_mode = int(msg.custom_mode)
        self.armed = bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
        self.heartbeats += 1
        self.heartbeat_at = self.clock()
        self._silent = None

    def _on_command_ack(self, msg: Message) -> None:
        self._ack_heartbeats[int(msg.command)] = self.heartbeats

    def _on_statustext(self, msg: Message) -> None:
        self.texts.append((self.clock(), int(msg.severity), str(msg.text)))
        log.info("vehicle %s says: %s", self.sysid, msg.text)

    def _keep(self, msg: Message) -> None:
        self._latest[msg.get_type()] = (self.clock(), msg)

    def _msg(self, kind: str) -> Message | None:
        entry = self._latest.get(kind)
        return None if entry is None else entry[1]

    # ------------------------------------------------------------ plumbing
    def _expect(self, kind: str | None, predicate: Callable[[Message], bool]) -> asyncio.Future[Message]:
        """A future resolved by the first ``kind`` message (any message: None) for which ``predicate`` holds."""
        future: asyncio.Future[Message] = asyncio.get_running_loop().create_future()
        self._waiters[future] = (kind, predicate)
        return future

    async def _await(self, future: asyncio.Future[Message], timeout: float) -> Message:
        """The future's message; TimeoutError after ``timeout``; VehicleError if the link fails meanwhile."""
        try:
            self._check_alive()
            return await asyncio.wait_for(future, timeout)
        finally:
            self._waiters.pop(future, None)
            future.cancel()

    async def _await_or_fail(self, future: asyncio.Future[Message], timeout: float, what: str,
                             detail: Callable[[], str] = str) -> Message:
        """As :meth:`_await`, with a VehicleError naming ``what`` on timeout."""
        try:
            return await self._await(future, timeout)
        except TimeoutError:
            raise VehicleError(f"vehicle {self.sysid}: waited {timeout} s for {what}{detail()}") from None

    def problem(self) -> str | None:
        error = self._dead or self._silent
        return None if error is None else str(error)

    def _check_alive(self) -> None:
        if error := self._dead or self._silent:
            raise error

    def _fail(self, error: VehicleError, final: bool = False) -> None:
        if final:
            self._dead = self._dead or error
        else:
            self._silent = error
        for future in list(self._waiters):
            if not future.done():
                future.set_exception(error)

    def _on_lost(self, why: str) -> None:
        self._fail(VehicleError(f"{self.url}: {why}"), final=True)
        if self._tasks and not self._closed:  # connected: the housekeeping opens it again
            self._lost_at = self.clock()
            log.warning("%s: %s; opening it again every %g s", self.url, why, REOPEN_S)

    async def _open(self) -> Transport:
        return await open_transport(self.url, self._on_bytes, self._on_lost, self.heartbeat_timeout, self.clock)

    def _deframer(self) -> Deframer:
        """A new decoder: signed messages only with a key; each datagram on its own over UDP."""
        decoder = mavlink2.MAVLink(None)
        if self.signing_key is not None:
            accept_signed_only(decoder, self.signing_key)
        return Deframer(decoder, whole=self.url.scheme in (Scheme.UDPIN, Scheme.UDPOUT))

    async def _reopen(self) -> None:
        """One attempt to open a lost stream again (the telemetry is asked for at the first HEARTBEAT)."""
        self._tried_at = self.clock()
        self._frames = self._deframer()  # a frame cut by the loss must not wait for the new stream's bytes
        try:
            transport = await asyncio.wait_for(self._open(), REOPEN_TIMEOUT_S)
        except (VehicleError, TimeoutError) as exc:
            log.debug("%s: not back yet: %s", self.url, exc)
            return
        if self._closed:  # closed while it opened
            transport.close()
            return
        log.warning("%s: open again after %.1f s", self.url, self.clock() - (self._lost_at or self._tried_at))
        self._transport, self._lost_at, self._dead, self._silent = transport, None, None, None
        # What came before the loss is no news of the vehicle now; it gets a whole timeout to speak.
        self._latest.clear()
        self._snapshot = None
        self.heartbeat_at = self.clock()
        self._streams.wanted = True
        self._send_heartbeat()

    async def _housekeeping(self) -> None:
        """Our HEARTBEAT at 1 Hz (PX4 and ArduPilot watch for a GCS), the vehicle's heartbeat watchdog,
        and a lost stream opened again."""
        last_sent = self.clock()
        async for _ in periodic(min(0.25, self.heartbeat_timeout / 4)):
            if self._closed:
                return
            now = self.clock()
            if self._lost_at is not None:
                if now - self._tried_at >= REOPEN_S:
                    await self._reopen()
                continue
            if now - last_sent >= 1.0:
                self._send_heartbeat()
                last_sent = now
            if self.heartbeat_at is not None and self._silent is None and self._dead is None \
                    and now - self.heartbeat_at > self.heartbeat_timeout:
                self._fail(VehicleError(f"vehicle {self.sysid} on {self.url}: no HEARTBEAT for "
                                        f"{now - self.heartbeat_at:.1f} s (timeout {self.heartbeat_timeout} s)"))

    def _send_heartbeat(self) -> None:
        self._send(self._enc.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0,
                                              mavlink2.MAV_STATE_ACTIVE))

    def _send(self, msg: Message) -> None:
        if self._transport is not None and self._dead is None:
            if self.signing_key is not None:
                stamp_now(self._enc)
            self._transport.send(msg.pack(self._enc))
            self._enc.seq = (self._enc.seq + 1) % 256


def _autopilot_heartbeat(msg: Message) -> bool:
    """A HEARTBEAT an autopilot sends (a ground station's says MAV_TYPE_GCS; a camera's, no autopilot)."""
    return bool(msg.autopilot != mavlink2.MAV_AUTOPILOT_INVALID and msg.type != mavlink2.MAV_TYPE_GCS)


def _velocity(local: Message | None, glob: Message | None, frame: GeoFrame | None) -> Ned | None:
    """From the message the positions come from: LOCAL_POSITION_NED (m/s), or with a frame (whose
    axes are north, east and down too) GLOBAL_POSITION_INT (cm/s)."""
    if frame is None:
        return None if local is None else Ned(local.vx, local.vy, local.vz)
    return None if glob is None else Ned(glob.vx / 100, glob.vy / 100, glob.vz / 100)


def _prearm_ok(status: Message | None) -> bool | None:
    """SYS_STATUS's pre-arm check bit (ArduPilot: healthy when armed or the checks pass); None if not reported."""
    bit = mavlink2.MAV_SYS_STATUS_PREARM_CHECK
    if status is None or not status.onboard_control_sensors_present & status.onboard_control_sensors_enabled & bit:
        return None
    return bool(status.onboard_control_sensors_health & bit)


def _geo(msg: Message) -> GeoPoint:
    """GLOBAL_POSITION_INT's position."""
    return GeoPoint(msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000)


def _any(msg: Message) -> bool:
    return True


def _ignore(msg: Message) -> None:
    """A message type we receive and deliberately do nothing with."""
