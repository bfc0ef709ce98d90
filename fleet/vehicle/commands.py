"""The commands both link backends carry out alike: arm, disarm, a mode change, take-off and landing.

Each is sent as :mod:`fleet.vehicle.policy` says for the autopilot, awaited until acknowledged (a
refusal raises :class:`~drona_gcs.errors.VehicleCommandRejected`), then confirmed from the
HEARTBEATs after its ACK by the session's :meth:`~fleet.vehicle.session.MavlinkSession.verdict`:
an autopilot may ACK what it does not do. A backend says only how a command travels
(:meth:`ConfirmedCommands._order`) and how it waits for the verdict (:meth:`_await_verdict`): the
abstract methods of :class:`ConfirmedCommands`.
"""

from __future__ import annotations

import abc
from collections.abc import Awaitable, Callable, Mapping, Sequence

from fleet.vehicle.link import Autopilot, Telemetry
from fleet.vehicle.modes import mode_command
from fleet.vehicle.policy import (
    CUSTOM_MODE_ENABLED,
    Command,
    Expectation,
    Timeouts,
    arming,
    landing,
    policy_of,
    switching,
    takeoff_params,
    takeoff_started,
)
from fleet.vehicle.session import MavlinkSession, Verdict

PARAM_TRIES = 3


class ConfirmedCommands(abc.ABC):
    """The command half of a :class:`~fleet.vehicle.link.VehicleLink`, over a backend's hooks."""

    session: MavlinkSession
    timeouts: Timeouts
    clock: Callable[[], float]
    parameters: dict[str, float]  #: the last PARAM_VALUE of each name heard (the backend keeps it)

    @property
    def sysid(self) -> int | None:
        return self.session.sysid

    @property
    def autopilot(self) -> Autopilot | None:
        return self.session.autopilot

    @property
    def armed(self) -> bool:
        return self.session.armed

    @property
    def mode(self) -> str | None:
        return self.session.mode

    @property
    def heartbeats(self) -> int:
        return self.session.heartbeats

    def problem(self) -> str | None:
        """Why the link cannot carry commands now: closed, lost, or the vehicle silent (None: it can)."""
        return self.session.problem()

    def _check_alive(self) -> None:
        self.session.check_alive()

    def parameters_heard(self) -> Mapping[str, float]:
        return self.parameters

    async def read_parameters(self, names: Sequence[str]) -> dict[str, float]:
        """Each parameter of ``names`` the vehicle answers PARAM_REQUEST_READ for (asked up to
        ``PARAM_TRIES`` times each: a request or its answer may be lost), with its value."""
        values: dict[str, float] = {}
        for name in names:
            for _ in range(PARAM_TRIES):
                if (value := await self._read_parameter(name)) is not None:
                    values[name] = value
                    break
        return values

    async def set_parameter(self, name: str, value: float) -> float | None:
        """PARAM_SET ``name`` to ``value`` (up to ``PARAM_TRIES`` times): the value the vehicle answers it
        holds (None: it never answered)."""
        for _ in range(PARAM_TRIES):
            if (held := await self._set_parameter(name, value)) is not None:
                return held
        return None

    # ------------------------------------------------------------ the backend's part
    @abc.abstractmethod
    async def _read_parameter(self, name: str) -> float | None:
        """PARAM_REQUEST_READ for ``name``: its PARAM_VALUE's value, None if none came in time."""

    @abc.abstractmethod
    async def _set_parameter(self, name: str, value: float) -> float | None:
        """PARAM_SET of ``name`` to ``value``: the answering PARAM_VALUE's value, None if none came in time."""

    @abc.abstractmethod
    async def _order(self, label: str, command: Command, params: tuple[float, ...]) -> int:
        """Send ``command`` and await its ACK (VehicleCommandRejected unless ACCEPTED); returns the
        HEARTBEATs heard by then."""

    @abc.abstractmethod
    async def _await_verdict(self, expect: Expectation, seen: int) -> Verdict:
        """Wait (bounded) until the session's verdict on ``expect`` after ``seen`` HEARTBEATs is in."""

    @abc.abstractmethod
    def _stop_setpoints(self) -> None:
        """Send no more setpoints (a landing)."""

    @abc.abstractmethod
    def telemetry(self) -> Telemetry:
        """The vehicle's latest telemetry."""

    @abc.abstractmethod
    async def wait_until(self, predicate: Callable[[Telemetry], bool], timeout: float, what: str) -> Telemetry:
        """The telemetry once ``predicate`` holds; VehicleError after ``timeout`` (waiting for ``what``)."""

    # ------------------------------------------------------------ the commands
    async def arm(self) -> None:
        await self._confirmed(Command.COMPONENT_ARM_DISARM, (1.0,), arming(True))

    async def disarm(self) -> None:
        await self._confirmed(Command.COMPONENT_ARM_DISARM, (0.0,), arming(False))

    async def set_mode(self, mode: str) -> None:
        """Switch to ``mode`` (ArduCopter or PX4 name) with DO_SET_MODE; confirmed from the next HEARTBEAT."""
        _, params = mode_command(self.autopilot, mode, f"vehicle {self.sysid}")
        await self.session.mode_doubt.around(
            self._confirmed(Command.DO_SET_MODE, (float(CUSTOM_MODE_ENABLED), *params), switching(mode)))

    async def takeoff(self, altitude_m: float) -> None:
        """Climb to ``altitude_m`` above home (ArduPilot: in GUIDED, switched to first); returns once climbing."""
        params = takeoff_params(self.telemetry(), altitude_m, f"vehicle {self.sysid}")
        mode = policy_of(self.autopilot).takeoff_mode
        if mode is not None and self.mode != mode:
            await self.set_mode(mode)
        await self._order(Command.NAV_TAKEOFF.name, Command.NAV_TAKEOFF, params)
        await self.wait_until(takeoff_started, self.timeouts.takeoff_start_s, "the takeoff to start")

    async def land(self) -> None:
        """Land where it is (no more setpoints); confirmed from the next HEARTBEAT's mode."""
        self._stop_setpoints()
        await self.session.mode_doubt.around(self._confirmed(Command.NAV_LAND, (), landing(self.autopilot)))

    async def _confirmed(self, command: Command, params: tuple[float, ...], expect: Expectation) -> None:
        """Send, await the ACK, then want ``expect`` from the HEARTBEATs after it."""
        await self._carried_out(lambda: self._order(expect.label, command, params), expect)

    async def _carried_out(self, order: Callable[[], Awaitable[int]], expect: Expectation) -> None:
        """Give the ``order`` (it returns the HEARTBEATs heard by its answer), then want ``expect`` from
        the HEARTBEATs after it: a refusal raises VehicleCommandRejected."""
        since = self.clock()
        seen = await order()
        if await self._await_verdict(expect, seen) is not Verdict.CONFIRMED:
            raise self.session.refusal(expect, since)
