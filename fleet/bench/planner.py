"""``drona bench planner``: the paper's planner workload (Tables 1 and 2), timed in CPU time.

For each grid size W and drone count R of Table 2, at Delta 0 and 1: a random
W x W grid with 20% obstacles (pockets filled), R drones at random free
cells, and a stream of tasks (see :mod:`drona_gcs.workload`). Each plan
is timed with the process CPU clock, and the mean is set beside the paper's
figure and our target of 1/50 of it. Table 1's cells run the Z3 generator.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import drona_gcs.planner as planner_module
from drona_gcs.errors import NoPlanFound
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.workload import TaskStream, random_workspace
from fleet import runtime
from fleet.bench import plot as bench_plot

#: Table 2 of the paper: mean seconds per plan of their A* plan generator, by (W, R).
PAPER_ASTAR: dict[tuple[int, int], float] = {
    (16, 4): 0.0174, (32, 4): 0.0179, (64, 4): 0.0215, (128, 4): 0.0518, (256, 4): 0.1485,
    (16, 8): 0.0179, (32, 8): 0.0184, (64, 8): 0.0249, (128, 8): 0.0837, (256, 8): 0.2651,
    (16, 16): 0.0187, (32, 16): 0.0206, (64, 16): 0.0318, (128, 16): 0.0884, (256, 16): 0.3038,
    (32, 32): 0.0247, (64, 32): 0.0435, (128, 32): 0.1007, (256, 32): 0.3186,
    (64, 64): 0.0666, (128, 64): 0.1538, (256, 64): 0.3882,
    (128, 128): 0.2293, (256, 128): 0.5159,
}
#: Table 1: mean seconds per plan of their Z3 plan generator.
PAPER_SMT: dict[tuple[int, int], float] = {
    (16, 4): 0.66, (32, 4): 3.5, (64, 4): 15.4, (16, 8): 0.9, (32, 8): 8.5, (64, 8): 33.55,
    (32, 16): 44.6, (64, 16): 138.0,
}
TARGET_FACTOR = 50


@dataclass(frozen=True)
class Row:
    planner: str
    grid: int
    drones: int
    delta: int
    plans: int
    mean_ms: float
    median_ms: float
    p99_ms: float
    failures: int
    paper_ms: float
    target_ms: float
    speedup: float
    meets_target: bool
    #: whether the planner ran its mypyc-compiled modules (``drona_gcs.planner.NATIVE``)
    compiled: bool = field(default_factory=lambda: planner_module.NATIVE)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tasks", type=int, help="tasks per cell (default 300; 40 with --quick: Z3 on 16x16 only)")
    parser.add_argument("--smt-tasks", type=int, default=5, help="tasks per Z3 cell (default 5)")
    parser.add_argument("--grids", help="comma-separated grid sizes to run (default: all of Table 2)")
    parser.add_argument("--drones", help="comma-separated drone counts to run (default: all)")
    parser.add_argument("--deltas", default="0,1", help="skew windows to run (default 0,1)")
    parser.add_argument("--no-smt", action="store_true", help="skip the Z3 generator (Table 1)")


def run(args: argparse.Namespace) -> int:
    try:
        grids = _ints(args.grids) if args.grids else None
        drones = _ints(args.drones) if args.drones else None
        deltas = _ints(args.deltas)
    except ValueError as exc:
        print(f"drona bench: {exc}", file=sys.stderr)
        return 2
    tasks = args.tasks or (40 if args.quick else 300)
    cells = [(w, r) for (w, r) in PAPER_ASTAR if (grids is None or w in grids) and (drones is None or r in drones)]
    cells.sort()
    if not args.json:
        _print_header()
    rows = [bench_astar(w, r, d, tasks, args.seed) for d in deltas for (w, r) in cells]
    for row in rows:
        _emit(row, args.json)
    smt_rows: list[Row] = []
    if not args.no_smt:
        smt_cells = [(16, 4)] if args.quick else sorted(PAPER_SMT)
        smt_cells = [(w, r) for (w, r) in smt_cells if (grids is None or w in grids)
                     and (drones is None or r in drones)]
        for w, r in smt_cells:
            smt_rows.append(bench_smt(w, r, args.smt_tasks, args.seed))
            _emit(smt_rows[-1], args.json)
    if not args.json:
        met = sum(r.meets_target for r in rows)
        print(f"\nA* cells meeting 1/{TARGET_FACTOR} of the paper: {met}/{len(rows)}")
    if rows or smt_rows:
        bench_plot.write(args, "planner", rows + smt_rows)
    return 0


def bench_astar(width: int, drones: int, delta: int, tasks: int, seed: int) -> Row:
    rng = random.Random(f"{seed}-{width}-{drones}-{delta}")
    ws = random_workspace(width, width, rng)
    planner = SafePlanner(ws, delta=delta, fleet_size=drones)
    return _measure("astar", width, drones, delta, ws, rng, tasks,
                    lambda t: planner.plan(t.start, t.goal, t.start_step, t.others).trajectory,
                    PAPER_ASTAR[(width, drones)])


def bench_smt(width: int, drones: int, tasks: int, seed: int) -> Row:
    from drona_gcs.planner.smt import plan_smt

    rng = random.Random(f"{seed}-{width}-{drones}-smt")
    ws = random_workspace(width, width, rng)
    return _measure("smt", width, drones, 0, ws, rng, tasks,
                    lambda t: plan_smt(ws, t.start, t.goal, t.start_step, t.others, 0).trajectory,
                    PAPER_SMT[(width, drones)])


def _measure(name: str, width: int, drones: int, delta: int, ws: object, rng: random.Random, tasks: int,
             plan: Callable[..., Trajectory], paper_s: float) -> Row:
    stream = TaskStream(ws, drones, rng)  # type: ignore[arg-type]
    # As the agent does after start-up: the planner's tables live for good (pauses of several ms at 256x256).
    runtime.settle_gc()
    times: list[float] = []
    failures = 0
    for _ in range(tasks):
        task = stream.next_task()
        started = time.process_time()
        try:
            traj: Trajectory | None = plan(task)
        except NoPlanFound:
            traj, failures = None, failures + 1
        times.append((time.process_time() - started) * 1000)
        stream.complete(task, traj)
    times.sort()
    mean = statistics.fmean(times)
    paper_ms = paper_s * 1000
    target = paper_ms / TARGET_FACTOR
    return Row(name, width, drones, delta, tasks, round(mean, 3), round(statistics.median(times), 3),
               round(times[min(len(times) - 1, int(0.99 * len(times)))], 3), failures, paper_ms,
               round(target, 3), round(paper_ms / mean, 1) if mean else float("inf"), mean <= target)


def _print_header() -> None:
    how = "compiled (mypyc)" if planner_module.NATIVE else "pure Python (slower: see README, Benchmark)"
    print(f"planner modules: {how}")
    print(f"{'planner':7} {'grid':>7} {'R':>4} {'D':>2} {'plans':>5} {'mean ms':>9} {'median':>8} "
          f"{'p99':>8} {'fails':>5} {'paper ms':>9} {'target':>7} {'x paper':>8}  ok")


def _emit(row: Row, as_json: bool) -> None:
    if as_json:
        print(json.dumps(asdict(row)), flush=True)
        return
    grid = f"{row.grid}x{row.grid}"
    print(f"{row.planner:7} {grid:>7} {row.drones:>4} {row.delta:>2} {row.plans:>5} {row.mean_ms:>9.3f} "
          f"{row.median_ms:>8.3f} {row.p99_ms:>8.3f} {row.failures:>5} {row.paper_ms:>9.1f} "
          f"{row.target_ms:>7.3f} {row.speedup:>8.1f}  {_verdict(row)}", flush=True)


def _verdict(row: Row) -> str:
    """The 1/50 target is for the A* generator; Z3 is the paper's baseline, shown for the ratio."""
    if row.planner != "astar":
        return "baseline"
    return "yes" if row.meets_target else "NO"


def _ints(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"expected comma-separated integers, got {text!r}") from None
