"""The workspace model and its loaders: real files, cell ids, delta, our YAML/JSON format, bad files."""

from __future__ import annotations

import dataclasses
import itertools
import json
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest
import yaml

from drona_gcs.errors import WorkspaceError
from drona_gcs.workspace import Cell, GeoOrigin, Workspace
from drona_gcs.workspace_files import load_workspace

# ------------------------------------------------------------ shared data
WriteFile = Callable[[str, str | bytes], Path]  #: the ``write_file`` fixture (tests/conftest.py)


def _xml_cell(elem: ET.Element | None) -> Cell:
    assert elem is not None
    return (int(elem.attrib["x"]), int(elem.attrib["y"]), int(elem.attrib["z"]))


def test_data_folder_holds_the_drona_workspaces(data_dir: Path) -> None:
    # Guards the parametrized tests below against a glob that silently matches less.
    names = {p.parent.name for p in data_dir.glob("drona-workspaces/*/Workspace.xml")}
    assert {"16_4", "16_8", "32_32", "64_64", "Delta", "Exp1"} <= names


def test_drona_workspace_loads(drona_xml: Path) -> None:
    root = ET.parse(drona_xml).getroot()
    ws = load_workspace(drona_xml)

    assert ws.size == _xml_cell(root.find("dimension"))
    robots = root.findall("robots/robot")
    assert len(ws.drones) == len(robots) > 0
    assert ws.drones == {r.attrib["id"]: _xml_cell(r.find("start")) for r in robots}
    obstacle_coords = [_xml_cell(c) for c in root.iterfind("obstacles/coord")]
    assert len(ws.obstacles) == len(set(obstacle_coords))
    assert ws.obstacles == frozenset(obstacle_coords)
    assert ws.pickups == tuple(_xml_cell(c) for c in root.iterfind("starts/coord"))
    assert ws.dropoffs == tuple(_xml_cell(c) for c in root.iterfind("ends/coord"))
    assert ws.charging_stations == tuple(_xml_cell(c) for c in root.iterfind("charging_stations/coord"))

    starts = list(ws.drones.values())
    assert not set(starts) & ws.obstacles, "a drone starts on an obstacle"
    assert len(set(starts)) == len(starts), "two drones share a start"
    assert all(ws.in_bounds(c) and c in ws.main_region for c in starts)
    assert ws.name == drona_xml.parent.name
    assert ws.source == str(drona_xml)


def _movingai_rows(path: Path) -> tuple[int, int, list[str], str, str]:
    """(width, height, rows, free characters, blocked characters), read independently of the loader."""
    lines = path.read_text(encoding="utf-8").splitlines()
    if path.suffix == ".grid":
        height, width = int(lines[0]), int(lines[1])
        return width, height, ["".join(line.split()) for line in lines[2:] if line.strip()], "0", "1"
    header = dict(line.split() for line in lines[:lines.index("map")] if line.strip())
    rows = [line for line in lines[lines.index("map") + 1:] if line.strip()]
    return int(header["width"]), int(header["height"]), rows, ".", "@T"


def test_movingai_map_loads(movingai_map: Path) -> None:
    width, height, rows, free_chars, blocked_chars = _movingai_rows(movingai_map)
    ws = load_workspace(movingai_map)

    assert ws.size == (width, height, 1)
    assert len(rows) == height and {len(r) for r in rows} == {width}
    assert set("".join(rows)) == set(free_chars + blocked_chars)
    # Row 0 is the top of the map (y = height - 1); every blocked character is an obstacle.
    blocked = {(x, height - 1 - r, 0) for r, row in enumerate(rows) for x, ch in enumerate(row)
               if ch in blocked_chars}
    assert blocked <= ws.obstacles
    assert len(blocked) > 0.05 * width * height
    # Only pockets cut off from the main region were added; what is left free is one region.
    assert set(ws.free_cells) == ws.main_region
    assert len(ws.main_region) > 0.3 * width * height


# ------------------------------------------------------------ cell ids, delta
@pytest.mark.parametrize("size", [(5, 4, 1), (1, 7, 1), (4, 3, 2), (3, 5, 4)])
def test_cell_ids_are_unique_dense_and_invertible(size: Cell) -> None:
    ws = Workspace(size=size)
    cells = list(itertools.product(range(size[0]), range(size[1]), range(size[2])))
    ids = [ws.cell_id(c) for c in cells]
    assert sorted(ids) == list(range(ws.num_cells)) == list(range(len(cells)))
    assert all(ws.cell_of_id(ws.cell_id(c)) == c for c in cells)
    assert all(ws.cell_id(ws.cell_of_id(i)) == i for i in range(ws.num_cells))


def test_cell_ids_run_along_x_then_y_then_z() -> None:
    ws = Workspace(size=(4, 3, 2))
    assert [ws.cell_id(c) for c in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (3, 2, 1)]] == [0, 1, 4, 12, 23]


@pytest.mark.parametrize("bad_id", [-1, 24, 1000])
def test_cell_of_id_out_of_range(bad_id: int) -> None:
    with pytest.raises(WorkspaceError, match=f"cell id {bad_id} is outside 0..23"):
        Workspace(size=(4, 3, 2)).cell_of_id(bad_id)


@pytest.mark.parametrize(("beta", "tau", "delta"), [
    (0.0, 0.1, 0),
    (0, 1.0, 0),
    (0.3, 0.1, 3),  # 0.3 / 0.1 == 2.9999999999999996
    (0.1 + 0.2, 0.1, 4),  # beta is 0.30000000000000004 > 0.3: round up, the safe side
    (1e-10, 1.0, 1),  # any positive skew needs a window
    (0.2, 0.1, 2),
    (0.6, 0.2, 3),  # 2.9999999999999996
    (0.7, 0.1, 7),  # 6.999999999999999
    (0.25, 0.1, 3),
    (0.01, 1.0, 1),
    (1.0, 1.0, 1),
    (1.5, 1.0, 2),
    (2.0, 0.5, 4),
])
def test_delta_is_ceil_beta_over_tau_for_a_vehicle_never_late(beta: float, tau: float, delta: int) -> None:
    assert Workspace.build(size=(2, 2, 1), beta_s=beta, tau_s=tau, lambda_s=0.0).delta == delta


@pytest.mark.parametrize(("beta", "lam", "tau", "delta"), [
    (0.2, 1.882, 0.5, 5),  # the coordination bench's grid
    (0.05, 2.345, 1.0, 3),  # the demo campus
    (0.1, 0.2, 0.1, 3),  # 0.30000000000000004 / 0.1 in floats
    (0.0, 0.5, 0.5, 1),
])
def test_delta_widens_by_the_vehicles_lateness(beta: float, lam: float, tau: float, delta: int) -> None:
    assert Workspace.build(size=(2, 2, 1), beta_s=beta, tau_s=tau, lambda_s=lam).delta == delta


@pytest.mark.parametrize(("cell", "layer", "layers", "lateness"), [
    (1.0, 1.0, 1, 1.0 + 0.25 + 0.632),  # shaping lag, jerk ramp, half a metre at 2.5 m/s²
    (3.0, 3.0, 1, 1.0 + 0.25 + 1.095),
    (0.1, 1.0, 2, 0.4 + 0.1 + 1.0),  # half a metre up at 1 m/s² takes longer than 5 cm across
    (100.0, 1.0, 1, 1.0 + 0.25 + 4.0 + 3.0),  # 20 m to reach 10 m/s, then 30 m at it
])
def test_lambda_defaults_to_the_shaping_lag_and_half_a_cell_from_rest(cell: float, layer: float, layers: int,
                                                                      lateness: float) -> None:
    ws = Workspace.build(size=(2, 2, layers), cell_size_m=cell, geo=GeoOrigin(layer_height_m=layer))
    assert ws.lateness_s == pytest.approx(lateness, abs=1e-3)


def test_a_set_lambda_wins_and_a_bad_one_is_named() -> None:
    assert Workspace.build(size=(2, 2, 1), lambda_s=0.0).lateness_s == 0.0
    with pytest.raises(WorkspaceError, match="lambda_s"):
        Workspace.build(size=(2, 2, 1), lambda_s=-1.0)


# ------------------------------------------------------------ our YAML/JSON format
EXAMPLE_YAML = """\
name: depot-east
size: [6, 5, 2]
cell_size_m: 2.5
tau_s: 0.5
beta_s: 0.3
lambda_s: 0.7
max_plan_length: 40
geo_origin:
  lat: 52.2297
  lon: 21.0122
  alt_m: 110.0
  layer0_alt_m: 12.0
  layer_height_m: 3.0
obstacles:
  - [2, 2, 0]
  - [5, 4, 1]
  - box: [[3, 1, 1], [3, 0, 0]]   # corners in any order: x = 3, y 0..1, z 0..1
charging_stations:
  - [0, 0, 0]
  - [5, 0, 1]
drones:
  d1: [0, 0, 0]   # parked on a charging station
  d2: [1, 0, 0]
  7: [0, 4, 1]    # an integer id becomes the string "7"
pickups: [[0, 4, 0]]
dropoffs: [[5, 4, 0], [4, 2, 1]]
parking: [[1, 4, 0], [2, 4, 0]]
"""


def _cells(cs: Iterable[Cell]) -> list[list[int]]:
    return [list(c) for c in cs]


def _as_mapping(ws: Workspace) -> dict[str, object]:
    """The workspace written back in our file format (obstacles as plain cells)."""
    return {
        "name": ws.name, "size": list(ws.size), "cell_size_m": ws.cell_size_m, "tau_s": ws.tau_s,
        "beta_s": ws.beta_s, "lambda_s": ws.lambda_s, "max_plan_length": ws.max_plan_length,
        "geo_origin": dataclasses.asdict(ws.geo),
        "obstacles": _cells(sorted(ws.obstacles)), "charging_stations": _cells(ws.charging_stations),
        "drones": {k: list(v) for k, v in ws.drones.items()}, "pickups": _cells(ws.pickups),
        "dropoffs": _cells(ws.dropoffs), "parking": _cells(ws.parking),
    }


def test_yaml_example_loads_every_field(write_file: WriteFile) -> None:
    path = write_file("depot.yaml", EXAMPLE_YAML)
    ws = load_workspace(path)

    assert ws.name == "depot-east"
    assert ws.source == str(path)
    assert ws.size == (6, 5, 2)
    assert (ws.cell_size_m, ws.tau_s, ws.beta_s, ws.lambda_s, ws.max_plan_length) == (2.5, 0.5, 0.3, 0.7, 40)
    assert ws.geo == GeoOrigin(lat=52.2297, lon=21.0122, alt_m=110.0, layer0_alt_m=12.0, layer_height_m=3.0)
    assert ws.layer_height_m == 3.0
    assert ws.obstacles == {(2, 2, 0), (5, 4, 1), (3, 0, 0), (3, 1, 0), (3, 0, 1), (3, 1, 1)}
    assert ws.charging_stations == ((0, 0, 0), (5, 0, 1))
    assert ws.drones == {"d1": (0, 0, 0), "d2": (1, 0, 0), "7": (0, 4, 1)}
    assert ws.pickups == ((0, 4, 0),)
    assert ws.dropoffs == ((5, 4, 0), (4, 2, 1))
    assert ws.parking == ((1, 4, 0), (2, 4, 0))
    assert ws.delta == 2  # ceil((0.3 + 0.7) / 0.5)
    assert ws.plan_length_limit == 40
    assert len(ws.free_cells) == 6 * 5 * 2 - 6 == len(ws.main_region)


def test_yaml_round_trips(write_file: WriteFile) -> None:
    first = load_workspace(write_file("depot.yaml", EXAMPLE_YAML))
    again = load_workspace(write_file("again.yaml", yaml.safe_dump(_as_mapping(first), sort_keys=False)))
    assert dataclasses.replace(again, source=first.source) == first


@pytest.mark.parametrize("suffix", [".json", ".yml"])
def test_json_with_the_same_content_loads_identically(write_file: WriteFile, suffix: str) -> None:
    from_yaml = load_workspace(write_file("depot.yaml", EXAMPLE_YAML))
    path = write_file(f"depot{suffix}", json.dumps(yaml.safe_load(EXAMPLE_YAML), indent=2))
    loaded = load_workspace(path)
    assert loaded.source == str(path)
    assert dataclasses.replace(loaded, source=from_yaml.source) == from_yaml


def test_minimal_yaml_takes_the_defaults(write_file: WriteFile) -> None:
    ws = load_workspace(write_file("tiny.yaml", "size: [3, 2, 1]\n"))
    assert ws == Workspace(size=(3, 2, 1), name="tiny", source=ws.source)
    assert (ws.tau_s, ws.beta_s, ws.delta, ws.plan_length_limit, ws.layer_height_m) == (1.0, 0.0, 2, 6, 1.0)


# ------------------------------------------------------------ bad files
def _robots(*robots: str) -> str:
    return "<robots>" + "".join(robots) + "</robots>"


def _xml(*parts: str, dimension: str = '<dimension x="4" y="4" z="1"/>') -> str:
    return "<?xml version='1.0'?>\n<configuration>" + dimension + "".join(parts) + "</configuration>"


ROBOT_A = '<robot id="a"><start x="0" y="0" z="0"/></robot>'
GRID = "size: [4, 4, 1]\n"

# (test id, file name, content, the field named, phrases of the problem). A field of "" is a
# whole-file problem: the phrases then carry what locates it (a line, the bad key, the root tag).
BAD_FILES = [
    ("obstacle-out-of-bounds", "ws.yaml", GRID + "obstacles: [[1, 1, 0], [4, 0, 0]]\n",
     "obstacles", ["cell [4, 0, 0] is outside the grid [4, 4, 1]"]),
    ("box-out-of-bounds", "ws.yaml", GRID + "obstacles: [{box: [[2, 2, 0], [2, 5, 0]]}]\n",
     "obstacles", ["is outside the grid [4, 4, 1]"]),
    ("drone-out-of-bounds", "ws.yaml", GRID + "drones: {d1: [0, 0, 0], d2: [0, 0, 1]}\n",
     "drones.d2", ["cell [0, 0, 1] is outside the grid"]),
    ("drone-negative-coord", "ws.yaml", GRID + "drones: {d1: [-1, 0, 0]}\n",
     "drones.d1", ["cell [-1, 0, 0] is outside the grid"]),
    ("station-out-of-bounds", "ws.yaml", GRID + "charging_stations: [[0, 0, 0], [2, 4, 0]]\n",
     "charging_stations[1]", ["cell [2, 4, 0] is outside the grid"]),
    ("pickup-out-of-bounds", "ws.yaml", GRID + "pickups: [[9, 9, 9]]\n",
     "pickups[0]", ["is outside the grid"]),
    ("start-on-obstacle", "ws.yaml", GRID + "obstacles: [[1, 1, 0]]\ndrones: {d1: [1, 1, 0]}\n",
     "drones.d1", ["cell [1, 1, 0] is on an obstacle"]),
    ("start-inside-box", "ws.yaml", GRID + "obstacles: [{box: [[0, 0, 0], [1, 1, 0]]}]\ndrones: {d1: [1, 0, 0]}\n",
     "drones.d1", ["cell [1, 0, 0] is on an obstacle"]),
    ("station-on-obstacle", "ws.yaml", GRID + "obstacles: [[3, 3, 0]]\ncharging_stations: [[3, 3, 0]]\n",
     "charging_stations[0]", ["is on an obstacle"]),
    ("two-drones-one-cell", "ws.yaml", GRID + "drones: {d1: [2, 2, 0], d2: [2, 2, 0]}\n",
     "drones.d2", ["cell [2, 2, 0] is also the start of drones.d1"]),
    ("station-listed-twice", "ws.yaml", GRID + "charging_stations: [[0, 0, 0], [0, 0, 0]]\n",
     "charging_stations", ["listed twice"]),
    ("tau-zero", "ws.yaml", GRID + "tau_s: 0\n", "tau_s", ["must be a positive number, got 0"]),
    ("tau-negative", "ws.yaml", GRID + "tau_s: -0.5\n", "tau_s", ["must be a positive number, got -0.5"]),
    ("tau-nan", "ws.yaml", GRID + "tau_s: .nan\n", "tau_s", ["must be a positive number, got nan"]),
    ("tau-not-a-number", "ws.yaml", GRID + "tau_s: fast\n", "tau_s", ["must be a number, got 'fast'"]),
    ("beta-negative", "ws.yaml", GRID + "beta_s: -0.1\n", "beta_s", [">= 0, got -0.1"]),
    ("lambda-negative", "ws.yaml", GRID + "lambda_s: -0.5\n", "lambda_s", [">= 0, got -0.5"]),
    ("beta-infinite", "ws.yaml", GRID + "beta_s: .inf\n", "beta_s", [">= 0, got inf"]),
    ("beta-nan", "ws.yaml", GRID + "beta_s: .nan\n", "beta_s", [">= 0, got nan"]),
    ("plan-length-zero", "ws.yaml", GRID + "max_plan_length: 0\n", "max_plan_length", ["must be >= 1"]),
    ("cell-size-zero", "ws.yaml", GRID + "cell_size_m: 0\n", "cell_size_m", ["must be a positive number"]),
    ("size-missing", "ws.yaml", "drones: {d1: [0, 0, 0]}\n", "size", ["is required"]),
    ("size-two-numbers", "ws.yaml", "size: [4, 4]\n", "size", ["must be three integers", "[4, 4]"]),
    ("size-four-numbers", "ws.yaml", "size: [4, 4, 1, 1]\n", "size", ["must be three integers"]),
    ("size-zero", "ws.yaml", "size: [4, 0, 1]\n", "size", ["must be three positive integers, got [4, 0, 1]"]),
    ("size-negative", "ws.yaml", "size: [4, 4, -2]\n", "size", ["must be three positive integers"]),
    ("size-float", "ws.yaml", "size: [4, 4.5, 1]\n", "size", ["must be three integers", "4.5"]),
    ("size-bool", "ws.yaml", "size: [4, true, 1]\n", "size", ["must be three integers", "True"]),
    ("size-string", "ws.yaml", "size: 4x4x1\n", "size", ["must be three integers", "'4x4x1'"]),
    ("unknown-field", "ws.yaml", GRID + "colour: red\n", "", ["unknown field(s) ['colour']"]),
    ("box-three-corners", "ws.yaml", GRID + "obstacles: [[0, 0, 0], {box: [[1, 1, 0], [2, 2, 0], [3, 3, 0]]}]\n",
     "obstacles[1]", ["a box must be {box: [[x0,y0,z0], [x1,y1,z1]]}"]),
    ("box-one-corner", "ws.yaml", GRID + "obstacles: [{box: [[1, 1, 0]]}]\n", "obstacles[0]", ["a box must be"]),
    ("box-not-a-list", "ws.yaml", GRID + "obstacles: [{box: 3}]\n", "obstacles[0]", ["a box must be"]),
    ("box-extra-key", "ws.yaml", GRID + "obstacles: [{box: [[1, 1, 0], [2, 2, 0]], height: 3}]\n",
     "obstacles[0]", ["a box must be"]),
    ("box-2d-corners", "ws.yaml", GRID + "obstacles: [{box: [[1, 1], [2, 2]]}]\n",
     "obstacles[0]", ["must be three integers [x, y, z], got [1, 1]"]),
    ("drone-walled-off", "ws.yaml",
     "size: [4, 4, 2]\nobstacles: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\ndrones: {d0: [3, 3, 1], d1: [0, 0, 0]}\n",
     "drones.d1", ["cell [0, 0, 0] is walled off from the main free region"]),
    ("station-walled-off", "ws.yaml",
     "size: [5, 5, 1]\nobstacles: [[3, 4, 0], [4, 3, 0]]\ncharging_stations: [[0, 0, 0], [4, 4, 0]]\n",
     "charging_stations[1]", ["cell [4, 4, 0] is walled off"]),
    ("dropoff-walled-off", "ws.yaml",
     "size: [5, 5, 1]\nobstacles: [{box: [[1, 0, 0], [1, 4, 0]]}]\ndropoffs: [[0, 2, 0]]\n",
     "dropoffs[0]", ["cell [0, 2, 0] is walled off"]),
    ("malformed-yaml", "ws.yaml", "size: [4, 4, 1]\ndrones: {d1: [0, 0, 0]\ntau_s: 1\n",
     "", ["not valid YAML/JSON", "line 2"]),
    ("malformed-json", "ws.json", '{"size": [4, 4, 1],\n "drones": {"d1": [0, 0, 0]}\n', "", ["not valid YAML/JSON"]),
    ("yaml-not-a-mapping", "ws.yaml", "- [4, 4, 1]\n", "", ["must be a mapping of fields, got list"]),
    ("empty-yaml", "ws.yaml", "", "", ["must be a mapping of fields, got NoneType"]),
    ("not-utf8", "ws.yaml", b"size: [4, 4, 1]\nname: \xff\xfe\n", "", ["not UTF-8"]),
    ("drone-non-integer", "ws.yaml", GRID + "drones: {d1: [0, 1.5, 0]}\n",
     "drones.d1", ["must be three integers [x, y, z], got [0, 1.5, 0]"]),
    ("obstacle-strings", "ws.yaml", GRID + "obstacles: [['1', '1', '0']]\n",
     "obstacles[0]", ["must be three integers"]),
    ("drones-not-a-mapping", "ws.yaml", GRID + "drones: [[0, 0, 0]]\n", "drones", ["must map drone ids"]),
    ("stations-not-a-list", "ws.yaml", GRID + "charging_stations: 3\n", "charging_stations", ["must be a list"]),
    ("geo-unknown-key", "ws.yaml", GRID + "geo_origin: {lat: 52.0, lon: 21.0, height: 3}\n",
     "geo_origin", ["unknown field(s) ['height']"]),
    ("geo-lat-out-of-range", "ws.yaml", GRID + "geo_origin: {lat: 91.0, lon: 21.0}\n",
     "geo_origin", ["lat must be within [-90, 90]"]),
    ("geo-lat-negative", "ws.yaml", GRID + "geo_origin: {lat: -90.5}\n", "geo_origin", ["lat must be within"]),
    ("geo-lon-out-of-range", "ws.yaml", GRID + "geo_origin: {lat: 52.0, lon: 181}\n",
     "geo_origin", ["lon within [-180, 180]"]),
    ("geo-lat-string", "ws.yaml", GRID + "geo_origin: {lat: '52.1N'}\n", "geo_origin.lat", ["must be a number"]),
    ("geo-not-a-mapping", "ws.yaml", GRID + "geo_origin: [52, 21]\n", "geo_origin", ["must be a mapping"]),
    ("geo-layer-height-zero", "ws.yaml", GRID + "geo_origin: {layer_height_m: 0}\n",
     "geo_origin.layer_height_m", ["must be a positive number"]),
    ("malformed-xml", "Workspace.xml", "<configuration><dimension x='4' y='4' z='1'>\n</configuration>",
     "", ["not well-formed XML", "mismatched tag", "line 2"]),
    ("empty-xml", "Workspace.xml", "", "", ["not well-formed XML"]),
    ("xml-wrong-root", "Workspace.xml", "<workspace><dimension x='4' y='4' z='1'/></workspace>",
     "", ["root element is <workspace>, expected <configuration>"]),
    ("xml-no-dimension", "Workspace.xml", "<configuration>" + _robots(ROBOT_A) + "</configuration>",
     "dimension", ["is missing"]),
    ("xml-dimension-zero", "Workspace.xml", _xml(dimension='<dimension x="4" y="0" z="1"/>'),
     "dimension", ["must be three positive integers"]),
    ("xml-dimension-not-integer", "Workspace.xml", _xml(dimension='<dimension x="4" y="four" z="1"/>'),
     "dimension", ["needs integer x, y, z attributes"]),
    ("xml-robot-without-start", "Workspace.xml", _xml(_robots(ROBOT_A, '<robot id="b"></robot>')),
     "robots/robot[1]", ["has no <start>"]),
    ("xml-duplicate-robot-id", "Workspace.xml",
     _xml(_robots(ROBOT_A, '<robot id="a"><start x="1" y="0" z="0"/></robot>')),
     "robots/robot[1]", ["drone id 'a' is used twice"]),
    ("xml-start-not-integer", "Workspace.xml", _xml(_robots('<robot id="a"><start x="0" y="1.5" z="0"/></robot>')),
     "robots/robot[0]/start", ["needs integer x, y, z attributes", "'1.5'"]),
    ("xml-obstacle-not-integer", "Workspace.xml",
     _xml("<obstacles><coord x='1' y='1' z='0'/><coord x='2' y='' z='0'/></obstacles>"),
     "obstacles/coord[1]", ["needs integer x, y, z attributes"]),
    ("xml-start-on-obstacle", "Workspace.xml",
     _xml(_robots(ROBOT_A), "<obstacles><coord x='0' y='0' z='0'/></obstacles>"),
     "drones.a", ["cell [0, 0, 0] is on an obstacle"]),
    ("xml-two-robots-one-cell", "Workspace.xml",
     _xml(_robots(ROBOT_A, '<robot id="b"><start x="0" y="0" z="0"/></robot>')),
     "drones.b", ["is also the start of drones.a"]),
    ("xml-station-out-of-bounds", "Workspace.xml",
     _xml("<charging_stations><coord x='4' y='0' z='0'/></charging_stations>"),
     "charging_stations[0]", ["cell [4, 0, 0] is outside the grid [4, 4, 1]"]),
    ("movingai-no-map-line", "bad.map", "type octile\nheight 2\nwidth 2\n..\n..\n", "", ["no 'map' line"]),
    ("movingai-no-rows", "bad.map", "type octile\nheight 2\nwidth 2\nmap\n", "", ["the map has no rows"]),
]


@pytest.mark.parametrize(("name", "content", "field", "phrases"),
                         [pytest.param(*case[1:], id=case[0]) for case in BAD_FILES])
def test_bad_file_is_a_workspace_error_naming_file_field_and_problem(
        write_file: WriteFile, name: str, content: str | bytes, field: str, phrases: list[str]) -> None:
    path = write_file(name, content)
    with pytest.raises(WorkspaceError) as info:
        load_workspace(path)
    err, message = info.value, str(info.value)
    assert err.source == str(path)
    assert message.startswith(f"{path}: ")
    assert err.field == field
    if field:
        assert message.startswith(f"{path}: {field}: ")
    for phrase in phrases:
        assert phrase in err.problem, f"{phrase!r} not in {message!r}"


def test_missing_file_is_a_workspace_error(tmp_path: Path) -> None:
    path = tmp_path / "nowhere" / "depot.yaml"
    with pytest.raises(WorkspaceError) as info:
        load_workspace(path)
    assert info.value.source == str(path)
    assert info.value.field == ""
    assert str(info.value) == f"{path}: cannot read the file: No such file or directory"


def test_a_directory_is_not_a_workspace_file(tmp_path: Path) -> None:
    with pytest.raises(WorkspaceError, match="cannot read the file"):
        load_workspace(tmp_path)


def test_build_rejects_an_invalid_workspace_without_a_file() -> None:
    with pytest.raises(WorkspaceError) as info:
        Workspace.build(size=(3, 3, 1), obstacles=frozenset({(1, 1, 0)}), drones={"d": (1, 1, 0)})
    assert str(info.value) == "drones.d: cell [1, 1, 0] is on an obstacle"


def test_with_drones_validates_the_new_starts() -> None:
    ws = Workspace.build(size=(3, 3, 1), obstacles=frozenset({(1, 1, 0)}))
    assert ws.with_drones({"d": (0, 0, 0)}).drones == {"d": (0, 0, 0)}
    with pytest.raises(WorkspaceError) as info:
        ws.with_drones({"d": (0, 0, 0), "e": (1, 1, 0)})
    assert str(info.value) == "drones.e: cell [1, 1, 0] is on an obstacle"
