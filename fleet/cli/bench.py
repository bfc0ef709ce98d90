"""``drona bench``: one subcommand per benchmark, each in :mod:`fleet.bench`.

``planner``: the paper's planner workload in CPU time; ``mavlink``: fake
vehicles and MAVLink links on loopback; ``coordination``: agents over Zenoh on
loopback; ``api``: durable mail submissions against the service. Each prints
its figures beside its target, and shares ``--quick``, ``--json``, ``--seed``
and ``--plot``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from fleet.bench import plot as bench_plot

#: name -> (module, help). Each module has ``add_arguments(parser)`` and ``run(args) -> int``.
BENCHES: dict[str, tuple[str, str]] = {
    "planner": ("fleet.bench.planner", "the paper's planner workload (Tables 1 and 2), in CPU time"),
    "mavlink": ("fleet.bench.mavlink", "telemetry throughput and setpoint jitter of fake vehicles on loopback"),
    "coordination": ("fleet.bench.coordination", "coordination latency of N agents over Zenoh on loopback"),
    "api": ("fleet.bench.api", "sustained durable mail submissions against the service"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="what", required=True, metavar="BENCH")
    for name, (module, help_text) in BENCHES.items():
        bench = sub.add_parser(name, help=help_text, description=help_text)
        _add_shared(bench)
        importlib.import_module(module).add_arguments(bench)
        bench.set_defaults(_bench=module)


def _add_shared(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="a short run (each option says its own)")
    parser.add_argument("--json", action="store_true", help="print JSON rows instead of a table")
    parser.add_argument("--seed", type=int, default=2017, help="random seed (default 2017)")
    parser.add_argument("--plot", type=Path, metavar="FILE",
                        help="also draw the figures into FILE, a .png or .svg (needs matplotlib: the plot extra)")


def run(args: argparse.Namespace) -> int:
    if args.plot is not None:
        try:
            bench_plot.check_target(args.plot)
        except bench_plot.PlotError as exc:
            print(f"drona bench: {exc}", file=sys.stderr)
            return 2
    code: int = importlib.import_module(args._bench).run(args)
    return code
