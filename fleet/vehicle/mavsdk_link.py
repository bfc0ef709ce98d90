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

As for the pymavlink backend, a sans-I/O :class:`~fleet.vehicle.session.MavlinkSession` keeps what the
vehicle says; the commands (and offboard's start) are :class:`~fleet.vehicle.commands.ConfirmedCommands`.

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
from collections.abc import Callable
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
from fleet.vehicle.commands import ConfirmedCommands
from fleet.vehicle.link import (
    REOPEN_S,
    Aim,
    Autopilot,
    Position,
    Share,
    StreamRequests,
    Sweep,
    Telemetry,
    Trail,
    not_ready,
)
from fleet.vehicle.mavsdk_messages import (
    EKF_STATUS_REPORT,
    EXTENDED_SYS_STATE,
    RESULTS,
    SYS_STATUS,
    UNANSWERED,
    command_long,
    inbound,
    mavsdk_url,
    param_request_read,
    param_set,
    setpoint,
    settle,
)
from fleet.vehicle.mavsdk_telemetry import POSITION_NAMES, TELEMETRY, Subscribed
from fleet.vehicle.policy import (
    DEFAULT_TIMEOUTS,
    Command,
    Expectation,
    Result,
    Timeouts,
    may_stream_setpoints,
    policy_of,
)
from fleet.vehicle.session import LinkState, MavlinkSession, Verdict
from fleet.vehicle.signing import SigningKeyError
from fleet.vehicle.urls import LinkUrl, Scheme, parse_link_url
from fleet.vehicle.waiters import Updates

__all__ = ["MavsdkLink", "mavsdk_url"]  # mavsdk_url: where it was

log = logging.getLogger(__name__)

SETPOINTS_BEFORE_START = 3  #: at MAVSDK's own 20 Hz
Start = Callable[[Callable[..., None]], None]  #: starts a MAVSDK ``*_async`` call with its callback


class MavsdkLink(ConfirmedCommands):
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
        self._aim: Aim | None = None  #: ArduPilot's streamed at setpoint_hz by this link, PX4's by MAVSDK
        self.session = MavlinkSession(str(self.url), heartbeat_timeout)
        self._mavsdk: Mavsdk | None = None
        self._connection: Any = None  #: MAVSDK's handle of our connection
        self._reopened_at = -math.inf  #: the last attempt to open a silent serial link again
        self._action: Any = None
        self.parameters: dict[str, float] = {}
        self._values_heard: collections.Counter[str] = collections.Counter()  #: PARAM_VALUEs heard, by name
        self._offboard: Any = None
        self._telemetry: Any = None
        self._direct: Any = None
        self._tasks: list[asyncio.Task[None]] = []
        self._subscriptions: list[tuple[Callable[[Any], None], Any]] = []  #: (unsubscribe, handle)
        self._failures: set[asyncio.Future[None]] = set()  #: resolved when the link fails: ends _call's wait
        self._updates = Updates(self._check_alive, lambda: f"vehicle {self.sysid}")
        self._streams = StreamRequests(self._ask_for_streams, str(self.url))
        self._latest = Subscribed()  #: the subscriptions' latest values
        self._trail = Trail()

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
            wait = self._mavsdk.first_autopilot_async(timeout, lambda s: loop.call_soon_threadsafe(settle, found, s))
            try:
                system = await asyncio.wait_for(found, timeout + 1.0)
            finally:
                self._mavsdk.cancel_first_autopilot(wait)
            if system is None:
                raise VehicleError(f"vehicle {self.sysid}: waited {timeout} s for a HEARTBEAT from a vehicle")
            self.session.sysid = system.get_system_id()
            self._action, self._offboard = Action(system), Offboard(system)
            self._telemetry, self._direct = MavsdkTelemetry(system), MavlinkDirect(system)
            self.session.autopilot = {MavsdkAutopilot.PX4: Autopilot.PX4,
                                      MavsdkAutopilot.ARDUPILOT: Autopilot.ARDUPILOT}.get(system.autopilot_type(),
                                                                                          Autopilot.OTHER)
            for kind, handler in (("HEARTBEAT", self._on_heartbeat), ("COMMAND_ACK", self._on_message),
                                  ("STATUSTEXT", self._on_message), ("SYS_STATUS", self._keep_direct),
                                  ("EKF_STATUS_REPORT", self._keep_direct), ("PARAM_VALUE", self._on_parameter)):
                handle = self._direct.subscribe_message(kind, self._handler(handler))
                self._subscriptions.append((self._direct.unsubscribe_message, handle))
            for name in TELEMETRY:
                keep = self._handler(functools.partial(self._keep, name))
                handle = getattr(self._telemetry, f"subscribe_{name}")(keep)
                self._subscriptions.append((getattr(self._telemetry, f"unsubscribe_{name}"), handle))
            self._tasks += [asyncio.create_task(self._watchdog()), asyncio.create_task(self._stream_setpoint())]
            await self._updates.wait_for(lambda: self.heartbeats > 0, timeout, "a HEARTBEAT from a vehicle")
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
            await self.command("SET_MESSAGE_INTERVAL", Command.SET_MESSAGE_INTERVAL, msg_id,
                               share.interval_us(self.stream_hz))

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
        await self._updates.wait_for(lambda: not_ready(self.telemetry()) is None, timeout, "readiness",
                                     lambda: f" ({not_ready(self.telemetry())})")

    # ------------------------------------------------------------ commands
    async def _order(self, label: str, command: Command, params: tuple[float, ...]) -> int:
        """Arming and landing through MAVSDK's Action, the rest as COMMAND_LONG; the HEARTBEATs heard by its answer."""
        if command is Command.COMPONENT_ARM_DISARM:
            await self._call(label, self._action.arm_async if params[0] else self._action.disarm_async, ActionError,
                             command)
        elif command is Command.NAV_LAND:
            await self._call(label, self._action.land_async, ActionError, command)
        else:
            await self.command(label, command, *params)
        return self.heartbeats

    async def _await_verdict(self, expect: Expectation, seen: int) -> Verdict:
        """The verdict, from the last HEARTBEAT before the answer on, within ``heartbeat_timeout``."""
        def verdict() -> Verdict:
            return self.session.verdict(expect, seen, at_once=True)
        await self._updates.wait_for(lambda: verdict() is not Verdict.PENDING, self.heartbeat_timeout,
                                     f"a HEARTBEAT after {expect.label}")
        return verdict()

    def _stop_setpoints(self) -> None:
        self._aim = None

    async def follow_setpoints(self) -> None:
        """PX4: MAVSDK's offboard, holding the current position as the first setpoint. ArduPilot: GUIDED,
        and no MAVSDK offboard: its setpoints stream from the first one on, and one cancels a take-off."""
        policy = policy_of(self.autopilot)
        mode = policy.follow_mode
        if mode is not None and self.session.in_mode(mode):
            return
        if mode is not None and not policy.setpoints_first:
            await self.set_mode(mode)
            return
        here = self.last_position()
        if here is None:
            raise VehicleError(f"vehicle {self.sysid}: no position to hold while starting offboard")
        # PX4 refuses OFFBOARD until setpoints stream, and MAVSDK only streams once offboard started: send a few.
        for _ in range(SETPOINTS_BEFORE_START):
            await self.send_position_target(here.ned)
            await asyncio.sleep(1 / 20)
        expect = Expectation("OFFBOARD start", mode=mode)
        await self.session.mode_doubt.around(self._carried_out(lambda: self._offboard_start(expect.label), expect))

    async def _offboard_start(self, label: str) -> int:
        """MAVSDK's offboard start (its answer is the DO_SET_MODE's ACK); the HEARTBEATs heard by then."""
        await self._call(label, self._offboard.start_async, OffboardError, Command.DO_SET_MODE)
        return self.heartbeats

    async def _read_parameter(self, name: str) -> float | None:
        """Through MavlinkDirect: MAVSDK's Param plugin only blocks."""
        return await self._parameter_answer(name, param_request_read(self.sysid or 0, name))

    async def _set_parameter(self, name: str, value: float) -> float | None:
        return await self._parameter_answer(name, param_set(self.sysid or 0, name, value))

    async def _parameter_answer(self, name: str, message: MavlinkMessage) -> float | None:
        """Send ``message``; the value of the next PARAM_VALUE for ``name`` (None: none in time)."""
        self._check_alive()
        heard = self._values_heard[name]
        self._direct.send_message(message)
        if await self._updates.until(lambda: self._values_heard[name] > heard, self.command_timeout):
            return self.parameters[name]
        return None

    async def command(self, label: str, command: int, *params: float) -> None:
        """COMMAND_LONG through MavlinkDirect; VehicleCommandRejected unless the ACK says ACCEPTED."""
        since, message = self.clock(), command_long(self.sysid or 0, command, params)
        ack = await self._call(label, lambda done: self._direct.send_command_async(message, done), MavlinkDirectError)
        result = int(json.loads(ack.fields_json)["result"])
        if result != Result.ACCEPTED:
            raise VehicleCommandRejected(label, result, await self._reason_since(since))

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
                loop.call_soon_threadsafe(settle, answer, (result, rest[0] if len(rest) > 1 else None))

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
        await self._updates.until(lambda: self.session.ack_since(command or -1, since) is not None, self.text_grace)
        ack = self.session.ack_since(command or -1, since)
        mav_result = ack.result if ack is not None else RESULTS.get(result.name, Result.FAILED)
        raise VehicleCommandRejected(label, mav_result, await self._reason_since(since)) from exc

    async def _reason_since(self, since: float) -> str:
        """The serious STATUSTEXT since ``since``, waiting ``text_grace`` for one if none came yet."""
        await self._updates.until(lambda: bool(self.session.serious_since(since)), self.text_grace)
        return ["", *self.session.serious_since(since)][-1]

    # ------------------------------------------------------------ setpoints
    async def send_position_target(self, target: Ned, sweep: Sweep | None = None) -> None:
        """Fly to ``target`` (local NED, or the workspace frame's with ``frame``), or along ``sweep`` from it.
        ArduPilot: this link streams it at ``setpoint_hz``, once the take-off is over, the sweep's velocity
        fed forward. PX4: MAVSDK's offboard repeats it at 20 Hz; a sweep's position is moved on at this
        link's rate (as a position only: MAVSDK's offboard has no velocity with a global position)."""
        self._check_alive()
        self._aim = Aim(target, sweep, self.clock())
        if self.autopilot is Autopilot.ARDUPILOT:
            self._send_setpoint()
            return
        try:
            self._offboard_to(target)
        except OffboardError as exc:
            raise VehicleError(f"vehicle {self.sysid}: setpoint not taken ({exc})") from exc

    def _offboard_to(self, target: Ned) -> None:
        """MAVSDK's offboard setpoint: these only store it (and send it once), they do not wait for the vehicle."""
        if self.frame is None:
            self._offboard.set_position_ned(PositionNedYaw(target.north, target.east, target.down, 0.0))
        else:
            g = self.frame.ned_to_global(target)
            self._offboard.set_position_global(
                PositionGlobalYaw(g.lat, g.lon, g.alt_m, 0.0, PositionGlobalYaw.AltitudeType.AMSL))

    def _send_setpoint(self) -> None:
        if self._aim is None or self.session.problem() is not None:
            return
        motion = self._aim.at(self.clock())
        if self.autopilot is not Autopilot.ARDUPILOT:
            if motion.velocity is not None:  # a sweep under way
                with contextlib.suppress(OffboardError):
                    self._offboard_to(motion.where)
            return
        if may_stream_setpoints(self.telemetry()):
            try:
                self._direct.send_message(setpoint(self.sysid or 0, motion, self.frame, self.clock()))
            except MavlinkDirectError as exc:
                log.debug("vehicle %s: setpoint not sent: %s", self.sysid, exc)

    async def _stream_setpoint(self) -> None:
        async for _ in periodic(1 / self.setpoint_hz):
            self._send_setpoint()

    # ------------------------------------------------------------ telemetry
    def last_position(self) -> Position | None:
        return self._latest.position(self.frame)

    def positions_since(self, at: float) -> list[Position]:
        return self._trail.since(at)

    def last_global(self) -> GeoPoint | None:
        return self._latest.global_position()

    def telemetry(self) -> Telemetry:
        return self._latest.telemetry(self.session, self.frame)

    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float, what: str) -> Telemetry:
        await self._updates.wait_for(lambda: predicate(self.telemetry()), timeout, what)
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
        if not self.session.dead:
            handle(item)
            self._updates.notify()

    def _keep(self, name: str, value: Any) -> None:
        self._latest.keep(name, value, self.clock())
        if name in POSITION_NAMES:
            self._trail.add(self.last_position())

    def _on_heartbeat(self, msg: MavlinkMessage) -> None:
        if msg.component_id != 1:
            return
        after_silence = self.session.receive(inbound(msg), self.clock())
        if not self.session.dead:  # back from a silence: maybe rebooted, its streams forgotten
            self._streams.on_heartbeat(after_silence, self._tasks)

    def _keep_direct(self, msg: MavlinkMessage) -> None:
        if msg.component_id == 1:
            self._keep(msg.message_name, json.loads(msg.fields_json))

    def _on_parameter(self, msg: MavlinkMessage) -> None:
        if msg.component_id == 1:
            fields = json.loads(msg.fields_json)
            name = str(fields["param_id"])
            self.parameters[name] = float(fields["param_value"])
            self._values_heard[name] += 1
            self._updates.notify()

    def _on_message(self, msg: MavlinkMessage) -> None:
        """A COMMAND_ACK or a STATUSTEXT."""
        self.session.receive(inbound(msg), self.clock())

    async def _watchdog(self) -> None:
        """Fails every wait when the vehicle has been silent for ``heartbeat_timeout`` seconds."""
        async for _ in periodic(min(0.25, self.heartbeat_timeout / 4)):
            now = self.clock()
            if (silence := self.session.watch(now)) is not None:
                self._fail(silence)
            if self.url.scheme is Scheme.SERIAL and self.session.state is LinkState.SILENT \
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
    def _fail(self, error: VehicleError, final: bool = False) -> None:
        self.session.fail(error, final)
        for future in self._failures:
            if not future.done():
                future.set_result(None)
        self._updates.notify()
