"""``drona verify``: the systematic tester. Exit 0 when no violation is found, 1 with a trace
and a replay token when one is, 2 on bad arguments."""

from __future__ import annotations

import argparse
import re
import time
from collections.abc import Callable

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from drona_gcs.errors import DronaError
from drona_gcs.verify import table3
from drona_gcs.verify.dfs import DEEPEN
from drona_gcs.verify.explore import (
    Explorer,
    Outcome,
    Scenario,
    Strategy,
    decode_token,
    encode_token,
)
from drona_gcs.verify.monitors import SKEW_STEPS
from drona_gcs.verify.mutants import SEEDED_BUGS
from drona_gcs.verify.sweep import SweepRow, configurations, run_sweep
from drona_gcs.verify.world import PARTITION_STEPS
from drona_gcs.workspace_files import load_workspace

_GRID = re.compile(r"^(\d+)x(\d+)(?:x(\d+))?$")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workspace", help="workspace file (YAML, DRONA XML, ...)")
    where.add_argument("--grid", help="random grid WxH[xL] (default 8x8)")
    parser.add_argument("--obstacles", type=float, help="obstacle ratio of --grid (default 0.2)")
    parser.add_argument("--drones", type=int, help="drones (default 4)")
    parser.add_argument("--requests", type=int, help="mail requests the environment sends (default 6)")
    parser.add_argument("--delta", type=int, help="the separation window in steps (default: the workspace's, "
                        "ceil((beta_s + lambda_s) / tau_s), or 1 on a random grid)")
    parser.add_argument("--strategy", choices=[s.value for s in Strategy], help="how schedules are chosen (default "
                        "random)")
    parser.add_argument("--schedules", type=int, default=1000, help="schedules to run (random, pct)")
    parser.add_argument("--max-depth", type=int, default=None,
                        help="transitions per schedule (default 5000; 100 with --table3)")
    parser.add_argument("--seed", type=int, default=0, help="seeds the scenario and the strategy")
    parser.add_argument("--time-limit", type=float, default=60.0, help="seconds (default 60)")
    parser.add_argument("--seed-bug", action="append", default=[], choices=sorted(SEEDED_BUGS),
                        help="plant a known bug (repeatable): "
                        + "; ".join(f"{k}: {v}" for k, v in SEEDED_BUGS.items()))
    parser.add_argument("--max-delay", type=int, default=None,
                        help="steps within which a message arrives (default 2; 0 with dfs, which keeps the "
                             "state space small: messages arrive within the step they were sent in)")
    parser.add_argument("--shrink", type=float, default=3.0,
                        help="seconds spent looking for a shorter trace once a violation is found (default 3)")
    parser.add_argument("--replay", metavar="TOKEN", help="replay the schedule of a token and print its trace")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--no-faults", action="store_true",
                        help="leave out the field's faults (duplicated messages, a mail cancelled, a vehicle down) "
                             "and the mixed fleet")
    parser.add_argument("--crashes", type=int, default=0, metavar="N",
                        help="also let N agents crash (their vehicles hold in the air) and restart, in each run "
                             "(default 0)")
    parser.add_argument("--partitions", type=int, default=0, metavar="N",
                        help="also let the network cut a drone off from the rest N times in each run, each "
                             f"healing within {PARTITION_STEPS} steps (default 0)")
    parser.add_argument("--skews", type=int, default=0, metavar="N",
                        help="also let N drones' clocks go beyond the fleet's bound in each run: every clock "
                             f"check says so in its turn, and that clock then keeps Delta + {SKEW_STEPS} steps "
                             "ahead of or behind the others' (default 0; not with --crashes or --partitions)")
    parser.add_argument("--sweep", type=int, metavar="N",
                        help="run N configurations drawn from --seed (2-6 drones, 2-10 requests, Delta 0-2, 8x8 "
                             "and 16x16, with and without obstacles, random and pct), --time-limit each, with the "
                             "faults, --max-delay and --seed-bug asked for; prints a row per run and exits 1 if any "
                             "fails")
    parser.add_argument("--table3", action="store_true",
                        help="the paper's Table 3: exhaustive search of 2, 4 and 8 drones (one request each) on 8x8, "
                             "16x16 and 32x32 grids, --time-limit seconds per cell; prints how deep each got")
    parser.add_argument("--deepen", type=int, default=DEEPEN,
                        help=f"dfs: iterative deepening raises the depth bound by this much (default {DEEPEN})")


#: What a sweep draws, and the paper's table fixes, itself; the default of each otherwise.
DRAWN: dict[str, object] = {"workspace": None, "grid": "8x8", "obstacles": 0.2, "drones": 4, "requests": 6,
                            "delta": None, "strategy": "random"}


def run(args: argparse.Namespace) -> int:
    console = Console(stderr=True)
    try:
        if args.replay:
            return _replay(args.replay)
        _refuse_what_is_set(args)
        if args.max_depth is None:
            args.max_depth = 100 if args.table3 else 5000
        if args.sweep is not None:
            return _sweep(args)
        if args.table3:
            return _table3(args)
        scenario = _scenario(args)
        explorer = Explorer(scenario)
    except (DronaError, ValueError) as exc:
        console.print(f"drona verify: {exc}", markup=False)
        return 2
    strategy = Strategy(args.strategy)
    if not explorer.workspace.charging_stations:
        print("note: the workspace has no charging stations, so batteries are not modelled")
    started = time.monotonic()
    with _progress(args.quiet, console) as bar:
        task = bar.add_task(strategy.value, total=None if strategy is Strategy.DFS else args.schedules, rate="")

        def progress(outcome: Outcome) -> None:
            elapsed = max(time.monotonic() - started, 1e-9)
            bar.update(task, completed=outcome.schedules,
                       rate=f"{outcome.schedules / elapsed:,.0f} schedules/s, {outcome.states / elapsed:,.0f} states/s")

        limit: float = args.time_limit

        def stop() -> bool:
            return time.monotonic() - started > limit

        if strategy is Strategy.DFS:
            outcome = explorer.exhaustive(args.max_depth, stop, progress, deepen=args.deepen)
        else:
            outcome = explorer.run(strategy, args.schedules, args.max_depth, args.seed, stop=stop, progress=progress)
    elapsed = time.monotonic() - started
    if outcome.violation is not None and args.shrink > 0:
        shrink_until = time.monotonic() + args.shrink
        outcome = explorer.shrink(outcome, strategy, args.seed, stop=lambda: time.monotonic() > shrink_until)
    _summary(outcome, strategy, elapsed)
    if outcome.violation is None:
        return 0
    token = encode_token(scenario, outcome.choices)
    _print_violation(outcome, token)
    return 1


def _refuse_what_is_set(args: argparse.Namespace) -> None:
    """A sweep draws its configurations, and the paper's table is fixed: given anyway, a flag that sets
    what they set would be ignored, and the run would not be the one asked for."""
    if args.sweep is not None and args.table3:
        raise ValueError("--sweep and --table3 are two runs: ask for one")
    given = [f"--{name}" for name in DRAWN if getattr(args, name) is not None]
    if args.table3:  # the paper's setting: its delay, the clean stack, no crash, cut or skew
        asked = {"--max-delay": args.max_delay is not None, "--seed-bug": bool(args.seed_bug),
                 "--crashes": args.crashes > 0, "--partitions": args.partitions > 0, "--skews": args.skews > 0}
        given += [flag for flag, is_set in asked.items() if is_set]
    mode = "--sweep" if args.sweep is not None else "--table3" if args.table3 else None
    if mode is not None and given:
        raise ValueError(f"{mode} sets {', '.join(given)} itself: leave {'it' if len(given) == 1 else 'them'} out")


def _defaults(args: argparse.Namespace) -> None:
    """What a single run was not given (a sweep and the paper's table read none of it)."""
    for name, default in DRAWN.items():
        if getattr(args, name) is None:
            setattr(args, name, default)


def _scenario(args: argparse.Namespace) -> Scenario:
    _defaults(args)
    grid = (8, 8, 1)
    if not args.workspace:
        match = _GRID.match(args.grid)
        if not match:
            raise ValueError(f"--grid must look like 8x8 or 8x8x2, got {args.grid!r}")
        grid = (int(match[1]), int(match[2]), int(match[3] or 1))
    if args.schedules < 1 or args.max_depth < 1 or args.time_limit <= 0:
        raise ValueError("--schedules, --max-depth and --time-limit must be positive")
    max_delay = args.max_delay if args.max_delay is not None else (0 if args.strategy == "dfs" else Scenario.max_delay)
    delta = args.delta
    if delta is None:
        delta = load_workspace(args.workspace).delta if args.workspace else 1
    return Scenario(drones=args.drones, requests=args.requests, delta=delta, seed=args.seed, grid=grid,
                    obstacles=args.obstacles, workspace_path=args.workspace, bugs=tuple(args.seed_bug),
                    max_delay=max_delay, faults=not args.no_faults, crashes=args.crashes, partitions=args.partitions,
                    skews=args.skews)


def _sweep(args: argparse.Namespace) -> int:
    if args.sweep < 1 or args.time_limit <= 0:
        raise ValueError("--sweep and --time-limit must be positive")

    def stop_after() -> Callable[[], bool]:
        deadline = time.monotonic() + args.time_limit
        return lambda: time.monotonic() > deadline

    def on_row(row: SweepRow) -> None:
        o = row.outcome
        print(f"{'clean' if row.clean else 'FAIL':<6} {row.configuration} ({o.schedules} schedules, "
              f"{o.transitions} transitions)", flush=True)
        if row.token is not None:
            print(f"       {o.violation}\n       replay: drona verify --replay {row.token}", flush=True)

    configs = configurations(args.seed, args.sweep, faults=not args.no_faults, crashes=args.crashes,
                             partitions=args.partitions, skews=args.skews,
                             max_delay=Scenario.max_delay if args.max_delay is None else args.max_delay,
                             bugs=tuple(args.seed_bug))
    rows = run_sweep(configs, args.schedules, args.max_depth, stop_after, on_row)
    failed = [row for row in rows if not row.clean]
    by_monitor = sorted({row.outcome.violation.monitor for row in failed if row.outcome.violation is not None})
    print(f"sweep seed {args.seed}: {len(rows) - len(failed)} of {len(rows)} clean"
          + (f"; failing monitors: {', '.join(by_monitor)}" if failed else ""))
    return 1 if failed else 0


def _table3(args: argparse.Namespace) -> int:
    if args.max_depth < 1 or args.time_limit <= 0 or args.deepen < 1:
        raise ValueError("--max-depth, --time-limit and --deepen must be positive")
    started = [0.0]

    def stop_after() -> Callable[[], bool]:
        started[0] = time.monotonic()
        deadline = started[0] + args.time_limit
        return lambda: time.monotonic() > deadline

    print(f"{'drones':>6} {'grid':>6} {'complete to depth':>17} {'states':>10} {'transitions':>12} {'seconds':>8}")

    def on_row(row: table3.Row) -> None:
        o, seconds = row.outcome, time.monotonic() - started[0]
        if row.refused is not None:
            print(f"{row.scenario.drones:>6} {row.grid:>6}  scenario refused: {row.refused}", flush=True)
            return
        depth = f"{o.complete_depth}"
        if o.violation is not None:
            depth += f" VIOLATION {o.violation.monitor}"
        print(f"{row.scenario.drones:>6} {row.grid:>6} {depth:>17} {o.complete_states:>10} {o.transitions:>12} "
              f"{seconds:>8.1f}", flush=True)
        if o.violation is not None:
            print(f"       {o.violation}\n       replay: drona verify --replay {encode_token(row.scenario, o.choices)}")

    rows = table3.run_table(table3.scenarios(args.seed, faults=not args.no_faults), args.max_depth, stop_after,
                            on_row, deepen=args.deepen)
    return 1 if any(row.outcome.violation is not None for row in rows) else 0


def _replay(token: str) -> int:
    scenario, choices = decode_token(token)
    outcome = Explorer(scenario).replay(choices)
    if outcome.violation is None:
        print(f"replayed {len(choices)} transitions: no violation")
        return 0
    _print_violation(outcome, token)
    return 1


def _summary(outcome: Outcome, strategy: Strategy, elapsed: float) -> None:
    rate = outcome.schedules / elapsed if elapsed else 0.0
    states = outcome.states / elapsed if elapsed else 0.0
    done = " (every schedule to the depth bound)" if outcome.exhausted else ""
    if strategy is Strategy.DFS:
        done = f", complete to depth {outcome.complete_depth}{done}"
    print(f"{strategy.value}: {outcome.schedules} schedules{done}, {outcome.transitions} transitions, "
          f"{outcome.states} states in {elapsed:.1f} s ({rate:,.1f} schedules/s, {states:,.0f} states/s)")


def _print_violation(outcome: Outcome, token: str) -> None:
    assert outcome.violation is not None
    print(f"\nVIOLATION {outcome.violation}\n")
    print("trace (who sent what, who stepped):")
    for line in compress_trace(outcome.trace):
        print(f"  {line}")
    print(f"\nreplay: drona verify --replay {token}")


def compress_trace(trace: list[str]) -> list[str]:
    """Runs of clock steps become one line, so the messages stand out."""
    out: list[str] = []
    run: list[str] = []
    for line in trace:
        step = re.match(r"^(\S+) steps to (\d+) \(battery (\d+)\)$", line)
        if step:
            run.append(f"{step[1]}@{step[2]}")
            continue
        if run:
            out.append("steps " + " ".join(run))
            run = []
        out.append(line)
    if run:
        out.append("steps " + " ".join(run))
    return out


def _progress(quiet: bool, console: Console) -> Progress:
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), TextColumn("{task.completed} schedules"),
                    TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), console=console, disable=quiet,
                    transient=True)
