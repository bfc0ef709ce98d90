"""The MAVSDK backend of :class:`~fleet.vehicle.link.VehicleLink`: MAVSDK 4 (the ctypes binding) does the MAVLink.

MAVSDK's plugins carry the commands: Action arms, disarms and lands, Offboard follows setpoints
(PX4's OFFBOARD, ArduCopter's GUIDED; MAVSDK streams the last setpoint at 20 Hz itself).
MavlinkDirect carries what MAVSDK has no call for: DO_SET_MODE by autopilot mode name, and
NAV_TAKEOFF with its altitude (MAVSDK's own takeoff altitude is PX4's MIS_TAKEOFF_ALT parameter,
and this link writes no parameter). Telemetry comes from subscriptions whose latest values
:meth:`MavsdkLink.telemetry` reads; HEARTBEAT, COMMAND_ACK and STATUSTEXT are subscribed through
MavlinkDirect for the exact mode, the exact MAV_RESULT of a refusal and the text that explains it.

Errors are mapped at this edge: a refused command (ActionError, OffboardError, a COMMAND_ACK that
is not ACCEPTED) is a :class:`~drona_gcs.errors.VehicleCommandRejected` with the MAV_RESULT and
the vehicle's STATUSTEXT; timeouts, a failed connection and a vehicle silent for
``heartbeat_timeout`` are :class:`~drona_gcs.errors.VehicleError`. Every wait is bounded. MAVSDK is
driven through its callback API (``arm_async``, ``subscribe_*``): its callbacks only hand the result to
the event loop (``call_soon_threadsafe``), so no thread ever blocks on a vehicle that went quiet, and a
call the link gave up on is simply forgotten.

MAVSDK hides the wire: a refused or closed TCP connection only shows in its log (its ``tcpout``
reconnects in the background), so here both look like a vehicle that stopped sending HEARTBEATs.
MAVSDK keeps a serial device open after it is gone (a USB adapter pulled out, a flight controller
on USB rebooted), so a silent serial link is opened again by its name every :data:`REOPEN_S`
seconds (a ``/dev/serial/by-id/...`` link finds the adapter wherever it comes back). At the first
HEARTBEAT after a silence the telemetry streams are asked for again (a rebooted autopilot forgot
them, and MAVSDK does not ask again), at each HEARTBEAT until every request is answered: as the
pymavlink backend does both.

Positions are local NED, or with a :class:`~drona_gcs.geo.GeoFrame` that workspace's frame (targets
go out as global setpoints, positions come from the global position), as with the pymavlink backend.

MAVSDK cannot sign MAVLink 2 (it has no signing API: mavlink/MAVSDK#1060), so a signing key is
refused with a :class:`~fleet.vehicle.signing.SigningKeyError` rather than flown unsigned.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import functools
import json
import logging
import math
import time
from collections.abc import Awaitable, Callable
from typing import Any

from mavsdk import Autopilot as MavsdkAutopilot
from mavsdk import ComponentType, Configuration, Mavsdk, MavsdkError
from mavsdk.plugins.action import Action, ActionError
from mavsdk.plugins.mavlink_direct import MavlinkDirect, MavlinkDirectError, MavlinkMessage
from mavsdk.plugins.offboard import Offboard, OffboardError, PositionGlobalYaw, PositionNedYaw
from mavsdk.plugins.telemetry import Telemetry as MavsdkTelemetry
from mavsdk.plugins.telemetry import TelemetryError

from drona_gcs.errors import VehicleCommandRejected, VehicleError
from drona_gcs.geo import GeoFrame, GeoPoint, Ned
from fleet.clock import cancel_all, periodic
from fleet.vehicle.link import REOPEN_S, Autopilot, LandedState, Position, Share, StreamRequests, Telemetry, not_ready
from fleet.vehicle.modes import CONFIRM_HEARTBEATS, FOLLOW_MODE, LAND_MODE, ModeDoubt, mode_command, mode_name
from fleet.vehicle.policy import DEFAULT_TIMEOUTS, Timeouts, ekf_has_position, may_stream_setpoints, takeoff_started
from fleet.vehicle.signing import SigningKeyError
from fleet.vehicle.urls import LinkUrl, Scheme, parse_link_url

log = logging.getLogger(__name__)

ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4  #: MAV_RESULT
SET_MESSAGE_INTERVAL, NAV_TAKEOFF, DO_SET_MODE = 511, 22, 176  #: MAV_CMD
ARM_DISARM, NAV_LAND = 400, 21
SYS_STATUS, EXTENDED_SYS_STATE, EKF_STATUS_REPORT = 1, 245, 193  #: message ids MAVSDK has no set_rate_* for
PREARM_CHECK = 1 << 28  #: MAV_SYS_STATUS_PREARM_CHECK
POSITION_ONLY = 0b110111111000  #: SET_POSITION_TARGET_* type_mask: x, y, z only
LOCAL_NED, GLOBAL_INT = 1, 5  #: MAV_FRAME
CUSTOM_MODE_ENABLED, SAFETY_ARMED = 1, 128  #: MAV_MODE_FLAG
SETPOINTS_BEFORE_START = 3  #: at MAVSDK's own 20 Hz
SERIOUS = 4  #: MAV_SEVERITY_WARNING: texts at this severity or worse explain a refusal
#: MAVSDK's ActionResult/OffboardResult name -> MAV_RESULT, when no COMMAND_ACK says better.
RESULTS = {"COMMAND_DENIED": DENIED, "COMMAND_DENIED_LANDED_STATE_UNKNOWN": DENIED,
           "COMMAND_DENIED_NOT_LANDED": DENIED, "BUSY": TEMPORARILY_REJECTED, "UNSUPPORTED": UNSUPPORTED}
#: Results that mean no answer came: a link problem, not a refusal.
UNANSWERED = {"NO_SYSTEM", "CONNECTION_ERROR", "TIMEOUT", "UNKNOWN"}
Start = Callable[[Callable[..., None]], None]  #: starts a MAVSDK ``*_async`` call with its callback
#: MAVSDK telemetry kept as latest values, with its rate (a share of ``stream_hz``).
TELEMETRY = {"position": Share.POSITION, "position_velocity_ned": Share.POSITION, "battery": Share.STATUS,
             "gps_info": Share.GPS, "landed_state": Share.LANDED}


def mavsdk_url(url: LinkUrl) -> str:
    """Our connection string in MAVSDK's form: our ``tcp://`` (a client) is its ``tcpout://``."""
    host = f"[{url.host}]" if ":" in url.host else url.host
    return {Scheme.UDPIN: f"udpin://{host}:{url.port}", Scheme.UDPOUT: f"udpout://{host}:{url.port}",
            Scheme.TCP: f"tcpout://{host}:{url.port}", Scheme.SERIAL: f"serial://{url.device}:{url.baud}"}[url.scheme]


class MavsdkLink:
    """One vehicle through one MAVSDK instance; see the module docstring."""

    def __init__(self, url: str | LinkUrl, *, frame: GeoFrame | None = None, heartbeat_timeout: float = 3.0,
                 command_timeout: float = 3.0, text_grace: float = 0.3, stream_hz: float = 10.0,
                 setpoint_hz: float = 20.0, timeouts: Timeouts = DEFAULT_TIMEOUTS,
                 clock: Callable[[], float] = time.monotonic, signing_key: bytes | None = None) -> None:
        self.url = parse_link_url(url) if isinstance(url, str) else url
        if signing_key is not None:
            raise SigningKeyError(f"{self.url}: the mavsdk backend cannot sign MAVLink 2 (MAVSDK has no message "
                                  "signing); fly a vehicle with a signing key with --backend pymavlink")
        self.frame, self.clock = frame, clock
        self.heartbeat_timeout, self.command_timeout = heartbeat_timeout, command_timeout
        self.text_grace, self.stream_hz, self.setpoint_hz, self.timeouts = text_grace, stream_hz, setpoint_hz, timeouts
        self._setpoint: MavlinkMessage | None = None  #: ArduPilot's, repeated at setpoint_hz by this link
        self.sysid: int | None = None
        self._mavsdk: Mavsdk | None = None
        self._connection: Any = None  #: MAVSDK's handle of our connection
        self._reopened_at = -math.inf  #: the last attempt to open a silent serial link again
        self._action: Any = None
        self._offboard: Any = None
        self._telemetry: Any = None
        self._direct: Any = None
        self._tasks: list[asyncio.Task[None]] = []
        self._subscriptions: list[tuple[Callable[[Any], None], Any]] = []  #: (unsubscribe, handle)
        self._failures: set[asyncio.Future[None]] = set()  #: resolved when the link fails: ends _call's wait
        self._tick = asyncio.Event()  #: replaced after each update; waiters re-check their condition
        self._dead: VehicleError | None = None  #: closed: final
        self._silent: VehicleError | None = None  #: no heartbeat lately: cleared by the next one
        self._streams = StreamRequests(self._ask_for_streams, str(self.url))
        self.autopilot: Autopilot | None = None
        self.custom_mode: int | None = None
        self._mode_doubt = ModeDoubt()
        self.armed = False
        self.heartbeats = 0
        self.heartbeat_at: float | None = None
        self._latest: dict[str, tuple[float, Any]] = {}  #: subscription -> (clock time, latest value)
        self._acks: dict[int, tuple[float, int]] = {}  #: command -> (clock time, MAV_RESULT) of its last ACK
        self.texts: collections.deque[tuple[float, int, str]] = collections.deque(maxlen=32)

    # ------------------------------------------------------------ connection
    async def connect(self, timeout: float = 10.0) -> None:
        """Add the connection, wait for an autopilot, subscribe to telemetry and ask for its streams."""
        self._mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            try:
                self._connection = self._mavsdk.add_any_connection_with_handle(mavsdk_url(self.url))
            except MavsdkError as exc:
                raise VehicleError(f"cannot open {self.url}: {exc}") from exc
            loop = asyncio.get_running_loop()
            found: asyncio.Future[Any] = loop.create_future()
            wait = self._mavsdk.first_autopilot_async(timeout, lambda s: loop.call_soon_threadsafe(_settle, found, s))
            try:
                system = await asyncio.wait_for(found, timeout + 1.0)
            finally:
                self._mavsdk.cancel_first_autopilot(wait)
            if system is None:
                raise VehicleError(f"vehicle {self.sysid}: waited {timeout} s for a HEARTBEAT from a vehicle")
            self.sysid = system.get_system_id()
            self._action, self._offboard = Action(system), Offboard(system)
            self._telemetry, self._direct = MavsdkTelemetry(system), MavlinkDirect(system)
            self.autopilot = {MavsdkAutopilot.PX4: Autopilot.PX4, MavsdkAutopilot.ARDUPILOT: Autopilot.ARDUPILOT}.get(
                system.autopilot_type(), Autopilot.OTHER)
            for kind, handler in (("HEARTBEAT", self._on_heartbeat), ("COMMAND_ACK", self._on_command_ack),
                                  ("STATUSTEXT", self._on_statustext), ("SYS_STATUS", self._keep_direct),
                                  ("EKF_STATUS_REPORT", self._keep_direct)):
                handle = self._direct.subscribe_message(kind, self._handler(handler))
                self._subscriptions.append((self._direct.unsubscribe_message, handle))
            for name in TELEMETRY:
                keep = self._handler(functools.partial(self._keep, name))
                handle = getattr(self._telemetry, f"subscribe_{name}")(keep)
                self._subscriptions.append((getattr(self._telemetry, f"unsubscribe_{name}"), handle))
            self._tasks += [asyncio.create_task(self._watchdog()), asyncio.create_task(self._stream_setpoint())]
            await self._wait_for(lambda: self.heartbeats > 0, timeout, "a HEARTBEAT from a vehicle")
            await self._ask_for_streams()
        except BaseException:
            await self.close()
            raise

    async def _ask_for_streams(self) -> None:
        """The telemetry at our rates (ArduCopter streams nothing until asked); VehicleError if a request fails."""
        for name, share in TELEMETRY.items():
            set_rate = getattr(self._telemetry, f"set_rate_{name}_async")
            await self._call(f"set_rate_{name}", functools.partial(set_rate, self.stream_hz * share), TelemetryError)
        direct = [(SYS_STATUS, Share.STATUS), (EXTENDED_SYS_STATE, Share.LANDED)]
        if self.autopilot is Autopilot.ARDUPILOT:
            direct.append((EKF_STATUS_REPORT, Share.STATUS))
        for msg_id, share in direct:
            await self.command("SET_MESSAGE_INTERVAL", SET_MESSAGE_INTERVAL, msg_id, 1e6 / (self.stream_hz * share))

    async def close(self) -> None:
        await cancel_all(self._tasks)
        for unsubscribe, handle in self._subscriptions:
            unsubscribe(handle)
        self._subscriptions = []
        self._fail(VehicleError(f"{self.url}: link closed"), final=True)
        if self._mavsdk is not None:
            self._mavsdk.destroy()
            self._mavsdk = None

    async def wait_ready(self, timeout: float) -> None:
        """:func:`~fleet.vehicle.link.not_ready`; VehicleError after ``timeout``."""
        await self._wait_for(lambda: not_ready(self.telemetry()) is None, timeout, "readiness",
                             lambda: f" ({not_ready(self.telemetry())})")

    # ------------------------------------------------------------ commands
    async def arm(self) -> None:
        await self._confirmed("ARM", self._call("ARM", self._action.arm_async, ActionError, ARM_DISARM),
                              lambda: self.armed, "is still disarmed")

    async def disarm(self) -> None:
        await self._confirmed("DISARM", self._call("DISARM", self._action.disarm_async, ActionError, ARM_DISARM),
                              lambda: not self.armed, "is still armed")

    async def set_mode(self, mode: str) -> None:
        """Switch to ``mode`` (ArduCopter or PX4 name) with DO_SET_MODE; confirmed from the next HEARTBEAT."""
        custom, params = mode_command(self.autopilot, mode, f"vehicle {self.sysid}")
        label = f"DO_SET_MODE {mode}"
        await self._mode_doubt.around(self._confirmed(
            label, self.command(label, DO_SET_MODE, CUSTOM_MODE_ENABLED, *params),
            lambda: self.custom_mode == custom, "stayed in {mode}"))

    async def follow_setpoints(self) -> None:
        """PX4: MAVSDK's offboard, holding the current position as the first setpoint. ArduPilot: GUIDED,
        and no MAVSDK offboard: its setpoints stream from the first one on, and one cancels a take-off."""
        mode = FOLLOW_MODE.get(self.autopilot or Autopilot.OTHER)
        if mode is not None and self.mode == mode and not self._mode_doubt.in_doubt:
            return
        if self.autopilot is Autopilot.ARDUPILOT:
            await self.set_mode("GUIDED")
            return
        here = self.last_position()
        if here is None:
            raise VehicleError(f"vehicle {self.sysid}: no position to hold while starting offboard")
        # PX4 refuses OFFBOARD until setpoints stream, and MAVSDK only streams once offboard started: send a few.
        for _ in range(SETPOINTS_BEFORE_START):
            await self.send_position_target(here.ned)
            await asyncio.sleep(1 / 20)
        start = self._call("OFFBOARD start", self._offboard.start_async, OffboardError, DO_SET_MODE)
        await self._mode_doubt.around(self._confirmed("OFFBOARD start", start,
                                                      lambda: mode is None or self.mode == mode, "stayed in {mode}"))

    async def takeoff(self, altitude_m: float) -> None:
        """Climb to ``altitude_m`` above home (ArduPilot: in GUIDED, switched to first); returns once climbing."""
        if not altitude_m > 0:
            raise ValueError(f"takeoff altitude must be > 0, got {altitude_m}")
        if self.autopilot is Autopilot.ARDUPILOT:
            if self.mode != "GUIDED":
                await self.set_mode("GUIDED")
            await self.command("TAKEOFF", NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude_m)
        else:  # PX4 wants AMSL: home's altitude is the absolute minus the relative altitude
            t = self.telemetry()
            if t.global_position is None or t.height_m is None:
                raise VehicleError(f"vehicle {self.sysid}: no global position, cannot take off")
            amsl = t.global_position.alt_m - t.height_m + altitude_m
            await self.command("TAKEOFF", NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, amsl)
        await self.wait_until(takeoff_started, self.timeouts.takeoff_start_s, "the takeoff to start")

    async def land(self) -> None:
        """Land where it is; confirmed from the next HEARTBEAT's mode (ArduPilot: its setpoint is dropped)."""
        self._setpoint = None
        mode = LAND_MODE.get(self.autopilot or Autopilot.OTHER)
        await self._mode_doubt.around(self._confirmed(
            "LAND", self._call("LAND", self._action.land_async, ActionError, NAV_LAND),
            lambda: mode is None or self.mode == mode, "stayed in {mode}"))

    async def command(self, label: str, command: int, *params: float) -> None:
        """COMMAND_LONG through MavlinkDirect; VehicleCommandRejected unless the ACK says ACCEPTED."""
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        fields = {"target_system": self.sysid or 0, "target_component": 1, "command": command, "confirmation": 0,
                  # JSON has no NaN: MavlinkDirect sends null as NaN (PX4: "unset")
                  **{f"param{i + 1}": None if math.isnan(v) else v for i, v in enumerate(p)}}
        since = self.clock()
        message = MavlinkMessage(message_name="COMMAND_LONG", target_system_id=self.sysid or 0,
                                 target_component_id=1, fields_json=json.dumps(fields))
        ack = await self._call(label, lambda done: self._direct.send_command_async(message, done), MavlinkDirectError)
        result = int(json.loads(ack.fields_json)["result"])
        if result != ACCEPTED:
            raise VehicleCommandRejected(label, result, await self._reason_since(since))

    async def _confirmed(self, label: str, sent: Awaitable[Any], effect: Callable[[], bool], failure: str) -> None:
        """Await the command ``sent``, then want ``effect`` within CONFIRM_HEARTBEATS HEARTBEATs."""
        since = self.clock()
        await sent
        seen = self.heartbeats
        await self._wait_for(lambda: effect() or self.heartbeats >= seen + CONFIRM_HEARTBEATS,
                             self.heartbeat_timeout, f"a HEARTBEAT after {label}")
        if not effect():
            texts = "; ".join(t for at, sev, t in self.texts if sev <= SERIOUS and at >= since)
            reason = f"acknowledged, but the vehicle {failure.format(mode=self.mode)}"
            reason += f" ({texts})" if texts else ""
            raise VehicleCommandRejected(label, ACCEPTED, reason)

    async def _call(self, label: str, start: Start, error: type[MavsdkError], command: int | None = None) -> Any:
        """Start a MAVSDK ``*_async`` call and await its callback, bounded by ``command_timeout`` and by the link.

        Returns the call's data (MavlinkDirect's ACK) on SUCCESS. A result that means no answer is a
        VehicleError; any other is a VehicleCommandRejected with the COMMAND_ACK's MAV_RESULT and the
        vehicle's STATUSTEXT, raised from MAVSDK's own ``error`` for that result.
        """
        self._check_alive()
        since, loop = self.clock(), asyncio.get_running_loop()
        answer: asyncio.Future[tuple[Any, Any]] = loop.create_future()
        failure: asyncio.Future[None] = loop.create_future()

        def done(result: Any, *rest: Any) -> None:  # MAVSDK's thread: (result, user_data) or (result, data, user_data)
            with contextlib.suppress(RuntimeError):  # the loop is closed: nobody waits for this answer any more
                loop.call_soon_threadsafe(_settle, answer, (result, rest[0] if len(rest) > 1 else None))

        start(done)
        self._failures.add(failure)
        try:
            either: set[asyncio.Future[Any]] = {answer, failure}
            await asyncio.wait(either, timeout=self.command_timeout, return_when=asyncio.FIRST_COMPLETED)
        finally:
            self._failures.discard(failure)
            failure.cancel()
        self._check_alive()
        if not answer.done():
            raise VehicleError(f"{label}: no answer from vehicle {self.sysid} within {self.command_timeout} s")
        result, data = answer.result()
        if result.name == "SUCCESS":
            return data
        exc = error(result, label)
        if result.name in UNANSWERED or error is MavlinkDirectError or error is TelemetryError:
            raise VehicleError(f"{label}: vehicle {self.sysid} did not answer ({result.name})") from exc
        await self._until(lambda: command in self._acks and self._acks[command][0] >= since, self.text_grace)
        ack = self._acks.get(command or -1)
        mav_result = ack[1] if ack is not None and ack[0] >= since else RESULTS.get(result.name, FAILED)
        raise VehicleCommandRejected(label, mav_result, await self._reason_since(since)) from exc

    async def _reason_since(self, since: float) -> str:
        """The serious STATUSTEXT since ``since``, waiting ``text_grace`` for one if none came yet."""
        def serious() -> list[str]:
            return [t for at, sev, t in self.texts if at >= since and sev <= SERIOUS]
        await self._until(lambda: bool(serious()), self.text_grace)
        return (serious() or [""])[-1]

    # ------------------------------------------------------------ setpoints
    async def send_position_target(self, target: Ned) -> None:
        """Fly to ``target`` (local NED, or the workspace frame's with ``frame``). PX4: MAVSDK's offboard
        repeats it at 20 Hz. ArduPilot: this link repeats it at ``setpoint_hz``, once the take-off is over."""
        self._check_alive()
        if self.autopilot is Autopilot.ARDUPILOT:
            self._setpoint = self._setpoint_message(target)
            self._send_setpoint()
            return
        try:  # these only store the setpoint (and send it once): they do not wait for the vehicle
            if self.frame is None:
                self._offboard.set_position_ned(PositionNedYaw(target.north, target.east, target.down, 0.0))
            else:
                g = self.frame.ned_to_global(target)
                self._offboard.set_position_global(
                    PositionGlobalYaw(g.lat, g.lon, g.alt_m, 0.0, PositionGlobalYaw.AltitudeType.AMSL))
        except OffboardError as exc:
            raise VehicleError(f"vehicle {self.sysid}: setpoint not taken ({exc})") from exc

    def _setpoint_message(self, target: Ned) -> MavlinkMessage:
        ms = round((self.clock() % 4e6) * 1000)
        fields: dict[str, float | int] = {"time_boot_ms": ms, "target_system": self.sysid or 0, "target_component": 1,
                                          "type_mask": POSITION_ONLY, **dict.fromkeys(
                                              ("vx", "vy", "vz", "afx", "afy", "afz", "yaw", "yaw_rate"), 0.0)}
        if self.frame is None:
            name = "SET_POSITION_TARGET_LOCAL_NED"
            fields.update(coordinate_frame=LOCAL_NED, x=target.north, y=target.east, z=target.down)
        else:
            name, g = "SET_POSITION_TARGET_GLOBAL_INT", self.frame.ned_to_global(target)
            fields.update(coordinate_frame=GLOBAL_INT, lat_int=round(g.lat * 1e7), lon_int=round(g.lon * 1e7),
                          alt=g.alt_m)
        return MavlinkMessage(message_name=name, target_system_id=self.sysid or 0, target_component_id=1,
                              fields_json=json.dumps(fields))

    def _send_setpoint(self) -> None:
        if self._setpoint is not None and self._silent is None and self._dead is None \
                and may_stream_setpoints(self.telemetry()):
            try:
                self._direct.send_message(self._setpoint)
            except MavlinkDirectError as exc:
                log.debug("vehicle %s: setpoint not sent: %s", self.sysid, exc)

    async def _stream_setpoint(self) -> None:
        async for _ in periodic(1 / self.setpoint_hz):
            self._send_setpoint()

    # ------------------------------------------------------------ telemetry
    @property
    def mode(self) -> str | None:
        return mode_name(self.autopilot, self.custom_mode)

    def last_position(self) -> Position | None:
        """The local NED position; with ``frame``, the global position in the workspace frame."""
        kind = "position_velocity_ned" if self.frame is None else "position"
        if (entry := self._latest.get(kind)) is None:
            return None
        at, value = entry
        if self.frame is None:
            p = value.position
            return None if math.isnan(p.north_m) else Position(Ned(p.north_m, p.east_m, p.down_m), at)
        g = self.last_global()
        return None if g is None else Position(self.frame.global_to_ned(g), at)

    def last_global(self) -> GeoPoint | None:
        p = self._value("position")
        if p is None or math.isnan(p.latitude_deg) or p.latitude_deg == p.longitude_deg == 0:
            return None  # ArduPilot before its first estimate sends stale zeros
        return GeoPoint(p.latitude_deg, p.longitude_deg, p.absolute_altitude_m)

    def telemetry(self) -> Telemetry:
        pv, glob, battery = self._value("position_velocity_ned"), self._value("position"), self._value("battery")
        gps, landed = self._value("gps_info"), self._value("landed_state")
        pct = round(battery.remaining_percent) if battery is not None and math.isfinite(battery.remaining_percent) \
            else None
        volts = battery.voltage_v if battery is not None and math.isfinite(battery.voltage_v) else None
        height = glob.relative_altitude_m if glob is not None and math.isfinite(glob.relative_altitude_m) else None
        velocity = None if pv is None else Ned(pv.velocity.north_m_s, pv.velocity.east_m_s, pv.velocity.down_m_s)
        return Telemetry(self.autopilot, self.armed, self.mode, self.last_position(), velocity, self.last_global(),
                         height, pct, volts, 0 if gps is None else int(gps.fix_type),
                         0 if gps is None else gps.num_satellites,
                         LandedState(int(landed)) if landed is not None else LandedState.UNDEFINED, self.heartbeat_at,
                         self._position_ok(), self._prearm_ok(), self._prearm_text())

    def _position_ok(self) -> bool | None:
        """ArduPilot's EKF on its position (not reported yet: not ok); None for autopilots that do not say."""
        if self.autopilot is not Autopilot.ARDUPILOT:
            return None
        ekf = self._value("EKF_STATUS_REPORT")
        return ekf is not None and ekf_has_position(int(ekf["flags"]), self.armed)

    def _prearm_ok(self) -> bool | None:
        status = self._value("SYS_STATUS")
        if status is None or not int(status["onboard_control_sensors_present"]) \
                & int(status["onboard_control_sensors_enabled"]) & PREARM_CHECK:
            return None
        return bool(int(status["onboard_control_sensors_health"]) & PREARM_CHECK)

    def _prearm_text(self) -> str:
        return next((text for _, _, text in reversed(self.texts) if text.startswith("PreArm")), "")

    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float, what: str) -> Telemetry:
        await self._wait_for(lambda: predicate(self.telemetry()), timeout, what)
        return self.telemetry()

    # ------------------------------------------------------------ subscriptions
    def _handler(self, handle: Callable[[Any], None]) -> Callable[..., None]:
        """A MAVSDK subscription callback that hands each item to ``handle`` on the event loop."""
        loop = asyncio.get_running_loop()

        def on_item(item: Any, *user_data: Any) -> None:  # MAVSDK's thread: hand over, nothing more
            with contextlib.suppress(RuntimeError):  # the loop is closed: the link is gone
                loop.call_soon_threadsafe(self._on_item, handle, item)
        return on_item

    def _on_item(self, handle: Callable[[Any], None], item: Any) -> None:
        if self._dead is None:
            handle(item)
            self._notify()

    def _keep(self, name: str, value: Any) -> None:
        self._latest[name] = (self.clock(), value)

    def _value(self, name: str) -> Any:
        entry = self._latest.get(name)
        return None if entry is None else entry[1]

    def _on_heartbeat(self, msg: MavlinkMessage) -> None:
        if msg.component_id != 1:
            return
        if self._dead is None:  # back from a silence: maybe rebooted, its streams forgotten
            self._streams.on_heartbeat(self._silent is not None, self._tasks)
        fields = json.loads(msg.fields_json)
        self.custom_mode = int(fields["custom_mode"])
        self.armed = bool(int(fields["base_mode"]) & SAFETY_ARMED)
        self.heartbeats += 1
        self.heartbeat_at = self.clock()
        self._silent = None

    def _keep_direct(self, msg: MavlinkMessage) -> None:
        if msg.component_id == 1:
            self._keep(msg.message_name, json.loads(msg.fields_json))

    def _on_command_ack(self, msg: MavlinkMessage) -> None:
        fields = json.loads(msg.fields_json)
        self._acks[int(fields["command"])] = (self.clock(), int(fields["result"]))

    def _on_statustext(self, msg: MavlinkMessage) -> None:
        fields = json.loads(msg.fields_json)
        self.texts.append((self.clock(), int(fields["severity"]), str(fields["text"])))

    async def _watchdog(self) -> None:
        """Fails every wait when the vehicle has been silent for ``heartbeat_timeout`` seconds."""
        async for _ in periodic(min(0.25, self.heartbeat_timeout / 4)):
            now = self.clock()
            if self.heartbeat_at is not None and self._silent is None and self._dead is None \
                    and now - self.heartbeat_at > self.heartbeat_timeout:
                self._fail(VehicleError(f"vehicle {self.sysid} on {self.url}: no HEARTBEAT for "
                                        f"{now - self.heartbeat_at:.1f} s (timeout {self.heartbeat_timeout} s)"))
            if self.url.scheme is Scheme.SERIAL and self._silent is not None and self._dead is None \
                    and now - self._reopened_at >= REOPEN_S:
                self._reopen()

    def _reopen(self) -> None:
        """Open the serial device again by its name (the vehicle's streams are asked for at its first HEARTBEAT)."""
        assert self._mavsdk is not None
        self._reopened_at = self.clock()
        if self._connection is not None:
            self._mavsdk.remove_connection(self._connection)
            self._connection = None
        try:
            self._connection = self._mavsdk.add_any_connection_with_handle(mavsdk_url(self.url))
        except MavsdkError as exc:
            log.debug("%s: not back yet: %s", self.url, exc)

    # ------------------------------------------------------------ plumbing
    def _notify(self) -> None:
        self._tick.set()
        self._tick = asyncio.Event()

    async def _until(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Whether ``condition`` holds within ``timeout``, re-checked on each update; VehicleError if the link fails."""
        deadline = asyncio.get_running_loop().time() + timeout
        while True:
            self._check_alive()
            if condition():
                return True
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                return False
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._tick.wait(), remaining)

    async def _wait_for(self, condition: Callable[[], bool], timeout: float, what: str,
                        detail: Callable[[], str] = str) -> None:
        if not await self._until(condition, timeout):
            raise VehicleError(f"vehicle {self.sysid}: waited {timeout} s for {what}{detail()}")

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
        for future in self._failures:
            if not future.done():
                future.set_result(None)
        self._notify()


def _settle(future: asyncio.Future[Any], value: Any) -> None:
    if not future.done():
        future.set_result(value)
