"""The workspace loaders: real files (DRONA's XML, MovingAI maps), our YAML/JSON format, and bad files
as workspace errors naming file, field and problem.
"""

from __future__ import annotations

import dataclasses
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
    ("vehicle-unknown-key", "ws.yaml", GRID + "vehicle: {accel: 5}\n", "vehicle",
     ["unknown field(s) ['accel']", "accel_m_s2"]),
    ("vehicle-not-a-mapping", "ws.yaml", GRID + "vehicle: fast\n", "vehicle", ["must be a mapping"]),
    ("vehicle-jerk-zero", "ws.yaml", GRID + "vehicle: {jerk_m_s3: 0}\n", "vehicle.jerk_m_s3",
     ["must be a positive number"]),
    ("vehicle-speed-string", "ws.yaml", GRID + "vehicle: {speed_m_s: fast}\n", "vehicle.speed_m_s",
     ["must be a number"]),
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
