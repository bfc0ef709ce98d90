"""The replay document of a flown run: frames, the audit's findings and the workspace's geometry.

``drona replay`` serves it as JSON to a page that plays the run back on a map
(``api/static/replay.html``). Nothing here judges the run anew: the findings
are :func:`drona_gcs.audit.audit`'s, the very ones ``drona audit`` prints.

Document::

    {"workspace": {"name", "size", "cell_size_m", "tau_s", "delta",
                   "grid": {"south", "west", "north", "east"},   # the grid's outer corners, WGS84
                   "layers_alt_m": [...],                        # AMSL of each layer's centre
                   "obstacles", "charging_stations", "parking", "pickups", "dropoffs": [[x, y, z], ...]},
     "first_step": s0, "last_step": s1,
     "drones": ["d1", ...],
     "frames": [{"step": k, "drones": {"d1": {"cell": [x, y, z], "planned": [x, y, z] | null,
                                              "seen": bool}}}, ...],
     "findings": [{"kind", "family", "step", "drones", "cells", "text"}, ...],
     "summary": {"safe", "violations", "deviations", "jumps", "conformance", "planned_steps", "gaps"}}

The map is the local tangent plane of :mod:`drona_gcs.geo`, in which latitude
grows linearly with north and longitude with east, so a page places cell
``(x, y)`` exactly by interpolating between the grid's corners. A drone before
its first record and after its last sits at its first and last cell, as the
safety checker holds it (``seen`` false), and so does a step it has no record of.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping
from typing import Any, cast

from drona_gcs.audit import Audit, audit
from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.safety import Violation, ViolationKind
from drona_gcs.workspace import Cell, Workspace

#: which family each finding belongs to, as the page groups them
SEPARATION = "separation"
CONFORMANCE = "conformance"
CONTINUITY = "continuity"

Json = dict[str, Any]


def replay_document(workspace: Workspace, records: Iterable[Mapping[str, object]]) -> Json:
    """The document of a run; :class:`ProblemError` for a malformed record or one of another workspace."""
    listed = list(records)
    if not listed:
        raise ProblemError("no records: the run recorded no step")
    result = audit(workspace, listed)  # validates every record's fields
    _check_workspace(workspace, listed)
    seen = _seen(listed)
    first = min(t.start_step for t in result.trajectories.values())
    last = max(t.end_step for t in result.trajectories.values())
    return {
        "workspace": geometry(workspace, result.delta),
        "first_step": first,
        "last_step": last,
        "drones": sorted(result.trajectories),
        "frames": [_frame(result, seen, step) for step in range(first, last + 1)],
        "findings": findings(result),
        "summary": _summary(result),
    }


def geometry(workspace: Workspace, delta: int) -> Json:
    """What a page needs to draw the workspace on its real coordinates."""
    frame = GeoFrame(workspace)
    nx, ny, nz = workspace.size
    size = workspace.cell_size_m
    south_west = frame.ned_to_global(Ned(0.0, 0.0, 0.0))
    north_east = frame.ned_to_global(Ned(ny * size, nx * size, 0.0))
    return {
        "name": workspace.name,
        "size": [nx, ny, nz],
        "cell_size_m": size,
        "tau_s": workspace.tau_s,
        "delta": delta,
        "grid": {"south": south_west.lat, "west": south_west.lon, "north": north_east.lat, "east": north_east.lon},
        "layers_alt_m": [frame.origin.alt_m + frame.layer_height_m(z) for z in range(nz)],
        "obstacles": _cells(sorted(workspace.obstacles)),
        "charging_stations": _cells(workspace.charging_stations),
        "parking": _cells(workspace.parking),
        "pickups": _cells(workspace.pickups),
        "dropoffs": _cells(workspace.dropoffs),
    }


def findings(result: Audit) -> list[Json]:
    """Every violation, deviation from the plan and jump the audit found, by step."""
    found = [_violation(result, v) for v in result.violations]
    found += [_finding("deviation", CONFORMANCE, d.step, [d.drone], [d.flown, d.planned], str(d))
              for d in result.conformance.deviations]
    found += [_finding("jump", CONTINUITY, j.step, [j.drone], [j.before, j.after], str(j)) for j in result.jumps]
    found.sort(key=lambda f: (f["step"], f["family"] != SEPARATION, f["drones"]))
    return found


def _check_workspace(workspace: Workspace, records: list[Mapping[str, object]]) -> None:
    """An agent records only its workspace's drones, in its grid: anything else is a record of another one."""
    known = set(workspace.drones)
    for number, record in enumerate(records, 1):
        drone, cell = record["drone"], record["cell"]
        if known and drone not in known:
            raise ProblemError(f"record {number}: drone {drone!r} is not in workspace {workspace.name!r} "
                               f"(it has {', '.join(sorted(known))}): a record of another workspace?")
        if isinstance(cell, list) and not workspace.in_bounds((cell[0], cell[1], cell[2])):
            raise ProblemError(f"record {number}: cell {cell} is outside the grid {list(workspace.size)} of "
                               f"workspace {workspace.name!r}: a record of another workspace?")


def _seen(records: list[Mapping[str, object]]) -> dict[str, dict[int, object]]:
    """Per drone, per recorded step: its planned cell (None when it had no plan)."""
    seen: dict[str, dict[int, object]] = defaultdict(dict)
    for record in records:
        seen[cast(str, record["drone"])][cast(int, record["step"])] = record.get("planned")
    return seen


def _frame(result: Audit, seen: Mapping[str, Mapping[int, object]], step: int) -> Json:
    drones = {}
    for drone, trajectory in sorted(result.trajectories.items()):
        recorded = seen[drone]
        drones[drone] = {"cell": list(trajectory.at(step)), "planned": recorded.get(step),
                         "seen": step in recorded}
    return {"step": step, "drones": drones}


def _violation(result: Audit, v: Violation) -> Json:
    if v.other is not None:  # check_fleet names the pair "a~b"
        drones = v.other.split("~")
        cells = [v.cell]
        if v.kind is ViolationKind.SWAP:
            cells.append(result.trajectories[drones[0]].at(v.step + 1))
    else:  # obstacle or out of the grid: whoever was in that cell then
        drones = [d for d, t in sorted(result.trajectories.items()) if t.at(v.step) == v.cell]
        cells = [v.cell]
    return _finding(v.kind.value, SEPARATION, v.step, drones, cells, str(v))


def _finding(kind: str, family: str, step: int, drones: list[str], cells: list[Cell], text: str) -> Json:
    return {"kind": kind, "family": family, "step": step, "drones": drones, "cells": _cells(cells), "text": text}


def _summary(result: Audit) -> Json:
    conformance = result.conformance
    return {
        "safe": result.safe,
        "violations": len(result.violations),
        "deviations": len(conformance.deviations),
        "jumps": len(result.jumps),
        "conformance": conformance.fraction,
        "planned_steps": conformance.planned_steps,
        "gaps": dict(sorted(result.gaps.items())),
    }


def _cells(cells: Iterable[Cell]) -> list[list[int]]:
    return [list(c) for c in cells]
