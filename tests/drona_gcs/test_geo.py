"""Geo-referencing: cells to NED and WGS84 and back, and the speed check."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drona_gcs.errors import WorkspaceError
from drona_gcs.geo import GeoFrame, GeoPoint, Ned, check_flyable, check_speed
from drona_gcs.workspace import GeoOrigin, VehicleLimits, Workspace

WS = Workspace.build(size=(40, 30, 3), cell_size_m=5.0, tau_s=2.0,
                     geo=GeoOrigin(lat=37.8716, lon=-122.2727, alt_m=52.0, layer0_alt_m=10.0, layer_height_m=4.0))
FRAME = GeoFrame(WS)


def test_axes_are_documented_ned() -> None:
    centre = FRAME.cell_to_ned((0, 0, 0))
    assert (centre.north, centre.east, centre.down) == (2.5, 2.5, -10.0)
    moved = FRAME.cell_to_ned((3, 1, 2))  # 3 cells east, 1 north, 2 layers up
    assert (moved.north, moved.east, moved.down) == (7.5, 17.5, -18.0)


def test_global_matches_a_known_distance() -> None:
    # 1000 m north and east of the origin: compare with the haversine distance on a sphere.
    point = FRAME.ned_to_global(Ned(1000.0, 1000.0, -10.0))
    lat1, lon1, lat2, lon2 = map(math.radians, (37.8716, -122.2727, point.lat, point.lon))
    a = math.sin((lat2 - lat1) / 2) ** 2 + math.cos(lat1) * math.cos(lat2) * math.sin((lon2 - lon1) / 2) ** 2
    assert 2 * 6371008.8 * math.asin(math.sqrt(a)) == pytest.approx(math.hypot(1000, 1000), rel=3e-3)
    assert point.alt_m == pytest.approx(62.0)
    assert point.lat > 37.8716 and point.lon > -122.2727  # north and east


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 39), st.integers(0, 29), st.integers(0, 2))
def test_cell_round_trips_through_global(x: int, y: int, z: int) -> None:
    fix = FRAME.locate_global(FRAME.cell_to_global((x, y, z)))
    assert fix.cell == (x, y, z)
    assert fix.error_m < 1e-6


@settings(max_examples=200, deadline=None)
@given(st.floats(0.01, 199.99), st.floats(0.01, 149.99), st.floats(-1.9, 1.9))
def test_a_position_gives_its_cell_and_distance(east: float, north: float, off: float) -> None:
    fix = FRAME.locate(Ned(north, east, -(14.0 + off)))  # layer 1 centre is 14 m up
    assert fix.cell == (int(east // 5), int(north // 5), 1)
    centre = FRAME.cell_to_ned(fix.cell)
    assert fix.error_m == pytest.approx(math.dist((north, east, -(14 + off)),
                                                  (centre.north, centre.east, centre.down)))


def test_outside_the_grid_has_no_cell() -> None:
    assert FRAME.locate(Ned(-1.0, 3.0, -10.0)).cell is None
    assert FRAME.locate_global(GeoPoint(0.0, 0.0, 0.0)).cell is None


def test_speed_check_refuses_a_grid_too_fast_for_the_vehicle() -> None:
    check_speed(WS, 2.5)  # 5 m cells every 2 s: exactly 2.5 m/s
    with pytest.raises(WorkspaceError, match=r"tau_s: one cell per tau needs 2.50 m/s .* at most 2.00"):
        check_speed(WS, 2.0)
    with pytest.raises(WorkspaceError, match="maximum speed must be > 0"):
        check_speed(WS, 0)


def test_a_workspace_whose_vehicles_cannot_fly_its_sweeps_is_refused_naming_the_limit() -> None:
    """A cell per tau, and half a cell from rest in a tau: 5 m cells and 4 m layers every 2 s need 2.5 m/s
    and 1.25 m/s² across, 2 m/s and 1 m/s² up and down; ArduCopter's default WPNAV_SPEED_DN (1.5 m/s) is
    too slow for the layers."""
    with pytest.raises(WorkspaceError, match=r"vehicle.descent_m_s: 1.5 m/s cannot fly 4 m a tau \(2 s\), which "
                                             r"needs 2.00 m/s"):
        check_flyable(WS)
    enough = VehicleLimits(speed_m_s=2.5, accel_m_s2=1.25, climb_m_s=2.0, descent_m_s=2.0, accel_z_m_s2=1.0)
    check_flyable(replace(WS, vehicle=enough))  # exactly enough
    check_flyable(Workspace.build(size=(40, 30, 1), cell_size_m=5.0, tau_s=2.0))  # no layers: none up or down
    for name in ("speed_m_s", "accel_m_s2", "climb_m_s", "descent_m_s", "accel_z_m_s2"):
        value = getattr(enough, name) * 0.96
        with pytest.raises(WorkspaceError, match=rf"vehicle.{name}: {value:g} "):
            check_flyable(replace(WS, vehicle=replace(enough, **{name: value})))
