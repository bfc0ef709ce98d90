"""``drona audit --workspace W RECORD...``: judge a recorded run (``--record`` files).

Prints each drone's steps and gaps, then every separation violation (collision
or swap under the run's Delta, obstacle, out of bounds), the conformance to
the plan (steps flown in the planned cell, the worst deviation) and the
continuity (moves of more than one cell per step). ``--json`` prints one JSON
object instead. Exit 0 when safe and within ``--min-conformance`` and
``--max-jumps``, 1 otherwise, 2 on unusable input.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from drona_gcs.audit import MIN_CONFORMANCE, Audit, audit
from drona_gcs.errors import DronaError
from drona_gcs.workspace_files import load_workspace


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("records", nargs="+", type=Path, help="JSON Lines files written by --record")
    parser.add_argument("--workspace", required=True, help="the workspace the run flew in")
    parser.add_argument("--min-conformance", type=_fraction, default=MIN_CONFORMANCE,
                        help=f"least share of planned steps flown in the planned cell (default {MIN_CONFORMANCE:g})")
    parser.add_argument("--max-jumps", type=_count, default=0,
                        help="most moves of more than one cell per step (default 0)")
    parser.add_argument("--json", action="store_true", help="print the verdict as one JSON object")


def run(args: argparse.Namespace) -> int:
    try:
        workspace = load_workspace(args.workspace)
        result = audit(workspace, read_records(args.records))
    except (DronaError, OSError) as exc:
        print(f"drona audit: {exc}", file=sys.stderr)
        return 2
    broken = result.broken(args.min_conformance, args.max_jumps)
    if args.json:
        print(json.dumps(_verdict(result, broken)))
    else:
        _print(result, broken)
    return 1 if broken else 0


def _print(result: Audit, broken: list[str]) -> None:
    for drone, trajectory in sorted(result.trajectories.items()):
        print(f"{drone}: steps {trajectory.start_step}..{trajectory.end_step}, "
              f"{result.gaps[drone]} without a record")
    for violation in result.violations:
        print(f"VIOLATION {violation}")
    for jump in result.jumps:
        print(f"JUMP {jump}")
    conformance = result.conformance
    worst = conformance.worst
    print(f"conformance: {conformance.planned_steps - len(conformance.deviations)} of "
          f"{conformance.planned_steps} planned steps in the planned cell ({conformance.fraction:.1%})"
          + (f", worst: {worst}" if worst else ""))
    print(f"{len(result.trajectories)} drones, delta {result.delta}: "
          f"{'safe' if result.safe else f'{len(result.violations)} violations'}, "
          f"{len(result.jumps)} jumps" + (f"; BROKEN: {'; '.join(broken)}" if broken else ""))


def _verdict(result: Audit, broken: list[str]) -> dict[str, Any]:
    conformance = result.conformance
    worst = conformance.worst
    return {
        "ok": not broken,
        "broken": broken,
        "delta": result.delta,
        "drones": {drone: {"first_step": t.start_step, "last_step": t.end_step, "gaps": result.gaps[drone]}
                   for drone, t in sorted(result.trajectories.items())},
        "violations": [str(v) for v in result.violations],
        "conformance": {
            "planned_steps": conformance.planned_steps,
            "in_planned_cell": conformance.planned_steps - len(conformance.deviations),
            "fraction": conformance.fraction,
            "worst_cells": worst.cells if worst else 0,
            "worst": str(worst) if worst else None,
        },
        "jumps": [str(j) for j in result.jumps],
    }


def _fraction(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not a fraction between 0 and 1")
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text} is negative")
    return value


def read_records(paths: list[Path]) -> Iterator[dict[str, object]]:
    """The records of ``--record`` files, blank lines skipped (``drona replay`` reads them too)."""
    for path in paths:
        with path.open(encoding="utf-8") as lines:
            for number, line in enumerate(lines, 1):
                if not line.strip():
                    continue
                try:
                    record = json.loads(line)
                except json.JSONDecodeError as exc:
                    raise DronaError(f"{path}:{number}: not JSON: {exc.msg}") from exc
                if not isinstance(record, dict):  # the audit reads fields: a list or a number has none
                    raise DronaError(f"{path}:{number}: not a JSON object: {line.strip()[:40]}")
                yield record
