"""Take-off and landing: keep the vehicle in the air exactly when the stack says it flies.

The stack reasons in cells; a landed drone sits under its cell (the grid
starts at layer 0's altitude), so taking off or landing in its own column
crosses no other drone's cell. The agent states what it wants with
:meth:`VehicleSupervisor.want_airborne`; :meth:`run` carries it out in order,
one command sequence at a time, and reports failures as alarms rather than
dying: a vehicle that refuses to arm must not take the agent down with it.
A take-off is over when the autopilot says so (see :mod:`fleet.vehicle.policy`):
ArduCopter takes no setpoint until then. While the vehicle is lost nothing is
tried (:meth:`VehicleSupervisor.pause`).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable

from drona_gcs.errors import VehicleCommandRejected, VehicleError
from drona_gcs.geo import Ned
from fleet.clock import cancel_all
from fleet.vehicle.link import Autopilot, LandedState, Telemetry, VehicleLink
from fleet.vehicle.policy import DEFAULT_TIMEOUTS, Timeouts, in_air

log = logging.getLogger(__name__)


SETTLED_M_S = 0.3  #: ground speed under which a vehicle is over where it is sent to land


class VehicleSupervisor:
    def __init__(self, name: str, link: VehicleLink, takeoff_alt_m: float, on_alarm: Callable[[str | None], None],
                 target: Callable[[], Ned], arrival_m: float, timeouts: Timeouts = DEFAULT_TIMEOUTS) -> None:
        self.name, self.link, self.takeoff_alt_m = name, link, takeoff_alt_m
        self.target, self.arrival_m = target, arrival_m
        self.on_alarm, self.command_timeout_s = on_alarm, timeouts.command_s
        self.paused = False  #: the vehicle is lost: no command is tried
        self.wanted = False
        self.airborne = False  #: the last sequence that completed left it in the air
        self._changed = asyncio.Event()
        self._stopping = False
        self._final = False  #: landing for good: wishes no longer change
        self.reached = asyncio.Event()  #: set while the vehicle is where it is wanted (air or ground)
        self.reached.set()

    def land_for_good(self) -> None:
        """Shutting down: land, and let no later wish take off again."""
        self.want_airborne(False)
        self._final = True

    def want_airborne(self, wanted: bool) -> None:
        if self._final:
            return
        if wanted != self.wanted:
            self.wanted = wanted
            self.reached.clear()
            self._changed.set()

    @property
    def settled(self) -> bool:
        """In the air and meant to be: its position is worth judging against the plan."""
        return self.airborne and self.wanted

    def grounded_by_itself(self) -> bool:
        """Meant to fly and taken up, yet down: a failsafe, a pilot, or a landing the autopilot finished
        after we gave it up. The stack flies a drone that is not there: worth an alarm. It is not
        taken up again from here: it may be down in another cell than the plan's."""
        t = self.link.telemetry()
        return self.settled and (not t.armed or t.landed is LandedState.ON_GROUND)

    def stop(self) -> None:
        self._stopping = True
        self._changed.set()

    def pause(self, paused: bool, airborne: bool | None = None) -> None:
        """Try nothing while ``paused`` (the vehicle is lost). Back, ``airborne`` says where it was found:
        what it is now, whatever the last sequence left it in."""
        self.paused = paused
        if airborne is not None:
            self.airborne = airborne
            self.reached.clear()
        self._changed.set()

    async def run(self) -> None:
        """Until :meth:`stop`: bring the vehicle to what is wanted, each time the wish changes."""
        while not self._stopping:
            if self.wanted != self.airborne and not self.paused:
                await self._carry_out(self.wanted)
                continue
            self._changed.clear()
            await self._changed.wait()

    async def _carry_out(self, airborne: bool) -> None:
        try:
            if airborne or self._final:
                await asyncio.wait_for(self._launch() if airborne else self._land(), self.command_timeout_s)
            elif not await self._land_unless_wanted_back():
                self.airborne = False  # somewhere between: the launch takes it from wherever it is
                return
        except (VehicleError, TimeoutError) as exc:
            what = "take off" if airborne else "land"
            why = str(exc) or f"not done within {self.command_timeout_s:g} s"  # asyncio's timeout says nothing
            self.on_alarm(f"vehicle: cannot {what}: {why}")
            log.warning("%s: cannot %s: %s", self.name, what, why)
            await asyncio.sleep(1.0)  # a retry pause: the next attempt must not flood the autopilot
            return
        self.airborne = airborne
        self.on_alarm(None)
        if self.airborne == self.wanted:
            self.reached.set()

    async def _land_unless_wanted_back(self) -> bool:
        """Land; False if a new plan wants the drone in the air before touchdown.

        The plan's lead time covers a take-off from the ground, not the rest of a descent
        first: a drone that finished coming down before climbing again would be late for its
        plan's first steps. So it stops descending at once (the launch switches LAND back to
        following setpoints; an airborne vehicle needs no take-off).
        """
        landing = asyncio.create_task(asyncio.wait_for(self._land(), self.command_timeout_s))
        wanted_back = asyncio.create_task(self._until_wanted())
        try:
            await asyncio.wait([landing, wanted_back], return_when=asyncio.FIRST_COMPLETED)
            if not landing.done():
                return False
            landing.result()  # its error, if it failed
            return True
        finally:
            await cancel_all([landing, wanted_back])

    async def _until_wanted(self) -> None:
        while not self.wanted:
            self._changed.clear()
            await self._changed.wait()

    def _over_target(self, telemetry: Telemetry) -> bool:
        """Over the landing cell and all but still: LAND brakes to a stop from where it starts, and a
        vehicle still moving would come down further on, in a cell that may be another's."""
        position, velocity = telemetry.position, telemetry.velocity
        if position is None or velocity is None or math.hypot(velocity.north, velocity.east) > SETTLED_M_S:
            return False
        here, there = position.ned, self.target()
        return math.hypot(here.north - there.north, here.east - there.east) <= self.arrival_m

    async def _launch(self) -> None:
        link = self.link
        await link.follow_setpoints()
        if not link.telemetry().armed:
            await link.arm()
        t = link.telemetry()
        # On the ground yet over half a metre above home (ground higher than home, a barometer that
        # drifted), ArduCopter still needs its take-off: the same rule as the climb's end.
        flying = _off_the_ground(t)
        if t.autopilot is Autopilot.ARDUPILOT and not flying:  # PX4 climbs to the streamed setpoint by itself
            try:
                await link.takeoff(self.takeoff_alt_m)
            except VehicleCommandRejected:
                # ArduCopter refuses a take-off in the air: a landing called back just above the ground,
                # before telemetry (landed state at a few Hz) showed it back in the air. In GUIDED it
                # climbs to the setpoints as it is (as it does once a take-off is under way). On the
                # ground, or not saying, the refusal is a real one.
                if link.telemetry().landed in (LandedState.ON_GROUND, LandedState.UNDEFINED):
                    raise
        # Done when the autopilot says so: ArduCopter reports TAKEOFF until it is up, and only then
        # takes setpoints (fleet.vehicle.policy).
        await link.wait_until(in_air, self.command_timeout_s, "the climb")

    async def _land(self) -> None:
        link = self.link
        t = link.telemetry()
        if not t.armed and t.landed is LandedState.ON_GROUND:
            return  # already down (by itself): there is no landing left to place
        # Land only once over the cell: LAND comes down where the vehicle is, and one still
        # catching up with its last setpoint would come down in the cell it was leaving.
        await link.wait_until(self._over_target, self.command_timeout_s, "the arrival over the landing cell")
        await link.land()
        await link.wait_until(lambda t: t.landed is LandedState.ON_GROUND or not t.armed,
                              self.command_timeout_s, "the touchdown")
        if link.telemetry().armed:  # disarmed on the ground: a charger only charges a disarmed vehicle
            await link.disarm()


def _off_the_ground(t: Telemetry) -> bool:
    """Climbing or up, by the landed state; by the height where the autopilot does not report one.
    Both where it does: the landed state comes at a lower rate than positions, and a vehicle half a
    metre up may not have said it left the ground yet. Called airborne on that last report, it would
    look grounded by itself (:meth:`VehicleSupervisor.grounded_by_itself`) at the next step boundary."""
    return t.landed is LandedState.IN_AIR or ((t.height_m or 0.0) > 0.5 and t.landed is not LandedState.ON_GROUND)
