"""``drona bench delivery``: mails drawn where the service takes them, a verdict that needs every mail
delivered and a clean record, and a short run of the real demo."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from api.validation import MailChecker
from drona_gcs.audit import audit
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import load_workspace
from fleet.bench import BenchError
from fleet.bench.delivery import draw_mails, summarize
from tests.integration.harness import workspace_yaml

DRONA_16_4 = Path(__file__).parents[2] / "data" / "drona-workspaces" / "16_4" / "Workspace.xml"


def test_mails_are_drawn_by_seed_where_the_service_takes_them_and_no_drone_rests() -> None:
    ws = load_workspace(DRONA_16_4)
    mails = draw_mails(ws, 44, seed=7)
    assert len(mails) == 44 and draw_mails(ws, 44, seed=7) == mails != draw_mails(ws, 44, seed=8)
    checker, resting = MailChecker(ws), set(ws.drones.values()) | set(ws.parking) | set(ws.charging_stations)
    for pickup, dropoff, priority in mails:
        assert pickup != dropoff and not checker.check(pickup, dropoff) and 0 <= priority <= 9
        assert pickup not in resting and dropoff not in resting


def test_no_mail_is_drawn_that_no_charged_battery_can_fly() -> None:
    """A corridor 160 cells long with its charger at one end: far pairs need more than a battery."""
    ws = Workspace.build(size=(160, 1, 1), cell_size_m=1.0, tau_s=1.0, drones={"d1": (0, 0, 0)},
                         charging_stations=((1, 0, 0),))
    checker = MailChecker(ws)
    assert any(checker.check((2, 0, 0), (x, 0, 0)) for x in range(3, 160))  # some pairs are refused
    assert all(not checker.check(pickup, dropoff) for pickup, dropoff, _ in draw_mails(ws, 30, seed=5))


def test_a_workspace_with_no_two_cells_for_mail_is_an_error_naming_the_count() -> None:
    ws = Workspace.build(size=(2, 1, 1), cell_size_m=1.0, tau_s=1.0, drones={"d1": (0, 0, 0)})
    with pytest.raises(BenchError, match=r"found 0 of 3 mails the service accepts"):
        draw_mails(ws, 3, seed=1)


def _record(cells: dict[str, list[tuple[int, int, int]]]) -> list[dict[str, object]]:
    return [{"drone": d, "step": k, "cell": list(c), "planned": list(c), "delta": 0} for d, path in cells.items()
            for k, c in enumerate(path)]


@pytest.mark.parametrize("statuses, paths, passed", [
    ({"a": "delivered", "b": "delivered"}, {"d1": [(0, 0, 0), (1, 0, 0)], "d2": [(3, 3, 0), (3, 2, 0)]}, True),
    ({"a": "delivered", "b": "assigned"}, {"d1": [(0, 0, 0), (1, 0, 0)]}, False),
    ({"a": "delivered", "b": "failed"}, {"d1": [(0, 0, 0), (1, 0, 0)]}, False),
    ({"a": "delivered", "b": "delivered"}, {"d1": [(0, 0, 0), (1, 0, 0)], "d2": [(2, 0, 0), (1, 0, 0)]}, False),
    ({"a": "delivered", "b": "delivered"}, {"d1": [(0, 0, 0), (2, 0, 0)]}, False),
], ids=["all-delivered-clean", "one-unfinished", "one-failed", "a-collision", "a-jump"])
def test_the_run_passes_only_with_every_mail_delivered_and_a_clean_record(
        statuses: dict[str, str], paths: dict[str, list[tuple[int, int, int]]], passed: bool) -> None:
    ws = Workspace.build(size=(4, 4, 1), cell_size_m=1.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (3, 3, 0)})
    records = _record(paths)
    result = summarize(ws, len(statuses), statuses, 120.0, audit(ws, records), len(records))
    assert result.passed is passed
    assert result.delivered == list(statuses.values()).count("delivered")
    assert result.per_minute == result.delivered / 2
    assert result.unfinished == list(statuses.values()).count("assigned")


@pytest.mark.slow
def test_a_short_run_delivers_its_mail_and_prints_one_json_row(tmp_path: Path) -> None:
    ws_file = tmp_path / "ws.yaml"
    ws_file.write_text(workspace_yaml(2))
    record = tmp_path / "flight.jsonl"
    record.write_text("a stale line\n")
    done = subprocess.run([sys.executable, "-m", "fleet.cli", "bench", "delivery", "--workspace", str(ws_file),
                           "--mails", "2", "--speedup", "6", "--minutes", "3", "--seed", "3", "--json",
                           "--record", str(record)], check=False, capture_output=True, text=True, timeout=400)
    assert done.returncode == 0, done.stderr[-3000:]
    row = json.loads(done.stdout.strip().splitlines()[-1])
    assert (row["mails"], row["delivered"], row["drones"], row["violations"], row["jumps"]) == (2, 2, 2, 0, 0)
    assert row["record_steps"] == len(record.read_text().splitlines()) > 0 and row["conformance"] >= 0.95
    assert "delivered 2" in done.stderr  # the progress, as the mail went


def test_a_record_it_cannot_write_is_refused_before_the_fleet_starts(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "fleet.cli", "bench", "delivery", "--workspace", str(DRONA_16_4),
                           "--record", str(tmp_path / "no" / "such" / "folder.jsonl")],
                          check=False, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "folder.jsonl" in done.stderr and "drones flying" not in done.stderr
