"""The fake vehicle itself, sans-I/O: decoded MAVLink messages in, messages out, time passed as ``now``.

``handle(msg, now)`` answers one incoming message; ``step(now)`` advances the flight rules,
the motion and the battery to ``now`` (:mod:`fleet.sim.flight`) and returns the telemetry then
due (:mod:`fleet.sim.telemetry`). Nothing here reads a clock or touches
a socket, so a test can drive it directly and the runner can drive many from one loop.

Behaviour copied from the real autopilots (see :mod:`fleet.sim.personality` for the numbers,
measured on their SITLs):

* a GPS fix comes ``gps_after_s`` after boot and the position estimate ``ready_after_s`` after
  it (ArduCopter SITL: 10 and 41.5 s); before the estimate there is no LOCAL_POSITION_NED or
  HOME_POSITION, ArduCopter's EKF_STATUS_REPORT has no absolute position and its
  GLOBAL_POSITION_INT says 0 degrees until the fix (PX4 sends none);
* arming is refused until the vehicle is ready and with a low battery; ArduCopter answers
  MAV_RESULT_FAILED with a STATUSTEXT. Disarmed, ArduCopter takes any mode (GUIDED too)
  before its estimate (``Copter::set_mode`` checks nothing while disarmed);
* ArduCopter takes off only armed in GUIDED and not yet airborne; its motors spool up for
  ``spool_up_s`` first (its landed state ON_GROUND), then it climbs (TAKEOFF) and holds there
  (IN_AIR). A position setpoint in GUIDED switches it to position control at once, cancelling a
  take-off: one that came before it left the ground leaves it there. It ignores setpoints
  outside GUIDED and holds at the last target;
* PX4 enters OFFBOARD only while setpoints stream and leaves it for AUTO.LOITER when they stop
  for more than COM_OF_LOSS_T;
* a vehicle armed on the ground disarms itself: ArduCopter after DISARM_DELAY, PX4 after
  COM_DISARM_PRFLT before a take-off and COM_DISARM_LAND after a touchdown; LAND and RTL disarm on
  touchdown;
* SYS_STATUS carries the pre-arm checks (MAV_SYS_STATUS_PREARM_CHECK, healthy when it may arm),
  which MAVSDK reads as ``health.is_armable``; ArduPilot's also its geofence (present for
  FENCE_TYPE's circle, enabled with FENCE_ENABLE only, healthy: never breached), PX4's none;
  PX4 answers PING requests;
* parameters (:mod:`fleet.sim.params`): each autopilot's small table, listed (paced), read and set
  over MAVLink; the values drive the model (motion limits, auto-disarm delays, return and take-off
  heights, offboard and GUIDED timeouts). PX4 answers parameter and mission requests addressed to
  its own system id only, ArduPilot broadcast ones (system 0) too;
* commands (:mod:`fleet.sim.commands`): each refused as its autopilot refuses it;
* missions (:mod:`fleet.sim.mission`): every list empty but ArduPilot's home, its item 0; uploads
  refused but empty ones. MAVLink FTP (:mod:`fleet.sim.ftp`) is refused at once, as for a file the
  autopilot does not have, so a ground station falls back to the message protocols.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import replace

from drona_gcs.geo import GeoPoint, Ned
from fleet.sim import commands, flight, ftp, mission, telemetry
from fleet.sim import params as parameters
from fleet.sim.commands import ACCEPTED, UNSUPPORTED, Command
from fleet.sim.config import Placement, VehicleConfig
from fleet.sim.mav import Message, mavlink2, source
from fleet.sim.params import ParamStore, Setting
from fleet.sim.personality import ARDUPILOT, Behaviour
from fleet.sim.physics import Battery, Body, Target
from fleet.sim.setpoints import setpoint_from_global, setpoint_from_local

__all__ = ["Command", "Placement", "VehicleConfig", "VehicleModel"]

#: Answers a message addressed to the vehicle: model, message, now -> messages to send.
Answer = Callable[["VehicleModel", Message, float], list[Message]]

log = logging.getLogger(__name__)


class VehicleModel:
    """One fake vehicle: its state and the message handlers (its commands: :mod:`fleet.sim.commands`)."""

    def __init__(self, config: VehicleConfig, placement: Placement, now: float) -> None:
        self.config = config
        self.personality = config.personality
        self.placement = placement
        self.home_global = placement.frame.ned_to_global(placement.home)
        self.boot_time = now
        self.last_step = now
        self.mode = self.personality.boot_mode
        self.armed = False
        self.airborne = False  #: has left the ground since the last touchdown
        self.flown = False  #: has left the ground since it was armed
        self.takeoff_point: Target | None = None  #: a takeoff is under way to this point
        self.climb_at = now  #: when the take-off's spool-up ends and the climb begins
        self.landed_since = now
        self.setpoint: Target | None = None
        self.setpoint_times: deque[float] = deque(maxlen=8)
        self.params = ParamStore(config)
        self.body = Body(self.params.limits)
        self.battery = Battery(remaining=config.battery_pct / 100)
        # Each vehicle out of step with the others (the golden ratio spreads any number evenly).
        self.streams = telemetry.Streams(dict(self.personality.default_streams), now,
                                         phase=(config.instance + 1) * 0.6180339887)
        self.unhandled: dict[str, int] = {}
        self._out: list[Message] = []
        self._handlers: dict[str, Callable[[Message, float], None]] = {
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_MODE": self._on_set_mode,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_setpoint,
            "SET_POSITION_TARGET_GLOBAL_INT": self._on_setpoint,
            "TIMESYNC": self._on_timesync,
            "REQUEST_DATA_STREAM": self._on_request_data_stream,
            "PING": self._on_ping,
            "PARAM_REQUEST_LIST": self._answer(parameters.on_request_list),
            "PARAM_REQUEST_READ": self._answer(parameters.on_request_read),
            "PARAM_SET": self._answer(parameters.on_set),
            "MISSION_REQUEST_LIST": self._answer(mission.on_request_list),
            "MISSION_REQUEST_INT": self._answer(mission.on_request_item),
            "MISSION_REQUEST": self._answer(mission.on_request_item),
            "MISSION_COUNT": self._answer(mission.on_upload),
            "MISSION_CLEAR_ALL": self._answer(mission.on_upload),
            "FILE_TRANSFER_PROTOCOL": self._answer(ftp.on_request, own_id=False),
            # Ignored on purpose:
            "HEARTBEAT": _ignore,  # the ground station's; we answer whoever writes
            "BAD_DATA": _ignore,  # corrupt bytes, or unsigned/badly signed while signing is on
            "SYSTEM_TIME": _ignore,
            "RADIO_STATUS": _ignore,
            "COMMAND_ACK": _ignore,
            "MISSION_ACK": _ignore,  # the ground station's word on a transfer; nothing follows it
        }
        self._commands: dict[int, commands.Run] = dict(commands.COMMANDS)

    # ------------------------------------------------------------------ state
    def ready(self, now: float) -> bool:
        """Has a position estimate (may arm)."""
        return now - self.boot_time >= self.config.ready_s

    def gps_fixed(self, now: float) -> bool:
        return now - self.boot_time >= self.config.gps_s

    def boot_ms(self, now: float) -> int:
        return max(0, round((now - self.boot_time) * 1000))

    @property
    def behaviour(self) -> Behaviour:
        return self.personality.behaviour(self.mode)

    def ned(self) -> Ned:
        """Where the vehicle is, in the workspace's NED frame."""
        h, b = self.placement.home, self.body
        return Ned(h.north + b.north, h.east + b.east, h.down + b.down)

    def global_position(self) -> GeoPoint:
        return self.placement.frame.ned_to_global(self.ned())

    def landed_state(self) -> int:
        """As ArduCopter's ``landed_state()``: on the ground until it left it (the spool-up too), taking
        off until its take-off is over, landing in LAND, else in the air."""
        state: int
        climbing = self.takeoff_point is not None and self.armed and self.last_step >= self.climb_at
        if not self.airborne and not climbing:
            state = mavlink2.MAV_LANDED_STATE_ON_GROUND
        elif self.takeoff_point is not None:
            state = mavlink2.MAV_LANDED_STATE_TAKEOFF
        elif self.behaviour is Behaviour.LAND:
            state = mavlink2.MAV_LANDED_STATE_LANDING
        else:
            state = mavlink2.MAV_LANDED_STATE_IN_AIR
        return state

    def on_charger(self) -> bool:
        size = self.placement.frame.ws.cell_size_m
        h, b = self.placement.home, self.body
        cell = (math.floor((h.east + b.east) / size), math.floor((h.north + b.north) / size))
        return cell in self.placement.chargers

    # ---------------------------------------------------------------- inbound
    def handle(self, msg: Message, now: float) -> list[Message]:
        """Answer one decoded message; returns what to send (ACKs, texts, requested messages)."""
        kind = msg.get_type()
        handler = self._handlers.get(kind)
        if handler is None:
            self.unhandled[kind] = self.unhandled.get(kind, 0) + 1
            if self.unhandled[kind] == 1:
                log.debug("vehicle %d: no handler for %s", self.config.system_id, kind)
            return []
        handler(msg, now)
        out, self._out = self._out, []
        return out

    def _for_me(self, target_system: int, target_component: int = 0) -> bool:
        return target_system in (0, self.config.system_id) and target_component in (0, mavlink2.MAV_COMP_ID_AUTOPILOT1)

    def _answer(self, answer: Answer, own_id: bool = True) -> Callable[[Message, float], None]:
        """A handler sending what ``answer`` says to a message addressed to this vehicle. ``own_id``: PX4's
        parameter and mission managers take only their system id, not a broadcast (system 0)."""
        def handler(msg: Message, now: float) -> None:
            broadcast_refused = own_id and self.personality is not ARDUPILOT and msg.target_system == 0
            if self._for_me(msg.target_system, msg.target_component) and not broadcast_refused:
                self._out.extend(answer(self, msg, now))
        return handler

    def _on_command_long(self, msg: Message, now: float) -> None:
        if self._for_me(msg.target_system, msg.target_component):
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
            self._run_command(Command(msg.command, params, None, source(msg)), now)

    def _on_command_int(self, msg: Message, now: float) -> None:
        if self._for_me(msg.target_system, msg.target_component):
            params = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
            self._run_command(Command(msg.command, params, msg.frame, source(msg)), now)

    def _run_command(self, cmd: Command, now: float) -> None:
        run = self._commands.get(cmd.command)
        result, after = run(self, cmd, now) if run else (UNSUPPORTED, [])
        # The ACK goes first; texts follow (ArduPilot queues STATUSTEXT), then requested messages.
        self._out.insert(0, telemetry.command_ack(cmd.command, result, cmd.source))
        self._out.extend(after)

    def _on_set_mode(self, msg: Message, now: float) -> None:
        if not self._for_me(msg.target_system):
            return
        result = self.change_mode(msg.base_mode, msg.custom_mode, now)
        # ArduPilot ACKs SET_MODE with the message id as the command; PX4 with DO_SET_MODE.
        command = (mavlink2.MAVLINK_MSG_ID_SET_MODE if self.personality is ARDUPILOT
                   else mavlink2.MAV_CMD_DO_SET_MODE)
        self._out.append(telemetry.command_ack(command, result, source(msg)))

    def _on_setpoint(self, msg: Message, now: float) -> None:
        if not self._for_me(msg.target_system, msg.target_component):
            return
        if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            update = setpoint_from_local(msg, self.body)
        else:
            update = setpoint_from_global(msg, self.placement.frame, self.placement.home)
        if update is None:  # unsupported frame
            return
        target, yaw = update
        self.setpoint_times.append(now)
        if target is not None and self.config.speedup != 1.0:
            s = self.config.speedup
            target = replace(target, vn=target.vn / s, ve=target.ve / s, vd=target.vd / s, an=target.an / s / s,
                             ae=target.ae / s / s)
        if self.personality is ARDUPILOT and self.behaviour is not Behaviour.FOLLOW:
            return  # ArduCopter uses setpoints only in GUIDED
        if target is not None:
            self.setpoint = target
            if self.personality is ARDUPILOT:
                # Position control from now on (mode_guided.cpp): the take-off is over, and on the
                # ground position control does nothing: a vehicle still spooling up stays there.
                self.takeoff_point = None
        if yaw is not None:
            self.body.yaw = yaw

    def _on_timesync(self, msg: Message, now: float) -> None:
        if msg.tc1 == 0:
            self._out.append(telemetry.timesync(round((now - self.boot_time) * 1e9), msg.ts1))

    def _on_ping(self, msg: Message, now: float) -> None:
        """PX4 (mavlink_receiver's handle_message_ping) answers a ping request, one addressed to
        system 0 component 0, with the same time_usec and seq addressed to the sender; MAVSDK
        sends one every few seconds to measure latency. The ArduCopter fake leaves it unanswered."""
        if self.personality is not ARDUPILOT and msg.target_system == 0 and msg.target_component == 0:
            self._out.append(telemetry.ping(msg.time_usec, msg.seq, source(msg)))

    def _on_request_data_stream(self, msg: Message, now: float) -> None:
        """ArduPilot's legacy stream rates (PX4 ignores the message)."""
        if self.personality is not ARDUPILOT or not self._for_me(msg.target_system, msg.target_component):
            return
        on = msg.start_stop and msg.req_message_rate > 0
        for msg_id in telemetry.DATA_STREAMS.get(msg.req_stream_id, ()):
            self.streams.set_interval(msg_id, 1e6 / msg.req_message_rate if on else -1, now)

    # --------------------------------------------------------------- commands
    def text(self, severity: int, text: str) -> None:
        self._out.append(telemetry.statustext(severity, text))

    def arming_problem(self, now: float) -> str:
        """Why arming would be refused now (the STATUSTEXT it sends), or "" when it may arm."""
        if problem := self.prearm_problem(now):
            return problem
        if self.behaviour in (Behaviour.RTL, Behaviour.LAND):
            return "Arm: Mode not armable"  # checked when arming, not among the pre-arm checks
        return ""

    def prearm_problem(self, now: float) -> str:
        """The pre-arm checks SYS_STATUS reports ("" when they pass)."""
        if not self.ready(now):
            return self.personality.text_not_ready
        if self.battery.percent < self.config.min_arm_battery_pct:
            return self.personality.text_low_battery
        return ""

    def disarm(self, now: float) -> None:
        self.armed = False
        self.takeoff_point = None
        self.setpoint = None
        self.landed_since = now

    def change_mode(self, base_mode: int, custom_mode: int, now: float) -> int:
        """SET_MODE's or DO_SET_MODE's answer (MAV_RESULT), switching if the autopilot would."""
        if not base_mode & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return UNSUPPORTED  # only custom modes are modelled
        name = self.personality.mode_name(custom_mode)
        if name is None:
            return self.personality.rejected
        if not self.ready(now) and self.personality.behaviour(name) is not Behaviour.LAND and (
                self.armed or self.personality is not ARDUPILOT):
            # Disarmed, ArduCopter checks nothing (set_mode's ignore_checks); armed, or PX4, a mode
            # that needs a position is refused without one.
            self.text(mavlink2.MAV_SEVERITY_WARNING, "Mode change failed: requires position")
            return self.personality.rejected
        if name == self.personality.follow_mode and self.personality is not ARDUPILOT and not self.streaming(now):
            self.text(mavlink2.MAV_SEVERITY_CRITICAL, "Switching to Offboard rejected: no setpoints")
            return self.personality.rejected
        if name == self.personality.takeoff_mode and not (self.armed and not self.airborne):
            return self.personality.rejected
        self.enter_mode(name, now)
        return ACCEPTED

    def enter_mode(self, name: str, now: float) -> None:
        if name == self.mode:
            return
        self.mode = name
        if self.personality is ARDUPILOT:
            self.setpoint = None  # GUIDED starts by holding where it is
        behaviour = self.personality.behaviour(name)
        if behaviour is Behaviour.TAKEOFF and self.takeoff_point is None:
            self.takeoff_point = Target(self.body.north, self.body.east, -self.params.setting(Setting.TAKEOFF_ALT))
        elif behaviour is not Behaviour.TAKEOFF:
            self.takeoff_point = None

    def streaming(self, now: float) -> bool:
        """PX4: is a setpoint stream on, its last setpoint within the offboard timeout?

        Like PX4 (COM_OF_LOSS_T), only the age of the last setpoint counts: a client that
        sends one setpoint and then asks for OFFBOARD (MAVSDK's documented sequence, its
        20 Hz stream starting with that setpoint) is let in; a stream slower than
        1 / COM_OF_LOSS_T leaves OFFBOARD.
        """
        times = self.setpoint_times
        return bool(times) and now - times[-1] <= self.params.setting(Setting.OFFBOARD_TIMEOUT)

    def step(self, now: float) -> list[Message]:
        """Advance to ``now``: flight rules, motion, battery; returns the telemetry due."""
        dt = max(0.0, now - self.last_step)
        self.last_step = now
        flight.advance(self, now, dt)
        out, self._out = self._out, []
        out.extend(self.params.stream())  # a parameter list under way, paced
        for msg_id in self.streams.due(now):
            msg = telemetry.REQUESTABLE[msg_id](self, now)
            if msg is not None:  # a position before the estimate: the autopilot sends none
                out.append(msg)
        return out


def _ignore(msg: Message, now: float) -> None:
    """A message type we receive and deliberately do nothing with."""
