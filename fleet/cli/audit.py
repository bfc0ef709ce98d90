"""``drona audit --workspace W RECORD...``: judge a recorded run (``--record`` files) for collisions.

Prints each drone's steps and gaps, then every violation (collision or swap
under the run's Delta, obstacle, out of bounds). Exit 0 safe, 1 violations
found, 2 unusable input.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from pathlib import Path

from drona_gcs.audit import audit
from drona_gcs.errors import DronaError
from drona_gcs.workspace_files import load_workspace


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("records", nargs="+", type=Path, help="JSON Lines files written by --record")
    parser.add_argument("--workspace", required=True, help="the workspace the run flew in")


def run(args: argparse.Namespace) -> int:
    try:
        workspace = load_workspace(args.workspace)
        result = audit(workspace, _records(args.records))
    except (DronaError, OSError) as exc:
        print(f"drona audit: {exc}", file=sys.stderr)
        return 2
    for drone, trajectory in sorted(result.trajectories.items()):
        print(f"{drone}: steps {trajectory.start_step}..{trajectory.end_step}, "
              f"{result.gaps[drone]} without a record")
    for violation in result.violations:
        print(f"VIOLATION {violation}")
    print(f"{len(result.trajectories)} drones, delta {result.delta}: "
          f"{'safe' if result.safe else f'{len(result.violations)} violations'}")
    return 0 if result.safe else 1


def _records(paths: list[Path]) -> Iterator[dict[str, object]]:
    for path in paths:
        with path.open(encoding="utf-8") as lines:
            for number, line in enumerate(lines, 1):
                if not line.strip():
                    continue
                try:
                    yield json.loads(line)
                except json.JSONDecodeError as exc:
                    raise DronaError(f"{path}:{number}: not JSON: {exc.msg}") from exc
