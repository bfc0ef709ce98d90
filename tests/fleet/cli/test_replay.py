"""`drona replay`: the replay document of a flown record, its errors, and the small server that serves it.

The page itself is tested in a browser: tests/api/test_replay_page.py.
"""

from __future__ import annotations

import json
import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drona_gcs.audit import record_line
from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame
from drona_gcs.replay import replay_document
from drona_gcs.workspace_files import workspace_from_mapping
from fleet.cli import main
from fleet.cli.replay import load_document, make_server

WS_DATA: dict[str, Any] = {
    "name": "yard", "size": [6, 4, 2], "cell_size_m": 5.0,
    "geo_origin": {"lat": 47.3977, "lon": 8.5456, "alt_m": 488.0, "layer0_alt_m": 5.0},
    "obstacles": [[3, 3, 0]], "charging_stations": [[0, 3, 0]],
    "drones": {"a": [0, 0, 0], "b": [2, 0, 0]},
}
WS = workspace_from_mapping(WS_DATA, source="yard.json")


def lines(drone: str, start: int, cells: list[tuple[int, int, int] | None],
          planned: list[tuple[int, int, int] | None] | None = None) -> list[str]:
    """Record lines as the agent writes them; a None cell is a step without a record."""
    plans = planned or [None] * len(cells)
    pairs = enumerate(zip(cells, plans, strict=True))
    return [record_line(start + k, drone, cell, plan, 1) for k, (cell, plan) in pairs if cell is not None]


#: a and b meet in [1, 0, 0] at step 11; b has no record at step 12.
MEETING = lines("a", 10, [(0, 0, 0), (1, 0, 0), (1, 1, 0)]) + lines("b", 10, [(2, 0, 0), (1, 0, 0), None, (3, 0, 0)])


def document(text: list[str]) -> dict[str, Any]:
    return replay_document(WS, [json.loads(line) for line in text])


def test_two_drones_in_one_cell_are_a_separation_finding_at_their_step() -> None:
    doc = document(MEETING)
    assert (doc["first_step"], doc["last_step"], doc["drones"]) == (10, 13, ["a", "b"])
    collisions = [f for f in doc["findings"] if f["kind"] == "collision" and f["step"] == 11]
    assert collisions and collisions[0]["drones"] == ["a", "b"] and collisions[0]["cells"] == [[1, 0, 0]]
    assert collisions[0]["family"] == "separation" and "collision at step 11" in collisions[0]["text"]
    assert doc["summary"]["safe"] is False and doc["summary"]["gaps"] == {"a": 0, "b": 1}
    # the findings are the audit's, listed by step
    steps = [f["step"] for f in doc["findings"]]
    assert steps == sorted(steps)


def test_frames_hold_a_drone_where_the_checker_does_and_say_when_it_was_not_seen() -> None:
    doc = document(MEETING)
    assert [f["step"] for f in doc["frames"]] == [10, 11, 12, 13]
    b = [f["drones"]["b"] for f in doc["frames"]]
    assert [x["cell"] for x in b] == [[2, 0, 0], [1, 0, 0], [1, 0, 0], [3, 0, 0]]
    assert [x["seen"] for x in b] == [True, True, False, True]
    a_last = doc["frames"][-1]["drones"]["a"]
    assert a_last == {"cell": [1, 1, 0], "planned": None, "seen": False}  # after its last record


def test_steps_off_the_plan_and_jumps_are_findings_too() -> None:
    flown = lines("a", 0, [(0, 0, 0), (0, 0, 0), (2, 0, 0)], planned=[(0, 0, 0), (1, 0, 0), (2, 0, 0)])
    doc = document(flown)
    kinds = {(f["kind"], f["family"], f["step"]) for f in doc["findings"]}
    assert ("deviation", "conformance", 1) in kinds and ("jump", "continuity", 2) in kinds
    deviation = next(f for f in doc["findings"] if f["kind"] == "deviation")
    assert deviation["cells"] == [[0, 0, 0], [1, 0, 0]]  # flown, planned
    assert doc["frames"][1]["drones"]["a"]["planned"] == [1, 0, 0]
    assert doc["summary"]["conformance"] == pytest.approx(2 / 3)


def test_the_geometry_places_cells_as_geo_does() -> None:
    ws = document(MEETING)["workspace"]
    assert ws["size"] == [6, 4, 2] and ws["obstacles"] == [[3, 3, 0]] and ws["delta"] == 1
    assert ws["layers_alt_m"] == [493.0, 498.0]  # 488 + 5, then a layer of 5 m (the cell size)
    g = ws["grid"]
    # the page interpolates between the corners: that must land on geo.py's cell centre
    x, y = 4, 2
    lat = g["south"] + (g["north"] - g["south"]) * (y + 0.5) / 4
    lon = g["west"] + (g["east"] - g["west"]) * (x + 0.5) / 6
    centre = GeoFrame(WS).cell_to_global((x, y, 0))
    assert lat == pytest.approx(centre.lat, abs=1e-9) and lon == pytest.approx(centre.lon, abs=1e-9)


@pytest.mark.parametrize(("line", "problem"), [
    (record_line(0, "zed", (0, 0, 0), None, 1), "drone 'zed' is not in workspace 'yard'"),
    (record_line(0, "a", (9, 0, 0), None, 1), "cell [9, 0, 0] is outside the grid [6, 4, 2]"),
])
def test_a_record_of_another_workspace_is_refused(line: str, problem: str) -> None:
    with pytest.raises(ProblemError, match=r"record 1: .*another workspace"):
        document([line])
    with pytest.raises(ProblemError) as caught:
        document([line])
    assert problem in str(caught.value)


def test_no_records_is_refused() -> None:
    with pytest.raises(ProblemError, match="no records"):
        document([])


# ------------------------------------------------------------------ the command
def files(tmp_path: Path, text: str) -> tuple[Path, Path]:
    (tmp_path / "yard.json").write_text(json.dumps(WS_DATA))
    (tmp_path / "run.jsonl").write_text(text)
    return tmp_path / "yard.json", tmp_path / "run.jsonl"


@pytest.mark.parametrize(("text", "problem"), [
    (None, "No such file"),
    ("".join(MEETING[:1]) + "{not json\n", "run.jsonl:2: not JSON"),
    ("[1, 2, 3]\n", "run.jsonl:1: not a JSON object"),
    ('{"step": 1, "drone": "a"}\n', "run.jsonl: record 1: needs an integer step"),
    (record_line(0, "a", (0, 9, 0), None, 1), "run.jsonl: record 1: cell [0, 9, 0] is outside the grid"),
    ("\n", "run.jsonl: no records"),
])
def test_bad_input_exits_2_naming_the_problem(tmp_path: Path, text: str | None, problem: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    ws, record = files(tmp_path, text or "")
    if text is None:
        record.unlink()
    assert main(["replay", str(record), "--workspace", str(ws), "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("drona replay: ") and problem in err


def test_a_demo_record_needs_no_workspace(tmp_path: Path) -> None:
    _, record = files(tmp_path, "".join(lines("d2", 0, [(15, 0, 0), (15, 1, 0)])))
    doc = load_document(record, None)
    assert doc["workspace"]["name"] == "demo-campus" and doc["drones"] == ["d2"]


@pytest.fixture
def served(tmp_path: Path) -> Iterator[str]:
    ws, record = files(tmp_path, "".join(MEETING))
    server = make_server(load_document(record, ws), "127.0.0.1", 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def get(url: str) -> tuple[int, str, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=5) as res:
            return res.status, res.headers["Content-Type"], res.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.headers["Content-Type"], exc.read()


def test_the_server_serves_the_page_the_document_and_static_files_only(served: str) -> None:
    status, kind, body = get(served + "/")
    assert status == 200 and kind.startswith("text/html") and b"/static/replay.js" in body
    status, kind, body = get(served + "/replay.json")
    assert status == 200 and kind == "application/json" and json.loads(body)["first_step"] == 10
    for path in ("/static/replay.js", "/static/replay.css", "/static/vendor/leaflet/leaflet.js"):
        assert get(served + path)[0] == 200, path
    for path in ("/static/../../pyproject.toml", "/static/%2e%2e/routes/dashboard.py", "/static/nope.js", "/x"):
        assert get(served + path)[0] == 404, path
