"""The simulator's own flight record: each vehicle's cell at each step, from its physics."""

from __future__ import annotations

import io
import json

from drona_gcs.audit import audit
from drona_gcs.geo import GeoFrame, Ned
from drona_gcs.workspace import Cell, Workspace
from fleet.sim.truth import TruthRecord

WS = Workspace.build(size=(6, 3, 1), cell_size_m=2.0, tau_s=0.5, drones={"a": (0, 0, 0), "b": (5, 0, 0)})
FRAME = GeoFrame(WS)


def over(cell: Cell, east: float = 0.0) -> Ned:
    """A point in ``cell`` at flying height, ``east`` metres east of its centre."""
    centre = FRAME.cell_to_ned(cell)
    return Ned(centre.north, centre.east + east, centre.down)


def flown(ticks: list[tuple[float, Cell, Cell]]) -> list[dict[str, object]]:
    """The lines written for vehicles a and b at (Unix time, a's cell, b's cell) ticks."""
    out = io.StringIO()
    truth = TruthRecord(FRAME, ["a", "b"], 0.0, out)
    for wall, a, b in ticks:
        truth.observe(wall, [over(a), over(b)])
    return [json.loads(line) for line in out.getvalue().splitlines()]


def test_a_line_per_vehicle_as_each_step_begins_with_the_cells_passed_in_between() -> None:
    """a crosses (1,0,0) and (2,0,0) within step 1: the line of step 2 names them; b stays put."""
    lines = flown([(0.5, (0, 0, 0), (5, 0, 0)), (0.6, (1, 0, 0), (5, 0, 0)), (0.8, (2, 0, 0), (5, 0, 0)),
                   (1.0, (3, 0, 0), (5, 0, 0)), (1.2, (3, 0, 0), (5, 0, 0))])
    assert [(r["step"], r["drone"], r["cell"], r.get("via")) for r in lines] == [
        (1, "a", [0, 0, 0], None), (1, "b", [5, 0, 0], None),
        (2, "a", [3, 0, 0], [[1, 0, 0], [2, 0, 0]]), (2, "b", [5, 0, 0], None)]
    assert all(r["planned"] is None and r["delta"] == 0 for r in lines)


def test_its_audit_finds_two_vehicles_that_passed_through_one_cell_within_a_step() -> None:
    """b darts through (2,0,0) within step 1, where a stays: the lines alone (at the boundaries) never
    put them together, the cells passed do."""
    ticks = [(0.5, (2, 0, 0), (4, 0, 0)), (0.7, (2, 0, 0), (3, 0, 0)), (0.8, (2, 0, 0), (2, 0, 0)),
             (0.9, (2, 0, 0), (3, 0, 0)), (1.0, (2, 0, 0), (4, 0, 0))]
    verdict = audit(WS, flown(ticks))
    assert {(v.kind.value, v.cell) for v in verdict.violations} == {("collision", (2, 0, 0))}
    apart = [(wall, a, (4, 0, 0)) for wall, a, _ in ticks]
    assert audit(WS, flown(apart)).safe
