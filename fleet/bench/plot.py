"""``drona bench ... --plot FILE``: a benchmark's figures as a PNG or SVG, beside its text.

The file's extension picks the format. matplotlib is an optional extra
(``pip install 'drona-gcs[plot]'``), imported only for ``--plot``; figures
are drawn on a bare :class:`~matplotlib.figure.Figure` with the Agg canvas,
so no display and no pyplot global state are needed. Each bench's figure is
drawn from the very result it prints:

* planner: mean, median and p99 ms per plan for each (grid, drones) cell and Delta,
  beside the target (1/50 of the paper), on a log scale;
* mavlink: messages per link per second against the rate asked, and the setpoint
  boundaries' lateness (p50, p99, max) against its target;
* coordination: coordination latency p50, p99 and max, all plans and past the opening burst;
* api: the submissions' latency percentiles against the p99 target;
* delivery: the mail delivered over time, against the mail posted.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.bench import BenchError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from fleet.bench.api import Result as ApiResult
    from fleet.bench.delivery import DeliveryResult
    from fleet.bench.latency import CoordinationResult
    from fleet.bench.mavlink import JitterRow, TelemetryRow
    from fleet.bench.planner import Row

FORMATS = {".png": "png", ".svg": "svg"}
INSTALL = "pip install 'drona-gcs[plot]' (or matplotlib>=3.8)"


class PlotError(BenchError, ValueError):
    """``--plot`` cannot be honoured: a bad file name, or no matplotlib."""


def check_target(path: Path) -> None:
    """Refuse a bad ``--plot`` before the bench runs, not after minutes of it."""
    if path.suffix.lower() not in FORMATS:
        raise PlotError(f"--plot {path}: the extension must be .png or .svg")
    if not path.parent.is_dir():
        raise PlotError(f"--plot {path}: no folder {path.parent}")
    if importlib.util.find_spec("matplotlib") is None:
        raise PlotError(f"--plot needs matplotlib: {INSTALL}")


def write(args: argparse.Namespace, bench: str, result: Any) -> None:
    """Draw ``bench``'s figure of ``result`` into ``args.plot`` when it is given."""
    path: Path | None = getattr(args, "plot", None)
    if path is None:
        return
    figure = FIGURES[bench](result)
    save(figure, path)
    print(f"drona bench: figure written to {path}", file=sys.stderr)  # stdout may be JSON Lines


def save(figure: Figure, path: Path) -> None:
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(figure)  # no display: PNG through Agg (SVG through its own writer)
    # SVG text stays text: searchable, and a tenth of the size of glyphs drawn as paths.
    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "drona"}):
        figure.savefig(path, format=FORMATS[path.suffix.lower()], bbox_inches="tight")


def _figure(panels: int = 1, width: float = 7.0) -> tuple[Figure, list[Axes]]:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise PlotError(f"--plot needs matplotlib: {INSTALL}") from exc
    figure = Figure(figsize=(width * panels if panels > 1 else width, 4.2), layout="constrained")
    return figure, [figure.add_subplot(1, panels, i + 1) for i in range(panels)]


def _bars(ax: Axes, labels: Sequence[str], values: Sequence[float], colour: str = "#1565c0") -> None:
    bars = ax.bar(labels, values, color=colour)
    ax.bar_label(bars, fmt="%.2f", fontsize=8)
    ax.margins(y=0.2)  # room above the tallest bar for its label and the legend


def _target(ax: Axes, value: float, label: str) -> None:
    ax.axhline(value, color="#c62828", linestyle="--", linewidth=1, label=label)
    ax.legend(loc="upper left", fontsize=8)


# ------------------------------------------------------------------ one figure per bench
def planner_figure(rows: Sequence[Row]) -> Figure:
    figure, (ax,) = _figure(width=max(7.0, 0.45 * len(rows) + 3))
    cells = sorted({(r.grid, r.drones) for r in rows})
    x = {cell: i for i, cell in enumerate(cells)}
    for (name, delta), colour in zip(sorted({(r.planner, r.delta) for r in rows}), _COLOURS, strict=False):
        series = sorted((r for r in rows if (r.planner, r.delta) == (name, delta)), key=lambda r: (r.grid, r.drones))
        xs = [x[(r.grid, r.drones)] for r in series]
        label = f"{name} Delta {delta}" if name == "astar" else f"{name} (paper's Table 1)"
        ax.plot(xs, [r.mean_ms for r in series], "o-", color=colour, label=f"{label}: mean")
        ax.plot(xs, [r.median_ms for r in series], "s:", color=colour, markersize=4, label=f"{label}: median")
        ax.plot(xs, [r.p99_ms for r in series], "^--", color=colour, markersize=4, label=f"{label}: p99")
    targets = {(r.grid, r.drones): r.target_ms for r in rows if r.planner == "astar"}
    ax.plot([x[c] for c in targets], list(targets.values()), "_", color="#c62828", markersize=18,
            markeredgewidth=2, label="target: 1/50 of the paper")
    ax.set_xticks(range(len(cells)), [f"{w}x{w}\nR {r}" for w, r in cells], fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("CPU ms per plan")
    compiled = "compiled" if all(r.compiled for r in rows) else "pure Python"
    ax.set_title(f"drona bench planner: ms per plan ({compiled})")
    ax.grid(True, which="both", axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    return figure


def mavlink_figure(rows: Sequence[TelemetryRow | JitterRow]) -> Figure:
    from fleet.bench.mavlink import TelemetryRow

    figure, axes = _figure(panels=len(rows), width=6.0)
    for ax, row in zip(axes, rows, strict=True):
        if isinstance(row, TelemetryRow):
            _bars(ax, ["mean", "min"], [row.mean_per_link, row.min_per_link])
            _target(ax, row.expected_per_link * row.target_share, f"{row.target_share:.0%} of the rate asked")
            ax.set_ylabel("messages per link per second")
            ax.set_title(f"telemetry: {row.vehicles} vehicles at {row.stream_hz:g} Hz")
        else:
            _bars(ax, ["p50", "p99", "max"], [row.late_ms_p50, row.late_ms_p99, row.late_ms_max])
            _target(ax, row.target_p99_ms, f"p99 target {row.target_p99_ms:g} ms")
            ax.set_ylabel("boundary lateness, ms")
            ax.set_title(f"setpoint jitter: {row.loops} loops, tau {row.tau_s:g} s, {row.samples} boundaries")
    return figure


def coordination_figure(result: CoordinationResult) -> Figure:
    figure, (ax,) = _figure()
    labels = ["p50", "p99", "max"]
    every = [result.p50_ms, result.p99_ms, result.max_ms]
    steady = [result.steady_p50_ms, result.steady_p99_ms, result.steady_max_ms]
    xs = range(len(labels))
    for offset, values, name, colour in ((-0.2, every, f"all {result.plans} plans", "#1565c0"),
                                         (0.2, steady, f"past the opening: {result.steady_plans}", "#2e7d32")):
        bars = ax.bar([i + offset for i in xs], values, width=0.4, color=colour, label=name)
        ax.bar_label(bars, fmt="%.1f", fontsize=8)
    ax.plot([-0.4, 0.4], [20, 20], "--", color="#c62828", label="targets: p50 20 ms, p99 100 ms")
    ax.plot([0.6, 1.4], [100, 100], "--", color="#c62828")
    ax.set_xticks(list(xs), labels)
    ax.set_ylabel("task arrival to plan scheduled, ms")
    ax.set_title(f"drona bench coordination: {result.agents} agents, {result.seconds:.0f} s")
    ax.legend(fontsize=8)
    return figure


def api_figure(result: ApiResult) -> Figure:
    figure, (ax,) = _figure()
    _bars(ax, ["p50", "p90", "p99", "max"], [result.p50_ms, result.p90_ms, result.p99_ms, result.max_ms])
    from fleet.bench.api import TARGET_P99_MS

    _target(ax, TARGET_P99_MS, f"p99 target {TARGET_P99_MS:g} ms")
    ax.set_ylabel("submission latency, ms")
    ax.set_title(f"drona bench api: {result.achieved:.0f}/s of {result.rate:.0f}/s asked, "
                 f"{result.created} of {result.sent} created")
    return figure


def delivery_figure(result: DeliveryResult) -> Figure:
    figure, (ax,) = _figure()
    times = [0.0, *result.delivered_s, result.seconds]
    counts = [0, *range(1, len(result.delivered_s) + 1), len(result.delivered_s)]
    ax.step(times, counts, where="post", color="#1565c0", label=f"delivered: {result.delivered}")
    _target(ax, result.mails, f"posted: {result.mails}")
    ax.set_xlabel("seconds after the mail was posted")
    ax.set_ylabel("mail delivered")
    ax.set_title(f"drona bench delivery: {result.drones} drones of {result.workspace}, "
                 f"{result.per_minute:.2f} a minute")
    ax.legend(fontsize=8)
    return figure


_COLOURS = ["#1565c0", "#2e7d32", "#6a1b9a", "#e08a00"]
FIGURES: dict[str, Callable[[Any], Figure]] = {
    "planner": planner_figure,
    "mavlink": mavlink_figure,
    "coordination": coordination_figure,
    "api": api_figure,
    "delivery": delivery_figure,
}
