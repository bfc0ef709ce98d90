"""`drona bench ... --plot FILE`: each bench's figure as a valid PNG or SVG, and --plot refused before a run."""

from __future__ import annotations

import argparse
import importlib.util
import struct
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from fleet.bench import plot as bench_plot
from fleet.bench.api import Result as ApiResult
from fleet.bench.delivery import DeliveryResult
from fleet.bench.latency import CoordinationResult
from fleet.bench.mavlink import JitterRow, TelemetryRow
from fleet.bench.planner import Row
from fleet.cli import main

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
SVG = "{http://www.w3.org/2000/svg}svg"


def planner_rows() -> list[Row]:
    def row(planner: str, grid: int, drones: int, delta: int, mean: float, paper: float) -> Row:
        return Row(planner, grid, drones, delta, 40, mean, mean * 0.9, mean * 3, 0, paper, paper / 50,
                   paper / mean, mean <= paper / 50, compiled=True)

    return [row("astar", 16, 4, 0, 0.2, 17.4), row("astar", 32, 4, 0, 0.3, 17.9), row("astar", 16, 4, 1, 0.25, 17.4),
            row("astar", 32, 4, 1, 0.4, 17.9), row("smt", 16, 4, 0, 90.0, 660.0)]


RESULTS: dict[str, Any] = {
    "planner": planner_rows(),
    "mavlink": [
        TelemetryRow("telemetry", 16, 5.0, 10.0, 32.5, 32.1, 31.0, 0.95, 0, 0.1, 0.4, 80.0, 0, 0, 1.2, 0.4, 25.0,
                     0.5, 31.0, True),
        JitterRow("jitter", 8, 1.0, 5, 40, 0.6, 1.8, 2.2, 0.2, 0.1, True),
    ],
    "coordination": CoordinationResult(8, 15.0, 120, 9.5, 40.2, 61.0, 90, 8.1, 30.0, 35.0, 14.0, 6.2, 0.3, 20),
    "api": ApiResult(1000.0, 3.0, 64, 8, 3000, 3000, 0, 998.7, 2.1, 4.0, 9.8, 20.5, 3000, True),
    "delivery": DeliveryResult("16_4", 4, 5, 4, 0, 1, 300.0, 0.8, 1200, 0, 0, 1.0, (40.5, 90.0, 150.2, 200.0)),
}


def plot_args(path: Path) -> argparse.Namespace:
    return argparse.Namespace(plot=path)


def assert_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    assert width > 300 and height > 200


def assert_svg(path: Path, *texts: str) -> None:
    root = ET.parse(path).getroot()
    assert root.tag == SVG
    content = path.read_text()
    for text in texts:
        assert text in content, text


@pytest.mark.parametrize("bench", sorted(RESULTS))
def test_each_bench_draws_its_result_as_png_and_svg(bench: str, tmp_path: Path) -> None:
    bench_plot.write(plot_args(tmp_path / f"{bench}.png"), bench, RESULTS[bench])
    assert_png(tmp_path / f"{bench}.png")
    bench_plot.write(plot_args(tmp_path / f"{bench}.svg"), bench, RESULTS[bench])
    assert_svg(tmp_path / f"{bench}.svg")


def test_the_svg_keeps_its_words_as_text(tmp_path: Path) -> None:
    bench_plot.write(plot_args(tmp_path / "p.svg"), "planner", RESULTS["planner"])
    assert_svg(tmp_path / "p.svg", "drona bench planner", "astar Delta 1: p99", "target: 1/50 of the paper")


def test_no_plot_asked_draws_nothing(tmp_path: Path) -> None:
    bench_plot.write(argparse.Namespace(), "api", RESULTS["api"])
    bench_plot.write(plot_args(None), "api", RESULTS["api"])  # type: ignore[arg-type]
    assert not list(tmp_path.iterdir())


def test_the_quick_planner_bench_writes_its_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "planner.svg"
    code = main(["bench", "planner", "--quick", "--grids", "16", "--drones", "4", "--tasks", "5", "--no-smt",
                 "--json", "--plot", str(out)])
    assert code == 0
    captured = capsys.readouterr()
    assert len(captured.out.splitlines()) == 2  # the JSON rows stay alone on stdout
    assert f"figure written to {out}" in captured.err
    assert_svg(out, "16x16", "astar Delta 0: mean")


@pytest.mark.parametrize(("name", "problem"), [
    ("figure.pdf", "the extension must be .png or .svg"),
    ("missing/figure.png", "no folder"),
])
def test_a_bad_plot_file_is_refused_before_the_bench_runs(tmp_path: Path, name: str, problem: str,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    # --tasks 100000 would run for minutes: the refusal must come first
    assert main(["bench", "planner", "--grids", "256", "--tasks", "100000", "--plot", str(tmp_path / name)]) == 2
    captured = capsys.readouterr()
    assert problem in captured.err and not captured.out


def test_without_matplotlib_plot_says_how_to_install_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None)
    assert main(["bench", "planner", "--grids", "256", "--tasks", "100000", "--plot", str(tmp_path / "f.png")]) == 2
    assert "--plot needs matplotlib: pip install 'drona-gcs[plot]'" in capsys.readouterr().err


def test_a_tiny_mavlink_jitter_run_writes_its_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "jitter.png"
    assert main(["bench", "mavlink", "--only", "jitter", "--loops", "2", "--tau", "0.2", "--boundaries", "3",
                 "--plot", str(out)]) == 0
    assert "Setpoint jitter" in capsys.readouterr().out
    assert_png(out)
