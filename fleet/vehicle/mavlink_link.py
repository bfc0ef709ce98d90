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

Positions: without ``frame`` they are in the autopilot's local NED frame. With a
:class:`~drona_gcs.geo.GeoFrame` they are in that workspace's frame: targets go out as
SET_POSITION_TARGET_GLOBAL_INT and positions come from GLOBAL_POSITION_INT (see
:mod:`fleet.vehicle.mavlink_telemetry`). No ArduPilot parameter is read or written.

What the vehicle's HEARTBEATs, ACKs and texts say is kept by a sans-I/O
:class:`~fleet.vehicle.session.MavlinkSession`; what to send each autopilot and what confirms it is
:mod:`fleet.vehicle.policy`, as for the MAVSDK backend.

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

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from drona_gcs.errors import VehicleCommandRejected, VehicleError
from drona_gcs.geo import GeoFrame, GeoPoint, Ned
from fleet.clock import cancel_all, periodic
from fleet.vehicle.commands import ConfirmedCommands
from fleet.vehicle.frames import Deframer
from fleet.vehicle.link import (
    POSITION_ONLY,
    POSITION_VELOCITY,
    REOPEN_S,
    STILL,
    Aim,
    Position,
    Share,
    StreamRequests,
    Sweep,
    Telemetry,
    Trail,
)
from fleet.vehicle.mavlink_telemetry import (
    ARDUPILOT_STREAMS,
    FRAMED_STREAMS,
    KEPT,
    POSITION_KINDS,
    STREAMS,
    Latest,
    streams_for,
)
from fleet.vehicle.policy import (
    DEFAULT_TIMEOUTS,
    Command,
    Expectation,
    Timeouts,
    explains_refusal,
    may_stream_setpoints,
    policy_of,
)
from fleet.vehicle.session import CommandAck, Heartbeat, MavlinkSession, StatusText, Verdict, autopilot_heartbeat
from fleet.vehicle.signing import accept_signed_only, sign_outgoing, stamp_now
from fleet.vehicle.urls import LinkUrl, Scheme, Transport, open_transport, parse_link_url
from fleet.vehicle.waiters import SETPOINT_SENT, Message, Waiters, any_message

__all__ = ["ARDUPILOT_STREAMS", "FRAMED_STREAMS", "STREAMS", "PymavlinkLink"]  # the streams: where they were

log = logging.getLogger(__name__)

GCS_COMPONENT = mavlink2.MAV_COMP_ID_MISSIONPLANNER
REOPEN_TIMEOUT_S = 5.0  #: how long one attempt may take (a TCP connect to a host that does not answer)


def _command_name(command: int) -> str:
    entry = mavlink2.enums["MAV_CMD"].get(command)
    return entry.name.removeprefix("MAV_CMD_") if entry is not None else f"command {command}"


# ------------------------------------------------------------------ the link
class PymavlinkLink(ConfirmedCommands):
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
        self.compid = mavlink2.MAV_COMP_ID_AUTOPILOT1
        self.session = MavlinkSession(str(self.url), heartbeat_timeout, target_system)
        self.signing_key = signing_key
        self._enc = mavlink2.MAVLink(None, srcSystem=source_system, srcComponent=GCS_COMPONENT)
        if signing_key is not None:
            sign_outgoing(self._enc, signing_key)
        self._frames = self._deframer()
        self._transport: Transport | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._waiters = Waiters(self._check_alive, lambda: f"vehicle {self.sysid}")
        self._lost_at: float | None = None  #: when the stream was lost (None: not lost, or closed by us)
        self._tried_at = -math.inf  #: the last attempt to open a lost stream again
        self._closed = False  #: closed by us: a stream lost now is not opened again
        self._streams = StreamRequests(self._ask_for_streams, str(self.url))
        self._started = clock()
        self._aim: Aim | None = None  #: streamed at setpoint_hz (PX4 leaves OFFBOARD without it)
        self._setpoints_sent = 0
        self._latest = Latest()  #: telemetry: the last message of each type
        self._trail = Trail()
        self.parameters: dict[str, float] = {}
        #: telemetry() as of the last message: read several times per drone at every step boundary
        self._snapshot: Telemetry | None = None
        self.unhandled: collections.Counter[str] = collections.Counter()
        self._handlers: dict[str, Callable[[Message], None]] = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_ACK": self._on_command_ack,
            "STATUSTEXT": self._on_statustext,
            "PARAM_VALUE": self._on_param_value,
            **dict.fromkeys(KEPT, self._keep),  # telemetry()
            # Ignored on purpose:
            **dict.fromkeys(("ATTITUDE", "ATTITUDE_QUATERNION", "HOME_POSITION", "TIMESYNC", "SYSTEM_TIME",
                             "AUTOPILOT_VERSION", "RADIO_STATUS", "VFR_HUD",
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
            await self._waiters.until("HEARTBEAT", any_message, timeout, "a HEARTBEAT from a vehicle")
            await self._ask_for_streams()
        except BaseException:
            await self.close()
            raise

    async def _ask_for_streams(self) -> None:
        """The telemetry at our rates (every stream's request acknowledged, or VehicleError)."""
        for msg_id, share in self.streams.items():
            await self.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, share.interval_us(self.stream_hz))

    async def close(self) -> None:
        self._closed, self._lost_at = True, None
        await cancel_all(self._tasks)
        if self._transport is not None:
            self._transport.close()
        self._fail(VehicleError(f"{self.url}: link closed"), final=True)

    async def wait_ready(self, timeout: float) -> None:
        """:func:`~fleet.vehicle.link.not_ready`, and a healthy GPS; VehicleError after ``timeout``."""
        if self._not_ready() is not None:
            await self._waiters.until(None, lambda m: self._not_ready() is None, timeout, "readiness",
                                      lambda: f" ({self._not_ready()})")

    def _not_ready(self) -> str | None:
        return self._latest.not_ready(self.telemetry())

    # ------------------------------------------------------------ commands
    async def command(self, command: int, *params: float, name: str = "") -> int:
        """COMMAND_LONG, acknowledged: returns the heartbeat count at the ACK; raises VehicleCommandRejected."""
        label = name or _command_name(command)
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        since, me = self.clock(), self._enc.srcSystem
        for confirmation in range(self.retries + 1):
            self._check_alive()
            ack = self._waiters.expect("COMMAND_ACK", lambda m: m.command == command and m.target_system in (0, me)
                                       and m.result != mavlink2.MAV_RESULT_IN_PROGRESS)
            self._send(self._enc.command_long_encode(self.sysid or 0, self.compid, command, confirmation, *p))
            try:
                msg = await self._waiters.wait(ack, self.ack_timeout)
            except TimeoutError:
                continue
            if msg.result != mavlink2.MAV_RESULT_ACCEPTED:
                raise VehicleCommandRejected(label, int(msg.result), await self._reason_since(since))
            ack_seen = self.session.acks.get(command)
            return self.heartbeats if ack_seen is None else ack_seen.heartbeats
        raise VehicleError(f"{label}: no COMMAND_ACK from vehicle {self.sysid} after {self.retries + 1} tries "
                           f"of {self.ack_timeout} s")

    async def _order(self, label: str, command: Command, params: tuple[float, ...]) -> int:
        return await self.command(command, *params, name=label)

    async def _read_parameter(self, name: str) -> float | None:
        return await self._parameter_answer(
            name, self._enc.param_request_read_encode(self.sysid or 0, self.compid, name.encode(), -1))

    async def _set_parameter(self, name: str, value: float) -> float | None:
        return await self._parameter_answer(name, self._enc.param_set_encode(
            self.sysid or 0, self.compid, name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32))

    async def _parameter_answer(self, name: str, message: Message) -> float | None:
        """Send ``message``; the value of the PARAM_VALUE for ``name`` that answers it (None: none in time)."""
        self._check_alive()
        answer = self._waiters.expect("PARAM_VALUE", lambda m: m.param_id == name)
        self._send(message)
        try:
            return float((await self._waiters.wait(answer, self.ack_timeout)).param_value)
        except TimeoutError:
            return None

    async def _await_verdict(self, expect: Expectation, seen: int) -> Verdict:
        """Each HEARTBEAT within ``heartbeat_timeout`` of the last, until the verdict is in."""
        while (verdict := self.session.verdict(expect, seen)) is Verdict.PENDING:
            await self._waiters.until("HEARTBEAT", any_message, self.heartbeat_timeout,
                                      f"a HEARTBEAT after {expect.label}")
        return verdict

    def _stop_setpoints(self) -> None:
        self._aim = None

    async def follow_setpoints(self) -> None:
        """GUIDED on ArduPilot; on PX4 stream the current position as the setpoint, then OFFBOARD."""
        policy = policy_of(self.autopilot)
        mode = policy.follow_mode
        if mode is None or self.session.in_mode(mode):
            return
        if policy.setpoints_first and self._aim is None:
            here = self.last_position()
            if here is None:
                raise VehicleError(f"vehicle {self.sysid}: no position to hold while entering OFFBOARD")
            await self.send_position_target(here.ned)
        if policy.setpoints_first:  # PX4 refuses OFFBOARD until setpoints arrive: stream a few first
            sent = self._setpoints_sent
            await self._waiters.until(SETPOINT_SENT, lambda m: self._setpoints_sent >= sent + 3,
                                      10 / self.setpoint_hz, "the setpoint stream")
        await self.set_mode(mode)

    async def _reason_since(self, since: float) -> str:
        """The serious STATUSTEXT since ``since``, waiting ``text_grace`` for one if none came yet."""
        if texts := self.session.serious_since(since):
            return texts[-1]
        with contextlib.suppress(TimeoutError):
            text = self._waiters.expect("STATUSTEXT", lambda m: explains_refusal(m.severity))
            msg = await self._waiters.wait(text, self.text_grace)
            return str(msg.text)
        return ""

    # ------------------------------------------------------------ setpoints
    async def send_position_target(self, target: Ned, sweep: Sweep | None = None) -> None:
        """Fly to ``target`` (local NED, or the workspace frame's with ``frame``), or along ``sweep`` from it;
        streamed at ``setpoint_hz``. The target being streamed, sent again, is left to the stream (a drone at
        rest gets one at every boundary)."""
        if self._aim is not None and (target, sweep) == (self._aim.start, self._aim.sweep):
            self._check_alive()
            return
        self._aim = Aim(target, sweep, self.clock())
        self._check_alive()
        self._send_setpoint()

    def _setpoint(self) -> Message:
        """The aim as of now: SET_POSITION_TARGET_LOCAL_NED, or _GLOBAL_INT with ``frame``."""
        assert self._aim is not None
        motion = self._aim.at(self.clock())
        where, v = motion.where, motion.velocity or STILL
        mask = POSITION_ONLY if motion.velocity is None else POSITION_VELOCITY
        ms = round((self.clock() - self._started) * 1000) & 0xFFFFFFFF
        if self.frame is None:
            return self._enc.set_position_target_local_ned_encode(
                ms, self.sysid or 0, self.compid, mavlink2.MAV_FRAME_LOCAL_NED, mask,
                where.north, where.east, where.down, v.north, v.east, v.down, 0, 0, 0, 0, 0)
        g = self.frame.ned_to_global(where)
        return self._enc.set_position_target_global_int_encode(
            ms, self.sysid or 0, self.compid, mavlink2.MAV_FRAME_GLOBAL_INT, mask,
            round(g.lat * 1e7), round(g.lon * 1e7), g.alt_m, v.north, v.east, v.down, 0, 0, 0, 0, 0)

    def _send_setpoint(self) -> None:
        if self._aim is not None and may_stream_setpoints(self.telemetry()):
            message = self._setpoint()
            self._send(message)
            self._setpoints_sent += 1
            self._waiters.resolve(SETPOINT_SENT, message)

    async def _stream_setpoint(self) -> None:
        async for _ in periodic(1 / self.setpoint_hz):
            if self.session.problem() is None:
                self._send_setpoint()

    # ------------------------------------------------------------ telemetry
    def last_position(self) -> Position | None:
        """LOCAL_POSITION_NED; with ``frame``, GLOBAL_POSITION_INT in the workspace frame."""
        return self._latest.position(self.frame)

    def positions_since(self, at: float) -> list[Position]:
        return self._trail.since(at)

    def last_global(self) -> GeoPoint | None:
        return self._latest.global_position()

    @property
    def streams(self) -> dict[int, Share]:
        """The telemetry asked for: message id -> rate as a share of ``stream_hz``."""
        return streams_for(self.frame, self.autopilot)

    def telemetry(self) -> Telemetry:
        if self._snapshot is None:
            self._snapshot = self._latest.telemetry(self.session, self.frame)
        return self._snapshot

    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float, what: str) -> Telemetry:
        if not predicate(self.telemetry()):
            await self._waiters.until(None, lambda m: predicate(self.telemetry()), timeout, what)
        return self.telemetry()

    # ------------------------------------------------------------ inbound
    def _on_bytes(self, data: bytes) -> None:
        for msg in self._frames.feed(data):
            self._dispatch(msg)

    def _dispatch(self, msg: Message) -> None:
        kind, ids = msg.get_type(), (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT" and not autopilot_heartbeat(msg.autopilot, msg.type):
            return  # a ground station's or a camera's: never the vehicle's state
        if not self.session.accepts(*ids, heartbeat=kind == "HEARTBEAT"):  # the first autopilot that speaks is ours
            return
        self._snapshot = None  # whatever it says may change the telemetry
        handler = self._handlers.get(kind)
        if handler is None:
            self.unhandled[kind] += 1
            if self.unhandled[kind] == 1:
                log.debug("vehicle %s: no handler for %s", self.sysid, kind)
            return
        handler(msg)
        self._waiters.resolve(kind, msg)

    def _on_heartbeat(self, msg: Message) -> None:
        if self._transport is not None:
            self._transport.vouch()  # udpin answers this datagram's sender, and hears only it
        heartbeat = Heartbeat.decode(msg.autopilot, int(msg.custom_mode), msg.base_mode)
        after_silence = self.session.receive(heartbeat, self.clock())
        if not self._closed:  # back from a silence: maybe rebooted, its streams forgotten
            self._streams.on_heartbeat(after_silence, self._tasks)

    def _on_command_ack(self, msg: Message) -> None:
        self.session.receive(CommandAck(int(msg.command), int(msg.result)), self.clock())

    def _on_statustext(self, msg: Message) -> None:
        self.session.receive(StatusText(int(msg.severity), str(msg.text)), self.clock())
        log.info("vehicle %s says: %s", self.sysid, msg.text)

    def _on_param_value(self, msg: Message) -> None:
        self.parameters[str(msg.param_id)] = float(msg.param_value)

    def _keep(self, msg: Message) -> None:
        self._latest.keep(msg, self.clock())
        if msg.get_type() in POSITION_KINDS:
            self._trail.add(self.last_position())

    # ------------------------------------------------------------ plumbing
    def _fail(self, error: VehicleError, final: bool = False) -> None:
        self.session.fail(error, final)
        self._waiters.fail(error)

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
        self._transport, self._lost_at = transport, None
        # What came before the loss is no news of the vehicle now; it gets a whole timeout to speak.
        self.session.reopened(self.clock())
        self._latest.clear()
        self._trail.clear()
        self._snapshot = None
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
            if (silence := self.session.watch(now)) is not None:
                self._fail(silence)

    def _send_heartbeat(self) -> None:
        self._send(self._enc.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0,
                                              mavlink2.MAV_STATE_ACTIVE))

    def _send(self, msg: Message) -> None:
        if self._transport is not None and not self.session.dead:
            if self.signing_key is not None:
                stamp_now(self._enc)
            self._transport.send(msg.pack(self._enc))
            self._enc.seq = (self._enc.seq + 1) % 256


def _ignore(msg: Message) -> None:
    """A message type we receive and deliberately do nothing with."""
