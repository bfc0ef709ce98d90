"""The workspace model: cell ids, delta and lambda, and the checks of a workspace built without a file.
"""

from __future__ import annotations

import itertools

import pytest

from drona_gcs.errors import WorkspaceError
from drona_gcs.workspace import Cell, GeoOrigin, VehicleLimits, Workspace
from drona_gcs.workspace_files import workspace_from_mapping


# ------------------------------------------------------------ cell ids, delta
@pytest.mark.parametrize("size", [(5, 4, 1), (1, 7, 1), (4, 3, 2), (3, 5, 4)])
def test_cell_ids_are_unique_dense_and_invertible(size: Cell) -> None:
    ws = Workspace(size=size)
    cells = list(itertools.product(range(size[0]), range(size[1]), range(size[2])))
    ids = [ws.cell_id(c) for c in cells]
    assert sorted(ids) == list(range(ws.num_cells)) == list(range(len(cells)))
    assert all(ws.cell_of_id(ws.cell_id(c)) == c for c in cells)
    assert all(ws.cell_id(ws.cell_of_id(i)) == i for i in range(ws.num_cells))


def test_cell_ids_run_along_x_then_y_then_z() -> None:
    ws = Workspace(size=(4, 3, 2))
    assert [ws.cell_id(c) for c in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (3, 2, 1)]] == [0, 1, 4, 12, 23]


@pytest.mark.parametrize("bad_id", [-1, 24, 1000])
def test_cell_of_id_out_of_range(bad_id: int) -> None:
    with pytest.raises(WorkspaceError, match=f"cell id {bad_id} is outside 0..23"):
        Workspace(size=(4, 3, 2)).cell_of_id(bad_id)


def test_neighbours_are_the_free_cells_one_move_away_of_any_cell() -> None:
    """Free cells, obstacles and cells outside alike (a search may ask about either end)."""
    ws = Workspace(size=(4, 3, 2), obstacles=frozenset({(1, 1, 0), (2, 0, 1)}))
    moves = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    for cell in itertools.product(range(-1, 5), range(-1, 4), range(-1, 3)):
        around = [(cell[0] + dx, cell[1] + dy, cell[2] + dz) for dx, dy, dz in moves]
        expected = [c for c in around if ws.in_bounds(c) and c not in ws.obstacles]
        assert list(ws.neighbours(cell)) == expected, cell
        assert list(ws.neighbours(cell)) == expected, cell  # and again, once worked out


@pytest.mark.parametrize(("beta", "tau", "delta"), [
    (0.0, 0.1, 0),
    (0, 1.0, 0),
    (0.3, 0.1, 3),  # 0.3 / 0.1 == 2.9999999999999996
    (0.1 + 0.2, 0.1, 4),  # beta is 0.30000000000000004 > 0.3: round up, the safe side
    (1e-10, 1.0, 1),  # any positive skew needs a window
    (0.2, 0.1, 2),
    (0.6, 0.2, 3),  # 2.9999999999999996
    (0.7, 0.1, 7),  # 6.999999999999999
    (0.25, 0.1, 3),
    (0.01, 1.0, 1),
    (1.0, 1.0, 1),
    (1.5, 1.0, 2),
    (2.0, 0.5, 4),
])
def test_delta_is_ceil_beta_over_tau_for_a_vehicle_never_late(beta: float, tau: float, delta: int) -> None:
    assert Workspace.build(size=(2, 2, 1), beta_s=beta, tau_s=tau, lambda_s=0.0).delta == delta


@pytest.mark.parametrize(("beta", "lam", "tau", "delta"), [
    (0.2, 1.882, 0.5, 5),  # ArduCopter's defaults at tau 0.5 s
    (0.05, 2.345, 1.0, 3),  # the demo campus
    (0.1, 0.2, 0.1, 3),  # 0.30000000000000004 / 0.1 in floats
    (0.0, 0.5, 0.5, 1),
])
def test_delta_widens_by_the_vehicles_lateness(beta: float, lam: float, tau: float, delta: int) -> None:
    assert Workspace.build(size=(2, 2, 1), beta_s=beta, tau_s=tau, lambda_s=lam).delta == delta


@pytest.mark.parametrize(("cell", "layer", "layers", "lateness"), [
    (1.0, 1.0, 1, 1.0 + 0.25 + 0.632),  # shaping lag, jerk ramp, half a metre at 2.5 m/s²
    (3.0, 3.0, 1, 1.0 + 0.25 + 1.095),
    (0.1, 1.0, 2, 0.4 + 0.1 + 1.0),  # half a metre up at 1 m/s² takes longer than 5 cm across
    (100.0, 1.0, 1, 1.0 + 0.25 + 4.0 + 3.0),  # 20 m to reach 10 m/s, then 30 m at it
])
def test_lambda_defaults_to_the_shaping_lag_and_half_a_cell_from_rest(cell: float, layer: float, layers: int,
                                                                      lateness: float) -> None:
    ws = Workspace.build(size=(2, 2, layers), cell_size_m=cell, geo=GeoOrigin(layer_height_m=layer))
    assert ws.lateness_s == pytest.approx(lateness, abs=1e-3)


def test_lambda_derives_from_the_vehicles_the_workspace_says_it_flies() -> None:
    """Quicker vehicles are less late: at ArduCopter's WPNAV_ACCEL 500 and PSC_JERK_XY 20 (the top of
    both ranges), 1 m cells are entered 1.072 s late at most, and Delta at tau 0.5 s, beta 0.2 s is 3, not 5."""
    quick = VehicleLimits(accel_m_s2=5.0, jerk_m_s3=20.0)
    ws = Workspace.build(size=(2, 2, 1), tau_s=0.5, beta_s=0.2, vehicle=quick)
    assert ws.lateness_s == pytest.approx(0.5 + 0.125 + 0.447, abs=1e-3)
    assert (ws.delta, Workspace.build(size=(2, 2, 1), tau_s=0.5, beta_s=0.2).delta) == (3, 5)
    assert workspace_from_mapping({"size": [2, 2, 1], "vehicle": {"accel_m_s2": 5, "jerk_m_s3": 20}}).vehicle == quick


def test_a_set_lambda_wins_and_a_bad_one_is_named() -> None:
    assert Workspace.build(size=(2, 2, 1), lambda_s=0.0).lateness_s == 0.0
    with pytest.raises(WorkspaceError, match="lambda_s"):
        Workspace.build(size=(2, 2, 1), lambda_s=-1.0)


def test_build_rejects_an_invalid_workspace_without_a_file() -> None:
    with pytest.raises(WorkspaceError) as info:
        Workspace.build(size=(3, 3, 1), obstacles=frozenset({(1, 1, 0)}), drones={"d": (1, 1, 0)})
    assert str(info.value) == "drones.d: cell [1, 1, 0] is on an obstacle"


def test_with_drones_validates_the_new_starts() -> None:
    ws = Workspace.build(size=(3, 3, 1), obstacles=frozenset({(1, 1, 0)}))
    assert ws.with_drones({"d": (0, 0, 0)}).drones == {"d": (0, 0, 0)}
    with pytest.raises(WorkspaceError) as info:
        ws.with_drones({"d": (0, 0, 0), "e": (1, 1, 0)})
    assert str(info.value) == "drones.e: cell [1, 1, 0] is on an obstacle"
