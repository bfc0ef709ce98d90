"""`drona plan`: the JSON Lines contract, every kind of bad line, and plans judged by the checker."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import drona_gcs.planner as planner
from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_trajectory
from drona_gcs.workspace_files import workspace_from_mapping
from fleet.cli import main

WS = {"size": [6, 6, 1], "obstacles": [[2, 2, 0], [2, 3, 0], [3, 2, 0]]}


def run_plan(lines: list[Any], tmp_path: Path, *extra: str) -> list[dict[str, Any]]:
    src = tmp_path / "in.jsonl"
    src.write_text("\n".join(x if isinstance(x, str) else json.dumps(x) for x in lines) + "\n")
    out = tmp_path / "out.jsonl"
    assert main(["plan", str(src), "--output", str(out), *extra]) == 0
    return [json.loads(line) for line in out.read_text().splitlines()]


def test_ok_result_has_the_contract_fields_and_is_safe(tmp_path: Path) -> None:
    others = {"a": {"start_step": 0, "cells": [[5, 0, 0], [4, 0, 0], [3, 0, 0], [3, 1, 0]]}}
    problem = {"workspace": WS, "start": [0, 0, 0], "goal": [5, 5, 0], "start_step": 2, "delta": 1,
               "max_length": 30, "others": others, "planner": "astar"}
    [result] = run_plan([problem], tmp_path)
    assert set(result) == {"status", "cells", "primitives", "cost", "ms"}
    assert result["status"] == "ok"
    assert result["cells"][0] == [0, 0, 0] and result["cells"][-1] == [5, 5, 0]
    assert len(result["primitives"]) == len(result["cells"]) - 1 == result["cost"]
    assert result["cost"] == 10  # Manhattan distance, reachable around the obstacles
    assert isinstance(result["ms"], float) and result["ms"] >= 0
    ws = workspace_from_mapping(WS)
    mine = Trajectory(2, tuple(tuple(c) for c in result["cells"]))
    theirs = {"a": Trajectory(0, ((5, 0, 0), (4, 0, 0), (3, 0, 0), (3, 1, 0)))}
    assert check_trajectory(ws, mine, theirs, 1, (5, 5, 0)) == []


def test_results_keep_input_order_and_errors_do_not_stop_the_batch(tmp_path: Path) -> None:
    good = {"workspace": WS, "start": [0, 0, 0], "goal": [1, 0, 0]}
    results = run_plan([good, "{oops", good, {**good, "goal": [9, 9, 0]}, good], tmp_path)
    assert [r["status"] for r in results] == ["ok", "error", "ok", "error", "ok"]
    assert results[1]["error"].startswith("line 2: not valid JSON")
    assert results[3]["error"].startswith("line 4: goal: cell [9, 9, 0] is outside the grid")


@pytest.mark.parametrize(("change", "expected"), [
    ({"start": [2, 2, 0]}, "start: cell [2, 2, 0] is on an obstacle"),
    ({"goal": [0, 0]}, None),  # a 2-D cell is accepted as z = 0 (start == goal: ok)
    ({"goal": "here"}, "goal: must be a cell [x, y, z] of integers"),
    ({"start": None}, "start: missing"),
    ({"start_step": "soon"}, "start_step: must be an integer"),
    ({"delta": -1}, "delta: must be >= 0"),
    ({"max_length": 1.5}, "max_length: must be an integer"),
    ({"planner": "dijkstra"}, "planner: must be one of ['astar', 'smt']"),
    ({"colour": "red"}, "unknown field(s) ['colour']"),
    ({"others": []}, "others: must map drone ids to trajectories"),
    ({"others": {"a": {"cells": []}}}, "others.a.cells: must be a non-empty list"),
    ({"others": {"a": {"cells": [[0, 5, 0], [2, 5, 0]]}}}, "others.a.cells[1]: [2, 5, 0] is not one move from"),
    ({"others": {"a": {"cells": [[2, 2, 0]]}}}, "others.a.cells[0]: cell [2, 2, 0] is on an obstacle"),
    ({"others": {"a": {"cells": [[1, 1, 0]], "speed": 3}}}, "others.a: unknown field(s) ['speed']"),
    ({"workspace": {"size": [0, 6, 1]}}, "workspace: workspace: size: must be three positive integers"),
    ({"workspace": {"size": [6, 6, 1], "walls": []}}, "unknown field(s) ['walls']"),
    ({"workspace": "/nonexistent/ws.yaml"}, "cannot read the file"),
    ({"costs": {"jump": 1}}, "unknown primitive 'jump' in costs"),
])
def test_each_bad_line_gets_its_error(tmp_path: Path, change: dict[str, Any], expected: str | None) -> None:
    problem = {"workspace": WS, "start": [0, 0, 0], "goal": [0, 0, 0], **change}
    problem = {k: v for k, v in problem.items() if v is not None}
    [result] = run_plan([problem], tmp_path)
    if expected is None:
        assert result["status"] == "ok"
    else:
        assert result["status"] == "error"
        assert result["error"].startswith("line 1: ")
        assert expected in result["error"]


def test_not_an_object_and_missing_workspace(tmp_path: Path) -> None:
    results = run_plan(["[1, 2]", {"start": [0, 0, 0], "goal": [1, 0, 0]}], tmp_path)
    assert "a problem must be a JSON object" in results[0]["error"]
    assert "workspace: missing, and no --workspace was given" in results[1]["error"]


def test_no_plan_when_the_goal_is_walled_in_by_a_parked_drone(tmp_path: Path) -> None:
    corridor = {"size": [5, 1, 1]}
    problem = {"workspace": corridor, "start": [0, 0, 0], "goal": [4, 0, 0],
               "others": {"b": {"start_step": 0, "cells": [[2, 0, 0]]}}}
    [result] = run_plan([problem], tmp_path)
    assert result["status"] == "no_plan" and set(result) == {"status", "ms"}


def test_workspace_flag_and_file_paths_and_id_echo(tmp_path: Path) -> None:
    ws_file = tmp_path / "ws.json"
    ws_file.write_text(json.dumps(WS))
    lines = [{"start": [0, 0, 0], "goal": [5, 5, 0], "id": "a"},
             {"workspace": str(ws_file), "start": [5, 5, 0], "goal": [0, 0, 0], "id": 2}]
    results = run_plan(lines, tmp_path, "--workspace", str(ws_file), "--check")
    assert [r["id"] for r in results] == ["a", 2]
    assert all(r["status"] == "ok" and r["safe"] is True for r in results)


def test_bad_workspace_flag_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", "--workspace", str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml" in capsys.readouterr().err


def test_console_script_reads_stdin(tmp_path: Path) -> None:
    line = json.dumps({"workspace": {"size": [3, 3, 1]}, "start": [0, 0, 0], "goal": [2, 2, 0]})
    done = subprocess.run([sys.executable, "-m", "fleet.cli", "plan"], input=line + "\n", text=True,
                          capture_output=True, timeout=60, check=True)
    result = json.loads(done.stdout)
    assert result["status"] == "ok" and result["cost"] == 4


def test_bench_quick_json_rows(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "planner", "--json", "--grids", "16", "--drones", "4", "--deltas", "0,1",
                 "--tasks", "12", "--no-smt"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(r["grid"], r["drones"], r["delta"]) for r in rows] == [(16, 4, 0), (16, 4, 1)]
    for row in rows:
        assert row["plans"] == 12 and row["paper_ms"] == pytest.approx(17.4)
        assert 0 < row["median_ms"] <= row["p99_ms"]
        assert row["meets_target"] == (row["mean_ms"] <= row["target_ms"])
        assert row["compiled"] is planner.NATIVE  # which planner code the figures are of
