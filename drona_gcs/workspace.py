"""The workspace: a 3-D occupancy grid with obstacles, chargers and drone starts.

Cells are ``(x, y, z)`` integer triples, ``0 <= x < nx`` and so on. Each cell
also has a unique integer id (the paper's Fig. 1 numbers the blocks):
``id = x + nx * (y + ny * z)``, so ids run along x first, then y, then z.

A :class:`Workspace` is immutable and validated when built: every cell is in
bounds, nothing that must be free sits on an obstacle, no two drones share a
start, and every drone start, charging station and task point lies in the one
connected free region (a start walled off from the rest could never be served).
Loaders for our YAML format and the original DRONA XML live in
:mod:`drona_gcs.workspace_files`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Collection, Iterable, Mapping
from dataclasses import asdict, dataclass, field, replace
from fractions import Fraction
from functools import cached_property

from drona_gcs.errors import WorkspaceError

Cell = tuple[int, int, int]

#: Default altitude (m above the origin's altitude) of the centre of layer 0.
DEFAULT_LAYER0_ALT_M = 10.0


@dataclass(frozen=True)
class VehicleLimits:
    """How fast a vehicle can get going, as its autopilot is set; the defaults are ArduCopter's
    (WPNAV_SPEED, WPNAV_ACCEL, PSC_JERK_XY; WPNAV_SPEED_UP, WPNAV_SPEED_DN, WPNAV_ACCEL_Z, PSC_JERK_Z)."""

    speed_m_s: float = 10.0  #: horizontal
    accel_m_s2: float = 2.5
    jerk_m_s3: float = 5.0
    climb_m_s: float = 2.5
    descent_m_s: float = 1.5
    accel_z_m_s2: float = 1.0
    jerk_z_m_s3: float = 5.0

    def sped_up(self, factor: float) -> VehicleLimits:
        """The same vehicle, its seconds ``factor`` times shorter (a simulation at ``factor`` times real time,
        seen from the wall clock)."""
        return VehicleLimits(self.speed_m_s * factor, self.accel_m_s2 * factor**2, self.jerk_m_s3 * factor**3,
                             self.climb_m_s * factor, self.descent_m_s * factor, self.accel_z_m_s2 * factor**2,
                             self.jerk_z_m_s3 * factor**3)


ARDUCOPTER = VehicleLimits()


def time_to_cover(distance_m: float, speed: float, accel: float, jerk: float) -> float:
    """Seconds a vehicle at rest needs to cover ``distance_m``: at ``accel`` up to ``speed``, its
    acceleration ramped up at ``jerk`` first (which delays it by at most accel / (2 jerk))."""
    ramp = accel / (2 * jerk)
    if distance_m <= speed * speed / (2 * accel):
        return ramp + math.sqrt(2 * distance_m / accel)
    return ramp + speed / accel + (distance_m - speed * speed / (2 * accel)) / speed


def shaping_lag_s(accel: float, jerk: float) -> float:
    """How far behind a position setpoint ArduCopter's shaped target runs: the inverse of the
    shaping's position gain, jerk / (2 accel) (``AP_Math/control.cpp``)."""
    return 2 * accel / jerk


def tracking_lateness_s(cell_size_m: float, layer_height_m: float, layers: int,
                        limits: VehicleLimits = ARDUCOPTER) -> float:
    """Lambda's default: how late after a boundary a vehicle enters its step's cell.

    The autopilot shapes each position setpoint into a target that trails it (see
    :func:`shaping_lag_s`), and a vehicle at rest at a cell's centre (after a wait, or where it turns
    back) crosses half a cell from rest before it is in the next one. On its way it is swept across
    its cells with the velocity fed forward (:mod:`fleet.setpoint_loop`), and is later by less.
    Vertical moves count only when the grid has layers, at the slower vertical limits.
    """
    across = shaping_lag_s(limits.accel_m_s2, limits.jerk_m_s3) + time_to_cover(
        cell_size_m / 2, limits.speed_m_s, limits.accel_m_s2, limits.jerk_m_s3)
    if layers < 2:
        return across
    up_down = shaping_lag_s(limits.accel_z_m_s2, limits.jerk_z_m_s3) + time_to_cover(
        layer_height_m / 2, min(limits.climb_m_s, limits.descent_m_s), limits.accel_z_m_s2, limits.jerk_z_m_s3)
    return max(across, up_down)


@dataclass(frozen=True)
class GeoOrigin:
    """Where the grid sits on Earth.

    ``lat``/``lon`` are the WGS84 position of the grid's corner cell (0, 0, *)
    outer corner, ``alt_m`` the ground altitude (AMSL) there. Layer ``z`` flies
    at ``alt_m + layer0_alt_m + z * layer_height_m``.
    """

    lat: float = 0.0
    lon: float = 0.0
    alt_m: float = 0.0
    layer0_alt_m: float = DEFAULT_LAYER0_ALT_M
    layer_height_m: float | None = None  # None: the cell size


@dataclass(frozen=True)
class Workspace:
    """A validated DRONA workspace. Build it with :meth:`build` to get checks."""

    size: tuple[int, int, int]
    obstacles: frozenset[Cell] = frozenset()
    charging_stations: tuple[Cell, ...] = ()
    drones: Mapping[str, Cell] = field(default_factory=dict)
    cell_size_m: float = 1.0
    tau_s: float = 1.0
    beta_s: float = 0.0
    lambda_s: float | None = None  #: None: derived (see :func:`tracking_lateness_s`)
    vehicle: VehicleLimits = ARDUCOPTER  #: what the vehicles can fly: lambda's default derives from it
    max_plan_length: int | None = None
    geo: GeoOrigin = field(default_factory=GeoOrigin)
    pickups: tuple[Cell, ...] = ()
    dropoffs: tuple[Cell, ...] = ()
    parking: tuple[Cell, ...] = ()
    name: str = "workspace"
    source: str = ""

    # ------------------------------------------------------------------ build
    @classmethod
    def build(cls, **kwargs: object) -> Workspace:
        """Build and validate; raises :class:`WorkspaceError` naming the field."""
        ws = cls(**kwargs)  # type: ignore[arg-type]
        ws.validate()
        return ws

    def validate(self) -> None:
        src = self.source
        if len(self.size) != 3 or any(not isinstance(n, int) or n < 1 for n in self.size):
            raise WorkspaceError(f"must be three positive integers, got {list(self.size)}",
                                 field="size", source=src)
        _positive(self.cell_size_m, "cell_size_m", src)
        _positive(self.tau_s, "tau_s", src)
        if not (self.beta_s >= 0 and math.isfinite(self.beta_s)):
            raise WorkspaceError(f"must be a finite number >= 0, got {self.beta_s}", field="beta_s", source=src)
        if self.lambda_s is not None and not (self.lambda_s >= 0 and math.isfinite(self.lambda_s)):
            raise WorkspaceError(f"must be a finite number >= 0, got {self.lambda_s}", field="lambda_s", source=src)
        for name, value in asdict(self.vehicle).items():
            _positive(value, f"vehicle.{name}", src)
        if self.max_plan_length is not None and self.max_plan_length < 1:
            raise WorkspaceError(f"must be >= 1, got {self.max_plan_length}",
                                 field="max_plan_length", source=src)
        if self.geo.layer_height_m is not None:
            _positive(self.geo.layer_height_m, "geo_origin.layer_height_m", src)
        for cell in self.obstacles:
            self._check_bounds(cell, "obstacles")
        self._check_free_cells()
        self._check_connected()

    def _check_bounds(self, cell: Cell, where: str) -> None:
        if not self.in_bounds(cell):
            raise WorkspaceError(f"cell {list(cell)} is outside the grid {list(self.size)}",
                                 field=where, source=self.source)

    def _named_free_cells(self) -> Iterable[tuple[str, Cell]]:
        for drone, cell in self.drones.items():
            yield f"drones.{drone}", cell
        for group in ("charging_stations", "pickups", "dropoffs", "parking"):
            for i, cell in enumerate(getattr(self, group)):
                yield f"{group}[{i}]", cell

    def _check_free_cells(self) -> None:
        owner: dict[Cell, str] = {}
        for where, cell in self._named_free_cells():
            self._check_bounds(cell, where)
            if cell in self.obstacles:
                raise WorkspaceError(f"cell {list(cell)} is on an obstacle",
                                     field=where, source=self.source)
            if where.startswith("drones.") and cell in owner:
                raise WorkspaceError(f"cell {list(cell)} is also the start of {owner[cell]}",
                                     field=where, source=self.source)
            owner.setdefault(cell, where)
        stations = self.charging_stations
        if len(set(stations)) != len(stations):
            raise WorkspaceError("a charging station is listed twice",
                                 field="charging_stations", source=self.source)

    def _check_connected(self) -> None:
        region = self.main_region
        for where, cell in self._named_free_cells():
            if cell not in region:
                raise WorkspaceError(
                    f"cell {list(cell)} is walled off from the main free region",
                    field=where, source=self.source)
        # Drones rest on parking cells for good: together they must not cut the free region.
        cut = self.cells_cut_off_by(self.parking)
        if cut:
            where = next(f"parking[{i}]" for i, c in enumerate(self.parking) if c in self.neighbour_set(cut))
            raise WorkspaceError(f"drones parked there would wall off {len(cut)} free cell(s), "
                                 f"such as {list(min(cut))}", field=where, source=self.source)

    def cells_cut_off_by(self, resting: Iterable[Cell]) -> set[Cell]:
        """Free cells that drones resting on ``resting`` would cut off from the rest."""
        resting = set(resting)
        rest = [c for c in self.main_region if c not in resting]
        if not resting or not rest:
            return set()
        found = {rest[0]}
        queue = deque(found)
        while queue:
            for nxt in self.neighbours(queue.popleft()):
                if nxt not in found and nxt not in resting:
                    found.add(nxt)
                    queue.append(nxt)
        return set(rest) - found

    def neighbour_set(self, cells: Iterable[Cell]) -> set[Cell]:
        return {n for c in cells for n in self.neighbours(c)}

    # -------------------------------------------------------------- geometry
    @property
    def nx(self) -> int:
        return self.size[0]

    @property
    def ny(self) -> int:
        return self.size[1]

    @property
    def nz(self) -> int:
        return self.size[2]

    @property
    def num_cells(self) -> int:
        return self.nx * self.ny * self.nz

    @property
    def lateness_s(self) -> float:
        """Lambda: how late a vehicle may enter its step's cell, set or derived from the geometry."""
        if self.lambda_s is not None:
            return self.lambda_s
        return round(tracking_lateness_s(self.cell_size_m, self.layer_height_m, self.nz, self.vehicle), 3)

    @property
    def delta(self) -> int:
        """Delta = ceil((beta + lambda) / tau): the window in steps that covers clock skew (Theorem
        3.1) and a vehicle's lateness; a drone may be in a step's cell from beta before the step
        until beta + lambda after it."""
        # Add and divide the decimal values, not their binary approximations: 0.3 / 0.1 is
        # 2.9999999999999996 in floats, but exactly 3, and a tiny beta still gives 1.
        spread = Fraction(str(self.beta_s)) + Fraction(str(self.lateness_s))
        return max(0, math.ceil(spread / Fraction(str(self.tau_s))))

    @property
    def plan_length_limit(self) -> int:
        """L_max: the configured one, or by default the number of cells."""
        return self.max_plan_length if self.max_plan_length is not None else self.num_cells

    @property
    def layer_height_m(self) -> float:
        return self.geo.layer_height_m if self.geo.layer_height_m is not None else self.cell_size_m

    def in_bounds(self, cell: Cell) -> bool:
        x, y, z = cell
        return 0 <= x < self.nx and 0 <= y < self.ny and 0 <= z < self.nz

    def is_free(self, cell: Cell) -> bool:
        return self.in_bounds(cell) and cell not in self.obstacles

    def cell_id(self, cell: Cell) -> int:
        x, y, z = cell
        return x + self.nx * (y + self.ny * z)

    def cell_of_id(self, cell_id: int) -> Cell:
        if not 0 <= cell_id < self.num_cells:
            raise WorkspaceError(f"cell id {cell_id} is outside 0..{self.num_cells - 1}",
                                 source=self.source)
        xy, z = cell_id % (self.nx * self.ny), cell_id // (self.nx * self.ny)
        return (xy % self.nx, xy // self.nx, z)

    def neighbours(self, cell: Cell) -> Iterable[Cell]:
        """Free cells one move away (6-connected in 3-D, 4-connected when nz == 1)."""
        found = self._adjacent.get(cell)
        return found if found is not None else self._free_around(cell)

    @cached_property
    def _adjacent(self) -> dict[Cell, tuple[Cell, ...]]:
        """Each free cell's neighbours, worked out once: every search of the task planner walks them."""
        return {cell: self._free_around(cell) for cell in self.free_cells}

    def _free_around(self, cell: Cell) -> tuple[Cell, ...]:
        x, y, z = cell
        return tuple(nxt for nxt in ((x + 1, y, z), (x - 1, y, z), (x, y + 1, z), (x, y - 1, z), (x, y, z + 1),
                                     (x, y, z - 1)) if self.is_free(nxt))

    @cached_property
    def free_cells(self) -> tuple[Cell, ...]:
        return tuple((x, y, z) for z in range(self.nz) for y in range(self.ny)
                     for x in range(self.nx) if (x, y, z) not in self.obstacles)

    @cached_property
    def main_region(self) -> frozenset[Cell]:
        """The largest connected set of free cells (ties: the one met first)."""
        seen: set[Cell] = set()
        best: set[Cell] = set()
        for cell in self.free_cells:
            if cell in seen:
                continue
            component = self.reachable_from(cell)
            seen |= component
            if len(component) > len(best):
                best = component
        return frozenset(best)

    def distances_from(self, start: Cell, walls: Collection[Cell] = frozenset()) -> dict[Cell, int]:
        """Steps of the shortest obstacle-free path from ``start`` to every reachable cell, around
        ``walls`` too."""
        found = {start: 0}
        queue = deque([start])
        while queue:
            cell = queue.popleft()
            for nxt in self.neighbours(cell):
                if nxt not in found and nxt not in walls:
                    found[nxt] = found[cell] + 1
                    queue.append(nxt)
        return found

    def shortest_way(self, start: Cell, goal: Cell, walls: Collection[Cell] = frozenset()) -> tuple[Cell, ...]:
        """The cells of a shortest path from ``start`` (left out) to ``goal`` around obstacles and
        ``walls``; empty if there is none."""
        back = self.distances_from(goal, walls)
        if start not in back:
            return ()
        way, cell = [], start
        while cell != goal:
            cell = min(c for c in self.neighbours(cell) if back.get(c) == back[cell] - 1)
            way.append(cell)
        return tuple(way)

    def reachable_from(self, start: Cell) -> set[Cell]:
        return set(self.distances_from(start))

    def with_drones(self, drones: Mapping[str, Cell]) -> Workspace:
        """A copy with another set of drones, validated."""
        return _replace_validated(self, drones=dict(drones))


def _replace_validated(ws: Workspace, **changes: object) -> Workspace:
    new = replace(ws, **changes)  # type: ignore[arg-type]
    new.validate()
    return new


def _positive(value: float, name: str, source: str) -> None:
    if not (isinstance(value, (int, float)) and value > 0 and math.isfinite(value)):
        raise WorkspaceError(f"must be a positive number, got {value!r}", field=name, source=source)


def box_cells(lo: Cell, hi: Cell) -> list[Cell]:
    """Every cell of the inclusive box between corners ``lo`` and ``hi``."""
    return [(x, y, z)
            for x in range(min(lo[0], hi[0]), max(lo[0], hi[0]) + 1)
            for y in range(min(lo[1], hi[1]), max(lo[1], hi[1]) + 1)
            for z in range(min(lo[2], hi[2]), max(lo[2], hi[2]) + 1)]
