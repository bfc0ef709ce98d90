"""`drona audit`: separation, conformance to the plan and continuity of a flown record.

The workspace is 5 x 5 x 1, free. Records are written as the agents write them.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from drona_gcs.audit import audit, record_line
from drona_gcs.errors import ProblemError
from drona_gcs.workspace import Workspace
from fleet.cli import main

WS = Workspace.build(size=(5, 5, 1), obstacles=frozenset())


def flight(drone: str, start: int, flown: list[tuple[int, int]], planned: Sequence[tuple[int, int] | None],
           delta: int = 1) -> list[dict[str, Any]]:
    """Records of one drone; a flown cell of (-1, -1) is a step without a record."""
    lines = []
    for k, (cell, plan) in enumerate(zip(flown, planned, strict=True)):
        if cell == (-1, -1):
            continue
        line = record_line(start + k, drone, (*cell, 0), None if plan is None else (*plan, 0), delta)
        lines.append(json.loads(line))
    return lines


def run_cli(tmp_path: Path, records: list[dict[str, Any]], *flags: str,
            capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    (tmp_path / "ws.json").write_text(json.dumps({"size": [5, 5, 1]}))
    (tmp_path / "run.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    code = main(["audit", "--workspace", str(tmp_path / "ws.json"), str(tmp_path / "run.jsonl"), *flags])
    return code, capsys.readouterr().out


PATH = [(0, 0), (1, 0), (2, 0), (3, 0)]


def test_a_flight_on_its_plan_conforms_fully() -> None:
    result = audit(WS, flight("d0", 10, PATH, PATH))
    assert result.safe and not result.jumps
    assert result.conformance.planned_steps == 4 and result.conformance.fraction == 1.0
    assert result.conformance.worst is None


def test_steps_flown_off_the_plan_lower_conformance_and_the_worst_is_named() -> None:
    # A vehicle that never left its start cell while its plan flew: three steps off, the last by three.
    result = audit(WS, flight("d0", 10, [(0, 0)] * 4, PATH))
    assert result.conformance.fraction == pytest.approx(0.25)
    worst = result.conformance.worst
    assert worst is not None and (worst.step, worst.cells, worst.planned) == (13, 3, (3, 0, 0))


def test_steps_with_no_plan_do_not_count_for_conformance() -> None:
    result = audit(WS, flight("d0", 0, [(0, 0), (0, 0), (1, 0)], [None, None, (1, 0)]))
    assert result.conformance.planned_steps == 1 and result.conformance.fraction == 1.0


def test_a_move_of_two_cells_in_one_step_is_a_jump_but_not_over_a_gap_of_two_steps() -> None:
    jumped = audit(WS, flight("d0", 0, [(0, 0), (2, 0)], [None, None]))
    assert [(j.step, j.steps) for j in jumped.jumps] == [(1, 1)]
    over_gap = audit(WS, flight("d0", 0, [(0, 0), (-1, -1), (2, 0)], [None, None, None]))
    assert not over_gap.jumps and over_gap.gaps == {"d0": 1}


def caught_up(via: list[tuple[int, int]]) -> list[dict[str, Any]]:
    """d0 recorded in (0,0) then (3,0) a step later, with the cells telemetry saw it pass in between."""
    second = json.loads(record_line(1, "d0", (3, 0, 0), (3, 0, 0), 1, tuple((*c, 0) for c in via)))
    return [*flight("d0", 0, [(0, 0)], [None]), second]


def test_cells_passed_via_make_a_catch_up_continuous_and_a_skipped_one_is_still_a_jump() -> None:
    assert not audit(WS, caught_up([(1, 0), (2, 0)])).jumps
    skipped = audit(WS, caught_up([(1, 0)]))
    assert [(j.before, j.after) for j in skipped.jumps] == [((1, 0, 0), (3, 0, 0))]


def test_a_cell_passed_via_is_checked_against_the_others_within_delta_of_both_records() -> None:
    # b comes down column 2 to (2,0): at step 2 it is within Delta 1 of d0's second record, at step 3 not.
    passing = caught_up([(1, 0), (2, 0)])
    b_at_2 = flight("b", 0, [(2, 2), (2, 1), (2, 0)], [None] * 3)
    unsafe = audit(WS, passing + b_at_2).violations
    assert [(v.cell, v.other, v.other_step) for v in unsafe] == [((2, 0, 0), "d0~b", 2)]
    b_at_3 = flight("b", 0, [(2, 3), (2, 2), (2, 1), (2, 0)], [None] * 4)
    assert audit(WS, passing + b_at_3).safe


def test_two_drones_catching_up_through_one_cell_at_once_are_a_separation_violation() -> None:
    """A stalled process lets all its drones fall behind at once, and they catch up at once: two of
    them may pass the same cell between the same two records, where neither record shows it."""
    # e, parked beside (2,0), darts into it and back between the same two records as d0 passes it.
    darting = json.loads(record_line(1, "e", (2, 1, 0), None, 1, ((2, 0, 0),)))
    crossing = [*caught_up([(1, 0), (2, 0)]), *flight("e", 0, [(2, 1)], [None]), darting]
    assert [(v.cell, v.other) for v in audit(WS, crossing).violations] == [((2, 0, 0), "d0~e")]
    later = json.loads(record_line(4, "e", (2, 1, 0), None, 1, ((2, 0, 0),)))  # steps 3-4: past Delta 1
    apart = [*caught_up([(1, 0), (2, 0)]), *flight("e", 0, [(2, 1)] * 4, [None] * 4), later]
    assert audit(WS, apart).safe


def test_a_first_record_passing_cells_is_judged_too() -> None:
    first = [json.loads(record_line(5, "d0", (0, 0, 0), None, 1, ((4, 4, 0),)))]
    assert [(j.before, j.after) for j in audit(WS, first).jumps] == [((4, 4, 0), (0, 0, 0))]


def test_a_cell_passed_next_to_a_parked_drone_is_one_violation_not_one_a_step() -> None:
    parked = flight("b", 0, [(2, 0)], [None])
    assert len(audit(WS, caught_up([(1, 0), (2, 0)]) + parked).violations) == 1


def test_a_diagonal_move_is_a_jump() -> None:
    assert len(audit(WS, flight("d0", 0, [(0, 0), (1, 1)], [None, None])).jumps) == 1


def test_two_drones_in_one_cell_are_a_separation_violation() -> None:
    records = flight("a", 0, [(0, 0), (1, 0)], [None, None]) + flight("b", 0, [(2, 0), (1, 0)], [None, None])
    assert not audit(WS, records).safe


def test_records_without_planned_are_still_read() -> None:
    old = [{"step": 0, "drone": "d0", "cell": [0, 0, 0], "delta": 0}]
    assert audit(WS, old).conformance.planned_steps == 0


@pytest.mark.parametrize(("record", "named"), [
    ({"step": 0, "drone": "d0", "cell": [0, 0, 0], "planned": [0, 0], "delta": 0}, "planned"),
    ({"step": 0, "drone": "d0", "cell": None, "planned": None, "delta": 0}, "cell"),
    ({"step": "0", "drone": "d0", "cell": [0, 0, 0], "delta": 0}, "integer step"),
    ({"step": 0, "drone": "d0", "cell": [0, 0, 0], "delta": 0, "via": [0, 0, 0]},
     r"each cell of via must be \[x, y, z\] integers, got 0$"),
    ({"step": 0, "drone": "d0", "cell": [0, 0, 0], "delta": 0, "via": [None]}, "integers, got null$"),
    ({"step": 0, "drone": "d0", "cell": [0, 0, 0], "delta": 0, "via": None}, "via must be a list .* got null$"),
])
def test_a_bad_record_is_named(record: dict[str, Any], named: str) -> None:
    with pytest.raises(ProblemError, match=named):
        audit(WS, [record])


def test_cli_exits_1_when_conformance_is_under_the_bound(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    off = flight("d0", 0, [(0, 0), (1, 0), (2, 0), (2, 0)], PATH)  # 75% in the planned cell
    code, out = run_cli(tmp_path, off, capsys=capsys)
    assert code == 1 and "conformance 75.0% < 95.0%" in out
    code, out = run_cli(tmp_path, off, "--min-conformance", "0.75", capsys=capsys)
    assert code == 0, out


def test_cli_exits_1_on_a_jump_unless_allowed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    jumped = flight("d0", 0, [(0, 0), (2, 0)], [None, None])
    code, out = run_cli(tmp_path, jumped, capsys=capsys)
    assert code == 1 and "JUMP d0 moved 2 cells in 1 step(s)" in out
    assert run_cli(tmp_path, jumped, "--max-jumps", "1", capsys=capsys)[0] == 0


def test_cli_json_verdict(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out = run_cli(tmp_path, flight("d0", 5, [(0, 0)] * 4, PATH), "--json", capsys=capsys)
    verdict = json.loads(out)
    assert code == 1 and verdict["ok"] is False
    assert verdict["conformance"]["planned_steps"] == 4 and verdict["conformance"]["in_planned_cell"] == 1
    assert verdict["conformance"]["worst_cells"] == 3
    assert verdict["drones"] == {"d0": {"first_step": 5, "last_step": 8, "gaps": 0}}


def test_cli_refuses_a_bound_outside_0_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        run_cli(tmp_path, [], "--min-conformance", "1.5", capsys=capsys)
    assert "not a fraction between 0 and 1" in capsys.readouterr().err


def test_cli_names_a_line_that_is_json_but_not_a_record(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "ws.json").write_text(json.dumps({"size": [5, 5, 1]}))
    (tmp_path / "run.jsonl").write_text("[1, 2, 3]\n")
    assert main(["audit", "--workspace", str(tmp_path / "ws.json"), str(tmp_path / "run.jsonl")]) == 2
    assert "run.jsonl:1: not a JSON object" in capsys.readouterr().err
