"""``drona bench``: one subcommand per benchmark, each in :mod:`fleet.bench`.

``planner``: the paper's planner workload in CPU time; ``mavlink``: fake
vehicles and MAVLink links on loopback; ``coordination``: agents over Zenoh on
loopback; ``api``: durable mail submissions against the service; ``delivery``: a
workspace's whole fleet delivering a batch of mail, its flight record audited. Each prints
its figures beside its target, and shares ``--quick``, ``--json``, ``--seed``
and ``--plot``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fleet.bench import plot as bench_plot

#: name -> (module, help). Each module has ``add_arguments(parser)`` and ``run(args) -> int``.
BENCHES: dict[str, tuple[str, str]] = {
    "planner": ("fleet.bench.planner", "the paper's planner workload (Tables 1 and 2), in CPU time"),
    "mavlink": ("fleet.bench.mavlink", "telemetry throughput and setpoint jitter of fake vehicles on loopback"),
    "coordination": ("fleet.bench.coordination", "coordination latency of N agents over Zenoh on loopback"),
    "api": ("fleet.bench.api", "sustained durable mail submissions against the service"),
    "delivery": ("fleet.bench.delivery", "a workspace's fleet delivers a batch of mail through the service"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    _add_shared(parser, defaults=True)
    sub = parser.add_subparsers(dest="what", required=True, metavar="BENCH")
    modules = {name: importlib.import_module(module) for name, (module, _) in BENCHES.items()}
    for name, (module, help_text) in BENCHES.items():
        bench = sub.add_parser(name, help=help_text, description=help_text)
        _add_shared(bench, defaults=False)
        modules[name].add_arguments(bench)
        for other, found in modules.items():
            if other != name:
                _accept_unused(bench, found.add_arguments)
        bench.set_defaults(_bench=module)


def _add_shared(parser: argparse.ArgumentParser, defaults: bool) -> None:
    """The options every bench takes; without ``defaults`` (a bench's own parser), a value given before the
    bench's name stays."""
    def given(value: Any) -> Any:
        return value if defaults else argparse.SUPPRESS

    parser.add_argument("--quick", action="store_true", default=given(False),
                        help="a short run (each option says its own)")
    parser.add_argument("--json", action="store_true", default=given(False), help="print JSON rows instead of a table")
    parser.add_argument("--seed", type=int, default=given(2017), help="random seed (default 2017)")
    parser.add_argument("--plot", type=Path, metavar="FILE", default=given(None),
                        help="also draw the figures into FILE, a .png or .svg (needs matplotlib: the plot extra)")


#: Where another bench's options land: accepted (command lines written when every bench took every
#: option keep working), left out of the help, and named in a warning when given.
UNUSED = "unused_"


def _accept_unused(bench: argparse.ArgumentParser, add_arguments: Callable[[argparse.ArgumentParser], None]) -> None:
    others = argparse.ArgumentParser(add_help=False)
    add_arguments(others)
    for action in others._actions:
        strings = [s for s in action.option_strings if s not in bench._option_string_actions]
        if not strings:
            continue
        bench.add_argument(*strings, dest=UNUSED + strings[0], help=argparse.SUPPRESS, default=argparse.SUPPRESS,
                           action="store_const" if action.nargs == 0 else "store", const=True if action.nargs == 0
                           else None)


def run(args: argparse.Namespace) -> int:
    if args.plot is not None:
        try:
            bench_plot.check_target(args.plot)
        except bench_plot.PlotError as exc:
            print(f"drona bench: {exc}", file=sys.stderr)
            return 2
    unused = sorted(k.removeprefix(UNUSED) for k in vars(args) if k.startswith(UNUSED))
    if unused:
        print(f"drona bench {args.what}: ignoring {', '.join(unused)} (not an option of this bench)", file=sys.stderr)
    code: int = importlib.import_module(args._bench).run(args)
    return code
