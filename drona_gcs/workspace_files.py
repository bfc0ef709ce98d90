"""Workspace loaders: our YAML/JSON format, the original DRONA XML, MovingAI maps.

Every loader reports a bad file as :class:`WorkspaceError` naming the file,
the field and the problem. The YAML format is documented in README.md; a JSON
object with the same fields (``{"size": [...], "obstacles": [...]}``) is
accepted everywhere a workspace is.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

import yaml

from drona_gcs.errors import WorkspaceError
from drona_gcs.workspace import Cell, GeoOrigin, VehicleLimits, Workspace, box_cells

_CELL_LISTS = ("charging_stations", "pickups", "dropoffs", "parking")
_NUMBERS = {"cell_size_m": float, "tau_s": float, "beta_s": float, "lambda_s": float, "max_plan_length": int}
_KNOWN = {"name", "size", "obstacles", "drones", "geo_origin", "vehicle", *_CELL_LISTS, *_NUMBERS}
_GEO_FIELDS = {"lat", "lon", "alt_m", "layer0_alt_m", "layer_height_m"}
_VEHICLE_FIELDS = {f.name for f in fields(VehicleLimits)}


def load_workspace(path: str | Path) -> Workspace:
    """Load a workspace file: ``.yaml``/``.yml``/``.json``, DRONA ``.xml``, MovingAI ``.map``/``.grid``."""
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise WorkspaceError(f"cannot read the file: {exc.strerror or exc}", source=source) from exc
    except UnicodeDecodeError as exc:
        raise WorkspaceError(f"is not UTF-8 text: {exc.reason} at byte {exc.start}", source=source) from exc
    suffix = path.suffix.lower()
    if suffix == ".xml":
        return workspace_from_xml(text, source=source, name=path.parent.name or path.stem)
    if suffix == ".map":
        return workspace_from_movingai(text, source=source, name=path.stem)
    if suffix == ".grid":
        return workspace_from_grid(text, source=source, name=path.stem)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise WorkspaceError(f"not valid YAML/JSON: {exc}", source=source) from exc
    return workspace_from_mapping(data, source=source, name=path.stem)


def workspace_from_mapping(data: object, *, source: str = "", name: str = "workspace") -> Workspace:
    """Build a workspace from a parsed YAML/JSON object (see README for the fields)."""
    if not isinstance(data, Mapping):
        raise WorkspaceError(f"must be a mapping of fields, got {type(data).__name__}", source=source)
    unknown = sorted(set(data) - _KNOWN)
    if unknown:
        raise WorkspaceError(f"unknown field(s) {unknown}; known: {sorted(_KNOWN)}", source=source)
    if "size" not in data:
        raise WorkspaceError("is required", field="size", source=source)
    kwargs: dict[str, Any] = {"source": source, "name": str(data.get("name", name))}
    kwargs["size"] = _cell(data["size"], "size", source, positive=True)
    kwargs["obstacles"] = frozenset(_obstacles(data.get("obstacles") or [], source))
    for key in _CELL_LISTS:
        kwargs[key] = tuple(_cell_list(data.get(key) or [], key, source))
    kwargs["drones"] = _drones(data.get("drones") or {}, source)
    for key, kind in _NUMBERS.items():
        if data.get(key) is not None:
            kwargs[key] = _number(data[key], key, source, kind)
    if data.get("geo_origin") is not None:
        kwargs["geo"] = _geo(data["geo_origin"], source)
    if data.get("vehicle") is not None:
        kwargs["vehicle"] = VehicleLimits(**_numbers(data["vehicle"], "vehicle", _VEHICLE_FIELDS, source))
    return Workspace.build(**kwargs)


def workspace_from_xml(text: str, *, source: str = "", name: str = "workspace") -> Workspace:
    """Parse the original DRONA ``<configuration>`` XML.

    ``starts`` and ``ends`` are the mail pickup and drop-off points; robot
    ``id`` attributes become drone ids.
    """
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise WorkspaceError(f"not well-formed XML: {exc}", source=source) from exc
    if root.tag != "configuration":
        raise WorkspaceError(f"root element is <{root.tag}>, expected <configuration>", source=source)
    dim = root.find("dimension")
    if dim is None:
        raise WorkspaceError("is missing", field="dimension", source=source)
    drones: dict[str, Cell] = {}
    for i, robot in enumerate(root.iterfind("robots/robot")):
        start = robot.find("start")
        where = f"robots/robot[{i}]"
        if start is None:
            raise WorkspaceError("has no <start>", field=where, source=source)
        drone_id = robot.get("id", str(i))
        if drone_id in drones:
            raise WorkspaceError(f"drone id {drone_id!r} is used twice", field=where, source=source)
        drones[drone_id] = _xml_cell(start, f"{where}/start", source)

    def coords(section: str) -> tuple[Cell, ...]:
        return tuple(_xml_cell(c, f"{section}/coord[{i}]", source)
                     for i, c in enumerate(root.iterfind(f"{section}/coord")))

    return Workspace.build(
        size=_xml_cell(dim, "dimension", source, positive=True), obstacles=frozenset(coords("obstacles")),
        drones=drones, charging_stations=coords("charging_stations"), pickups=coords("starts"),
        dropoffs=coords("ends"), name=name, source=source)


def workspace_from_movingai(text: str, *, source: str = "", name: str = "map") -> Workspace:
    """A MovingAI ``.map`` (header lines, then rows; ``.``/``G``/``S`` free). Row 0 is the top (y = H-1)."""
    lines = text.splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == "map") + 1
    except StopIteration:
        raise WorkspaceError("no 'map' line ends the header", source=source) from None
    rows = [line.rstrip("\n") for line in lines[start:] if line.strip()]
    return _from_rows(rows, lambda ch: ch not in ".GS", source, name)


def workspace_from_grid(text: str, *, source: str = "", name: str = "grid") -> Workspace:
    """A grid file: lines H and W, then H rows of space-separated 0 (free) / 1 (blocked)."""
    lines = [line.split() for line in text.splitlines() if line.strip()]
    rows = ["".join(tokens) for tokens in lines[2:]]
    return _from_rows(rows, lambda ch: ch == "1", source, name)


def _from_rows(rows: list[str], blocked: Any, source: str, name: str) -> Workspace:
    if not rows:
        raise WorkspaceError("the map has no rows", source=source)
    height, width = len(rows), max(len(r) for r in rows)
    obstacles = {(x, height - 1 - r, 0) for r, row in enumerate(rows)
                 for x, ch in enumerate(row.ljust(width, "@")) if blocked(ch)}
    ws = Workspace(size=(width, height, 1), obstacles=frozenset(obstacles), name=name, source=source)
    # Pockets cut off from the main region cannot be used; fill them so the map validates.
    pockets = set(ws.free_cells) - ws.main_region
    return Workspace.build(size=(width, height, 1), obstacles=frozenset(obstacles | pockets),
                           name=name, source=source)


# ------------------------------------------------------------------ helpers
def _number(value: object, key: str, source: str, kind: type) -> Any:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and value != int(value)):
        raise WorkspaceError(f"must be {'an integer' if kind is int else 'a number'}, got {value!r}",
                             field=key, source=source)
    return kind(value)


def _cell(value: object, where: str, source: str, positive: bool = False) -> Cell:
    if (not isinstance(value, (list, tuple)) or len(value) != 3
            or any(isinstance(v, bool) or not isinstance(v, int) for v in value)):
        raise WorkspaceError(f"must be three integers [x, y, z], got {value!r}", field=where, source=source)
    if positive and any(v < 1 for v in value):
        raise WorkspaceError(f"must be three positive integers, got {list(value)}", field=where, source=source)
    return (value[0], value[1], value[2])


def _cell_list(value: object, where: str, source: str) -> list[Cell]:
    if not isinstance(value, list):
        raise WorkspaceError(f"must be a list of cells, got {value!r}", field=where, source=source)
    return [_cell(v, f"{where}[{i}]", source) for i, v in enumerate(value)]


def _obstacles(value: object, source: str) -> set[Cell]:
    """Obstacle cells, given as ``[x, y, z]`` or ``{box: [[x0,y0,z0], [x1,y1,z1]]}`` (inclusive)."""
    if not isinstance(value, list):
        raise WorkspaceError(f"must be a list, got {value!r}", field="obstacles", source=source)
    cells: set[Cell] = set()
    for i, item in enumerate(value):
        where = f"obstacles[{i}]"
        if isinstance(item, Mapping):
            box = item.get("box")
            if set(item) != {"box"} or not isinstance(box, list) or len(box) != 2:
                raise WorkspaceError("a box must be {box: [[x0,y0,z0], [x1,y1,z1]]}", field=where, source=source)
            lo, hi = _cell(box[0], where, source), _cell(box[1], where, source)
            cells.update(box_cells(lo, hi))
        else:
            cells.add(_cell(item, where, source))
    return cells


def _drones(value: object, source: str) -> dict[str, Cell]:
    if not isinstance(value, Mapping):
        raise WorkspaceError(f"must map drone ids to start cells, got {value!r}", field="drones", source=source)
    return {str(k): _cell(v, f"drones.{k}", source) for k, v in value.items()}


def _geo(value: object, source: str) -> GeoOrigin:
    numbers = _numbers(value, "geo_origin", _GEO_FIELDS, source)
    if not -90 <= numbers.get("lat", 0.0) <= 90 or not -180 <= numbers.get("lon", 0.0) <= 180:
        raise WorkspaceError("lat must be within [-90, 90] and lon within [-180, 180]",
                             field="geo_origin", source=source)
    return GeoOrigin(**numbers)


def _numbers(value: object, section: str, known: set[str], source: str) -> dict[str, float]:
    """A mapping of numbers, each named in ``known``."""
    if not isinstance(value, Mapping):
        raise WorkspaceError(f"must be a mapping, got {value!r}", field=section, source=source)
    unknown = sorted(set(value) - known)
    if unknown:
        raise WorkspaceError(f"unknown field(s) {unknown}; known: {sorted(known)}", field=section, source=source)
    return {str(k): _number(v, f"{section}.{k}", source, float) for k, v in value.items()}


def _xml_cell(elem: ET.Element, where: str, source: str, positive: bool = False) -> Cell:
    try:  # a missing z is layer 0 of a cell, or one layer of a dimension
        cell = (int(elem.get("x", "")), int(elem.get("y", "")), int(elem.get("z", "1" if positive else "0")))
    except ValueError:
        raise WorkspaceError(f"needs integer x, y, z attributes, got {dict(elem.attrib)}",
                             field=where, source=source) from None
    return _cell(list(cell), where, source, positive)
