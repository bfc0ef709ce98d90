"""The vehicle seam: :class:`FakeVehicle`, a :class:`~fleet.vehicle.link.VehicleLink` whose vehicle the
test plays (and so a :class:`~fleet.vehicle.link.SetpointSink` too).

In the style of httpx's ``MockTransport``: a real implementation of the port, small, that the test
programs. What the vehicle reports is plain state the test sets (where it is, armed, landed, its
battery, its position estimate, why its link is lost); what it is sent is recorded: setpoints with
the time they went out, commands by name. An ArduCopter refuses what ArduCopter refuses, with
MAV_RESULT_FAILED as it answers (Copter's ``do_user_takeoff`` and its arming checks): NAV_TAKEOFF
unless armed, in GUIDED and on the ground, and ARM without a position estimate in a mode that needs
one. A command named in ``refuse`` is rejected with that MAV_RESULT whatever the state, as the test
programs it (both as :class:`~drona_gcs.errors.VehicleCommandRejected`). It flies only as the test
says: with ``follow`` it is at each setpoint as soon as sent, and ``on_wait`` is what it does while
the link waits on it (by default nothing: the wait ends at once, met or not).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from drona_gcs.errors import VehicleCommandRejected, VehicleError
from drona_gcs.geo import GeoFrame, GeoPoint, Ned
from drona_gcs.workspace import Cell
from fleet.vehicle.link import Autopilot, LandedState, Position, Sweep, Telemetry, Trail

GPS_FIX_WITH_ESTIMATE = 6  #: GPS_FIX_TYPE_RTK_FIXED: what a vehicle with its position estimate reports
GPS_FIX_WITHOUT = 1  #: GPS_FIX_TYPE_NO_FIX
MAV_RESULT_FAILED = 4  #: ArduCopter's answer to a command it cannot carry out now
#: ArduCopter's modes that need a position estimate to arm in (``requires_GPS``).
POSITION_MODES = frozenset({"GUIDED", "LOITER", "AUTO", "RTL", "POSHOLD", "SMART_RTL", "BRAKE", "CIRCLE"})


class FakeVehicle:
    """ArduCopter in GUIDED, armed and in the air, 90 % charged; over ``cell`` of ``frame`` if given,
    reported at ``at`` on the link's ``clock``."""

    def __init__(self, frame: GeoFrame | None = None, cell: Cell | None = None, *, at: float = 1.0,
                 clock: Callable[[], float] = lambda: 0.0, follow: bool = False,
                 on_wait: Callable[[FakeVehicle], None] | None = None) -> None:
        self.frame, self.clock, self.follow, self.on_wait = frame, clock, follow, on_wait
        # What the vehicle reports (the test sets it; telemetry() reads it as it is).
        self.autopilot: Autopilot | None = Autopilot.ARDUPILOT
        self.armed = True
        self.mode: str | None = "GUIDED"
        self.landed = LandedState.IN_AIR
        self.height_m: float | None = 2.0  #: above home
        self.battery_pct: int | None = 90
        self.battery_v: float | None = 16.0
        self.satellites = 10
        self.parameters: dict[str, float] = {}  #: what it answers PARAM_REQUEST_READ with, and says it is set to
        self.estimate = True  #: its position estimate: without it, no position and no fix
        self.where: Ned | None = None if cell is None else self._ned(cell)  #: its position (None: none reported)
        self.at = at  #: the link clock time of its last report (HEARTBEAT and position)
        self.lost: str | None = None  #: why its link cannot carry commands (None: it can)
        self.trail = Trail()  #: every position it reported: placed by the test, or read
        # What it was sent.
        self.sent: list[tuple[float, Ned, Sweep | None]] = []  #: (clock time, target, sweep) of every setpoint
        self.commands: list[str] = []  #: every command asked for, by name, refused ones too
        self.refuse: dict[str, int] = {}  #: command name -> the MAV_RESULT it is rejected with

    def _ned(self, cell: Cell) -> Ned:
        assert self.frame is not None, "a vehicle placed by cell needs a frame"
        return self.frame.cell_to_ned(cell)

    # ------------------------------------------------------- the test's side
    def over(self, cell: Cell, at: float | None = None) -> None:
        """Over ``cell`` now, reported at ``at`` (None: at its last report's time)."""
        self.where = self._ned(cell)
        if at is not None:
            self.at = at
        self.trail.add(self.last_position())

    def come_down(self) -> None:
        """On the ground and disarmed (a failsafe, a pilot)."""
        self.armed, self.landed, self.height_m = False, LandedState.ON_GROUND, None

    # ------------------------------------------------------------ the port
    async def send_position_target(self, target: Ned, sweep: Sweep | None = None) -> None:
        self.sent.append((self.clock(), target, sweep))
        if self.follow:
            self.where, self.at = target, self.clock()

    def last_position(self) -> Position | None:
        position = Position(self.where, self.at) if self.estimate and self.where is not None else None
        self.trail.add(position)
        return position

    def positions_since(self, at: float) -> list[Position]:
        self.last_position()
        return self.trail.since(at)

    def last_global(self) -> GeoPoint | None:
        if not self.estimate or self.where is None or self.frame is None:
            return None
        return self.frame.ned_to_global(self.where)

    def telemetry(self) -> Telemetry:
        fix = GPS_FIX_WITH_ESTIMATE if self.estimate else GPS_FIX_WITHOUT
        return Telemetry(self.autopilot, self.armed, self.mode, self.last_position(), None, self.last_global(),
                         self.height_m, self.battery_pct, self.battery_v, fix, self.satellites, self.landed, self.at,
                         position_ok=self.estimate)

    def problem(self) -> str | None:
        return self.lost

    async def read_parameters(self, names: Sequence[str]) -> dict[str, float]:
        return {name: self.parameters[name] for name in names if name in self.parameters}

    async def set_parameter(self, name: str, value: float) -> float | None:
        self._command(f"PARAM_SET {name}")
        self.parameters[name] = value
        return value

    def parameters_heard(self) -> Mapping[str, float]:
        return self.parameters

    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float, what: str) -> Telemetry:
        if self.on_wait is not None:
            self.on_wait(self)
        telemetry = self.telemetry()
        if not predicate(telemetry):
            raise VehicleError(f"no {what} within {timeout:g} s")
        return telemetry

    async def connect(self, timeout: float = 10.0) -> None:
        self._command("CONNECT")

    async def wait_ready(self, timeout: float) -> None:
        await self.wait_until(lambda t: t.position is not None, timeout, "position estimate")

    async def arm(self) -> None:
        self._command("ARM", self._arm_refusal())
        self.armed = True

    async def disarm(self) -> None:
        self._command("DISARM")
        self.armed = False

    async def set_mode(self, mode: str) -> None:
        self._command("DO_SET_MODE")
        self.mode = mode

    async def follow_setpoints(self) -> None:
        self._command("FOLLOW_SETPOINTS")
        self.mode = "GUIDED" if self.autopilot is Autopilot.ARDUPILOT else "OFFBOARD"

    async def takeoff(self, altitude_m: float) -> None:
        self._command("NAV_TAKEOFF", self._takeoff_refusal())
        self.landed = LandedState.TAKEOFF

    async def land(self) -> None:
        self._command("LAND")
        self.landed = LandedState.LANDING

    async def close(self) -> None:
        self.lost = "closed"

    def _arm_refusal(self) -> str | None:
        """ArduCopter's text when it would not arm now (None: it would)."""
        if self.autopilot is Autopilot.ARDUPILOT and self.mode in POSITION_MODES and not self.estimate:
            return "Arm: Need Position Estimate"
        return None

    def _takeoff_refusal(self) -> str | None:
        """"" when ArduCopter would not take off now (it says nothing, answers FAILED); None when it would."""
        may = self.armed and self.mode == "GUIDED" and self.landed is LandedState.ON_GROUND
        return None if may or self.autopilot is not Autopilot.ARDUPILOT else ""

    def _command(self, name: str, refusal: str | None = None) -> None:
        """Record ``name``; refuse it as programmed in ``refuse``, else as ArduCopter would (``refusal``)."""
        self.commands.append(name)
        if self.lost is not None:
            raise VehicleError(f"{name}: {self.lost}")
        if name in self.refuse:
            raise VehicleCommandRejected(name, self.refuse[name])
        if refusal is not None:
            raise VehicleCommandRejected(name, MAV_RESULT_FAILED, refusal)
