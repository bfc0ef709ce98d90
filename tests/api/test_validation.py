"""Mail requests checked against the workspace and the drones' own energy rule."""

from __future__ import annotations

import pytest

from api.errors import IllegalTransition
from api.lifecycle import TRANSITIONS, Status, check_transition
from api.validation import MailChecker
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.stack.mail import MailPlanner, MailRejected, MailRequest
from drona_gcs.workspace import Workspace


def corridor(chargers: tuple[tuple[int, int, int], ...] = ((0, 0, 0),)) -> Workspace:
    return Workspace.build(size=(60, 1, 1), charging_stations=chargers)


def small_battery_checker(ws: Workspace) -> MailChecker:
    """A battery of 75 steps, so the corridor's far ends are out of reach."""
    return MailChecker(ws, BatteryModel(drain_per_step=1.0), lead_steps=2)


def test_cells_are_checked_in_turn(workspace: Workspace) -> None:
    checker = MailChecker(workspace)
    assert checker.check((1, 1, 0), (7, 6, 0)) == []
    [problem] = checker.check((1, 1, 0), (0, 8, 0))
    assert (problem.field, problem.kind) == ("dropoff", "out_of_bounds") and "[0, 8, 0]" in problem.message
    kinds = [(p.field, p.kind) for p in checker.check((4, 4, 0), (9, 4, 0))]
    assert kinds == [("pickup", "obstacle"), ("dropoff", "unreachable")]


def test_chargers_and_parking_cells_are_refused_as_the_drones_refuse_them() -> None:
    ws = Workspace.build(size=(8, 8, 1), charging_stations=((0, 0, 0),), parking=((7, 7, 0),))
    checker = MailChecker(ws)
    kinds = [(p.field, p.kind) for p in checker.check((0, 0, 0), (7, 7, 0))]
    assert kinds == [("pickup", "rest_spot"), ("dropoff", "rest_spot")]
    assert checker.check((1, 0, 0), (6, 7, 0)) == []


def test_the_energy_rule_is_the_drones_own() -> None:
    """Accepted exactly when a drone's mail planner, charged at a station, does not reject it."""
    ws = corridor()
    checker = small_battery_checker(ws)
    for pickup_x in range(1, 60, 3):
        for dropoff_x in range(1, 60, 7):
            if pickup_x == dropoff_x:
                continue
            pickup, dropoff = (pickup_x, 0, 0), (dropoff_x, 0, 0)
            planner = MailPlanner((0, 0, 0), ws.charging_stations, (), checker.distance, checker.battery,
                                  leg_overhead=checker.leg_overhead)
            planner.assign(MailRequest("x", pickup, dropoff, 5))
            rejected = any(isinstance(a, MailRejected) for a in planner.decide(0, planner.recharged_level, ()))
            assert bool(checker.check(pickup, dropoff)) == rejected, (pickup, dropoff)


def test_the_energy_problem_blames_the_pickup_or_the_dropoff() -> None:
    checker = small_battery_checker(corridor())
    [far_pickup] = checker.check((50, 0, 0), (49, 0, 0))
    assert (far_pickup.field, far_pickup.kind) == ("pickup", "energy")
    assert "a full battery gives" in far_pickup.message
    [far_dropoff] = checker.check((2, 0, 0), (45, 0, 0))
    assert (far_dropoff.field, far_dropoff.kind) == ("dropoff", "energy")


def test_without_chargers_there_is_no_energy_rule() -> None:
    assert small_battery_checker(corridor(chargers=())).check((50, 0, 0), (59, 0, 0)) == []


def test_distances_and_paths_go_around_obstacles(workspace: Workspace) -> None:
    checker = MailChecker(workspace)
    assert checker.distance((3, 3, 0), (6, 3, 0)) == 7  # around the wall x=4..5, y=2..5
    path = checker.path((3, 3, 0), (6, 3, 0))
    assert path[0] == (3, 3, 0) and path[-1] == (6, 3, 0) and len(path) == 8
    assert not set(path) & workspace.obstacles


def test_every_transition_outside_the_table_is_refused_naming_both() -> None:
    for current in Status:
        for wanted in Status:
            if wanted in TRANSITIONS[current]:
                check_transition("m", current, wanted)
            else:
                with pytest.raises(IllegalTransition, match=f"is {current.value}: it cannot become {wanted.value}"):
                    check_transition("m", current, wanted)
    assert TRANSITIONS[Status.PICKED_UP] == {Status.DELIVERED, Status.FAILED}
