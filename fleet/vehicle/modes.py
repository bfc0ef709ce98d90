"""Flight modes of ArduCopter and PX4 as they travel in HEARTBEAT.custom_mode, shared by both backends."""

from __future__ import annotations

from collections.abc import Awaitable

from drona_gcs.errors import VehicleError
from fleet.vehicle.link import Autopilot

ARDUCOPTER_MODES = {"STABILIZE": 0, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9,
                    "POSHOLD": 16, "BRAKE": 17}
#: PX4 mode name -> (main mode, sub mode); custom_mode = main << 16 | sub << 24.
PX4_MODES = {"MANUAL": (1, 0), "ALTCTL": (2, 0), "POSCTL": (3, 0), "AUTO.TAKEOFF": (4, 2), "AUTO.LOITER": (4, 3),
             "AUTO.MISSION": (4, 4), "AUTO.RTL": (4, 5), "AUTO.LAND": (4, 6), "OFFBOARD": (6, 0)}


class ModeDoubt:
    """Whether a mode change was sent and not confirmed (given up on, or failed): until one is
    confirmed, the last HEARTBEAT's mode may be about to change. A LAND abandoned before its
    confirmation still lands the vehicle, so a switch back must not trust the mode it reads."""

    def __init__(self) -> None:
        self.in_doubt = False

    async def around(self, confirmed: Awaitable[None]) -> None:
        """Await a mode change's confirmation; in doubt until it completes."""
        self.in_doubt = True
        await confirmed
        self.in_doubt = False


def px4_custom(main: int, sub: int) -> int:
    return (main << 16) | (sub << 24)


def mode_command(autopilot: Autopilot | None, mode: str, who: str) -> tuple[int, tuple[float, ...]]:
    """The custom_mode a switch to ``mode`` should produce, and the DO_SET_MODE params after the flag."""
    if autopilot is Autopilot.ARDUPILOT and mode in ARDUCOPTER_MODES:
        return ARDUCOPTER_MODES[mode], (float(ARDUCOPTER_MODES[mode]),)
    if autopilot is Autopilot.PX4 and mode in PX4_MODES:
        main, sub = PX4_MODES[mode]
        return px4_custom(main, sub), (float(main), float(sub))
    raise VehicleError(f"{who} ({autopilot}): unknown mode {mode!r}")


def mode_name(autopilot: Autopilot | None, custom_mode: int | None) -> str | None:
    """The name of a HEARTBEAT's custom_mode for this autopilot."""
    if custom_mode is None:
        return None
    names: dict[str, int] = {}
    if autopilot is Autopilot.ARDUPILOT:
        names = ARDUCOPTER_MODES
    elif autopilot is Autopilot.PX4:
        names = {n: px4_custom(*ms) for n, ms in PX4_MODES.items()}
    return next((n for n, c in names.items() if c == custom_mode), f"custom_mode={custom_mode}")
