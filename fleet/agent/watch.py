"""What an agent knows of its vehicle from one step boundary to the next: ready or not, lost or back.

The link says whether it can carry commands (:meth:`~fleet.vehicle.link.VehicleLink.problem`) and
what the vehicle last reported; the watch turns that into what the drone must do at a boundary:

* **lost**: the link closed or the vehicle went silent. The drone stays a member of the fleet, holds
  every cell its vehicle may be in (see :meth:`drona_gcs.stack.drone.DroneStack.vehicle_lost`) and
  takes no task; the link keeps opening itself again;
* **back**: a HEARTBEAT and a position newer than the loss. Where the vehicle is decides: landed (below
  the grid, where it meets no drone) or in the air in a cell its drone held, it rests there and carries
  on; anywhere else it stays out of service, for its operator to bring down;
* **readiness**: whether the vehicle can fly plans (its position estimate, GPS, battery, pre-arm checks).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from drona_gcs.geo import GeoFrame
from drona_gcs.workspace import Cell
from fleet.transport.wire import VehicleView
from fleet.vehicle.link import LandedState, Readiness, Telemetry, VehicleLink, not_ready, readiness


class Seen(enum.Enum):
    """What happened to the vehicle since the last boundary."""

    STEADY = "steady"  #: nothing new: answering, or still lost
    LOST = "lost"  #: it stopped answering
    BACK = "back"  #: it answers again and was located: :attr:`Verdict.cell`
    BACK_ELSEWHERE = "back_elsewhere"  #: it answers again, but not in a cell its drone held


@dataclass(frozen=True)
class Verdict:
    seen: Seen
    reason: str = ""  #: why it was lost, or where it came back
    cell: Cell | None = None  #: where it came back (a landed vehicle: the cell above it)
    landed: bool = False


class VehicleWatch:
    def __init__(self, link: VehicleLink, frame: GeoFrame) -> None:
        self.link, self.frame = link, frame
        self.lost_since: int | None = None  #: the step it was lost at (None: it answers)
        self.lost_at: float | None = None  #: the link clock time of its last HEARTBEAT before the loss
        self.last_seen: Cell | None = None  #: the last cell telemetry put it in while it answered
        self._seen_at: dict[str, float | None] = {}  #: the time of the position seen at each look

    @property
    def lost(self) -> bool:
        return self.lost_since is not None

    def readiness(self) -> Readiness:
        return readiness(self.link.telemetry(), lost=self.lost)

    def flown(self) -> Cell | None:
        """The grid cell telemetry puts the vehicle in; below the grid, the cell above it (a vehicle landing
        at its goal is there). None: in none, or it does not answer."""
        if self.lost:
            return None
        cell = self.recorded_cell()
        if cell is not None:
            self.last_seen = cell
        return cell

    def boundary(self, step: int, held: tuple[Cell, ...], placeable: bool = True) -> Verdict:
        """At boundary ``step``: what changed. ``held``: the cells its drone holds for it while lost;
        ``placeable``: whether its drone can be placed now (not while it coordinates: back is then
        reported at a later boundary)."""
        problem = self.link.problem()
        if problem is not None:
            if self.lost:
                return Verdict(Seen.STEADY)
            self.lost_since, self.lost_at = step, self.link.telemetry().heartbeat_at
            return Verdict(Seen.LOST, problem)
        if not self.lost or not placeable:
            return Verdict(Seen.STEADY)
        return self._located(held)

    def _located(self, held: tuple[Cell, ...]) -> Verdict:
        t = self.link.telemetry()
        position = t.position
        if position is None or (self.lost_at is not None and position.at <= self.lost_at):
            return Verdict(Seen.STEADY)  # answering, but not located yet
        self.lost_since = self.lost_at = None
        cell = self.frame.locate(position.ned).cell
        if _on_the_ground(t):
            column = self.frame.column_cell(position.ned)
            if column is not None:
                return Verdict(Seen.BACK, cell=column, landed=True)
        if cell is not None and cell in held:
            self.last_seen = cell
            return Verdict(Seen.BACK, cell=cell)
        where = f"in {list(cell)}" if cell is not None else "outside the grid"
        return Verdict(Seen.BACK_ELSEWHERE, f"its vehicle is back {where}, not in a cell held for it")

    def seen_cell(self, look: str = "boundary") -> Cell | None:
        """At a boundary (or another periodic ``look``), :meth:`recorded_cell` from a position reported
        since the previous one: None when none came (the vehicle lost, or silent), for a stale position
        is not a sighting."""
        position = self.link.last_position()
        fresh = position is not None and position.at != self._seen_at.get(look) and not self.lost
        self._seen_at[look] = None if position is None else position.at
        return self.recorded_cell() if fresh else None

    def recorded_cell(self) -> Cell | None:
        """Where telemetry puts the vehicle for the flight record (GeoFrame.recorded_cell; None: no
        position, or outside the grid)."""
        position = self.link.last_position()
        return None if position is None else self.frame.recorded_cell(position.ned)

    def misplaced(self, start: Cell) -> str | None:
        """The stack starts the drone at its start cell: its vehicle must be there (in that column), or its
        first plan would fly it from elsewhere across cells nobody reserved (None: it is there)."""
        here = self.recorded_cell()
        if here is not None and here[:2] == start[:2]:
            return None
        where = f"over cell {list(here)}" if here is not None else "outside the grid"
        return (f"its vehicle is {where}, not at its start cell {list(start)}: bring it there, or give the "
                "workspace its cell")

    def view(self) -> VehicleView:
        """What the drone's state says of its vehicle."""
        t, status = self.link.telemetry(), self.readiness()
        reason = (self.link.problem() or "no HEARTBEAT") if status is Readiness.LOST else not_ready(t) or ""
        return VehicleView(status=status.value, reason=reason, mode=t.mode, armed=t.armed,
                           landed=t.landed.name.lower(), height_m=t.height_m, gps_fix=t.gps_fix,
                           satellites=t.satellites, battery_v=t.battery_v)


def _on_the_ground(t: Telemetry) -> bool:
    return t.landed is LandedState.ON_GROUND or (not t.armed and (t.height_m or 0.0) < 0.5)


def joined(cells: tuple[Cell, ...], then: tuple[Cell, ...]) -> tuple[Cell, ...]:
    """Cells seen, then the cells seen next: a cell at both ends of the join was one visit."""
    return cells + (then[1:] if cells and then and cells[-1] == then[0] else then)
