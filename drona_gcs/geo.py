"""Geo-referencing: grid cells to local NED positions and WGS84 coordinates, and back.

Axes
----
The local frame is the vehicle convention, NED, with its origin at the
grid's corner (the outer corner of cell ``(0, 0, *)``) on the ground, at the
origin's altitude ``alt_m``:

* grid **x** grows to the **east** (NED ``E``),
* grid **y** grows to the **north** (NED ``N``),
* grid **z** is the layer: its centre flies ``layer0_alt_m + z * layer_height_m``
  above the origin, so NED ``D = -(that)``.

A cell's centre is therefore ``N = (y + 0.5) * cell``, ``E = (x + 0.5) * cell``.
Latitude and longitude come from the local tangent plane at the origin with
the WGS84 radii of curvature there: exact to centimetres over a few
kilometres, which is the scale of a delivery grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drona_gcs.errors import WorkspaceError
from drona_gcs.workspace import Cell, Workspace

_A = 6378137.0  # WGS84 semi-major axis (m)
_E2 = 6.69437999014e-3  # WGS84 first eccentricity squared


@dataclass(frozen=True)
class Ned:
    north: float
    east: float
    down: float


@dataclass(frozen=True)
class GeoPoint:
    lat: float
    lon: float
    alt_m: float  #: AMSL


@dataclass(frozen=True)
class CellFix:
    """Where a position falls: its cell (None outside the grid) and the distance to that cell's centre."""

    cell: Cell | None
    error_m: float


def _radii(lat_deg: float) -> tuple[float, float]:
    """Meridional and prime-vertical radii of curvature at ``lat_deg``."""
    s = math.sin(math.radians(lat_deg))
    w = math.sqrt(1 - _E2 * s * s)
    return _A * (1 - _E2) / w**3, _A / w


class GeoFrame:
    """Conversions for one workspace."""

    def __init__(self, workspace: Workspace) -> None:
        self.ws = workspace
        geo = workspace.geo
        self.origin = GeoPoint(geo.lat, geo.lon, geo.alt_m)
        self._meridional, self._normal = _radii(geo.lat)
        self._cos_lat = math.cos(math.radians(geo.lat))

    # ---------------------------------------------------------- cell -> position
    def layer_height_m(self, z: int) -> float:
        """Height of layer ``z``'s centre above the origin's ground."""
        return self.ws.geo.layer0_alt_m + z * self.ws.layer_height_m

    def cell_to_ned(self, cell: Cell) -> Ned:
        x, y, z = cell
        size = self.ws.cell_size_m
        return Ned((y + 0.5) * size, (x + 0.5) * size, -self.layer_height_m(z))

    def ned_to_global(self, ned: Ned) -> GeoPoint:
        lat = self.origin.lat + math.degrees(ned.north / self._meridional)
        lon = self.origin.lon + math.degrees(ned.east / (self._normal * self._cos_lat))
        return GeoPoint(lat, lon, self.origin.alt_m - ned.down)

    def cell_to_global(self, cell: Cell) -> GeoPoint:
        return self.ned_to_global(self.cell_to_ned(cell))

    # ---------------------------------------------------------- position -> cell
    def global_to_ned(self, point: GeoPoint) -> Ned:
        north = math.radians(point.lat - self.origin.lat) * self._meridional
        east = math.radians(point.lon - self.origin.lon) * self._normal * self._cos_lat
        return Ned(north, east, self.origin.alt_m - point.alt_m)

    def locate(self, ned: Ned) -> CellFix:
        """The cell a local position is in, and how far it is from that cell's centre."""
        size, layer = self.ws.cell_size_m, self.ws.layer_height_m
        x = math.floor(ned.east / size)
        y = math.floor(ned.north / size)
        z = round((-ned.down - self.ws.geo.layer0_alt_m) / layer)
        cell = (x, y, z)
        centre = self.cell_to_ned(cell)
        error = math.dist((ned.north, ned.east, ned.down), (centre.north, centre.east, centre.down))
        return CellFix(cell if self.ws.in_bounds(cell) else None, error)

    def column_cell(self, ned: Ned) -> Cell | None:
        """The lowest cell over a position (None outside the grid, or on an obstacle): a vehicle on the
        ground, taking off or landing there meets no other drone, as in that cell."""
        size, ws = self.ws.cell_size_m, self.ws
        cell = (math.floor(ned.east / size), math.floor(ned.north / size), 0)
        return cell if ws.in_bounds(cell) and cell not in ws.obstacles else None

    def recorded_cell(self, ned: Ned) -> Cell | None:
        """The cell a flight record puts a position in: the one it is in, or below the grid (landed,
        climbing) the cell over it (None: outside the grid)."""
        cell = self.locate(ned).cell
        if cell is not None:
            return cell
        return self.column_cell(ned) if -ned.down < self.ws.geo.layer0_alt_m else None

    def locate_global(self, point: GeoPoint) -> CellFix:
        return self.locate(self.global_to_ned(point))


def check_speed(workspace: Workspace, max_speed_m_s: float) -> None:
    """Refuse a workspace whose drones would need to fly a cell per tau faster than they can."""
    if max_speed_m_s <= 0:
        raise WorkspaceError(f"the vehicle's maximum speed must be > 0, got {max_speed_m_s}")
    needed = max(workspace.cell_size_m, workspace.layer_height_m) / workspace.tau_s
    if needed > max_speed_m_s:
        raise WorkspaceError(
            f"one cell per tau needs {needed:.2f} m/s but the vehicle flies at most {max_speed_m_s:.2f} m/s: "
            "use smaller cells or a longer tau", field="tau_s", source=workspace.source)


def check_flyable(workspace: Workspace) -> None:
    """Refuse a workspace whose vehicles, as its ``vehicle`` limits say, cannot fly the executor's sweeps:
    a cell per tau, and from rest at a cell's centre to its face (half a cell) in a tau, sped up evenly
    (and so slowed down): ``cell / tau`` and ``cell / tau**2``. Vertically too, when the grid has layers."""
    limits, tau = workspace.vehicle, workspace.tau_s
    cell, layer = workspace.cell_size_m, workspace.layer_height_m
    needs = [("speed_m_s", cell / tau, "m/s", cell), ("accel_m_s2", cell / tau**2, "m/s²", cell)]
    if workspace.size[2] > 1:
        needs += [("climb_m_s", layer / tau, "m/s", layer), ("descent_m_s", layer / tau, "m/s", layer),
                  ("accel_z_m_s2", layer / tau**2, "m/s²", layer)]
    for name, needed, unit, across in needs:
        has = getattr(limits, name)
        if has < needed:
            raise WorkspaceError(
                f"{has:g} {unit} cannot fly {across:g} m a tau ({tau:g} s), which needs {needed:.2f} {unit}: "
                "give quicker vehicles (and set their autopilots so), smaller cells or a longer tau",
                field=f"vehicle.{name}", source=workspace.source)
