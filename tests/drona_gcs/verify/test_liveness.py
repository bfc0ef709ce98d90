"""The systematic tester's liveness monitor: who waits for whom, what it excuses, from when its
bound runs, and regressions the sweeps found.
"""

from __future__ import annotations

import dataclasses

import pytest

from drona_gcs.stack.mail import MailPickedUp, MailRequest
from drona_gcs.verify.explore import Explorer, Scenario, Strategy
from drona_gcs.verify.monitors import Flier, Monitors, Violation
from drona_gcs.verify.world import Left, World, WorldConfig
from drona_gcs.workspace import Workspace


def test_a_liveness_counterexample_says_who_waits_for_whom() -> None:
    """(d) ends with each drone's protocol state, whom a coordinating one waits for and the mail it holds."""
    explorer = Explorer(Scenario(drones=2, requests=2, delta=1, seed=0))
    world = World(dataclasses.replace(explorer.config, liveness_steps=0), explorer.planner)
    with pytest.raises(Violation) as found:
        for _ in range(50):
            world.apply(world.enabled()[0])
    assert found.value.monitor == "d"
    text = str(found.value)
    assert "Wait-for: d" in text and all(f"{d} " in text.split("Wait-for:")[1] for d in explorer.config.drones)
    assert "holds ['m" in text and "battery" in text


def test_liveness_excuses_only_mail_the_vehicles_down_cut_off() -> None:
    """(d) excuses a mail only when no path joins it to its drop-off around obstacles and vehicles
    down; mail with a way through is still owed."""
    ws = Workspace.build(size=(5, 2, 1), obstacles=frozenset({(2, 1, 0)}))
    request = MailRequest("m", (1, 0, 0), (3, 0, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (4, 1, 0)), (request,), ("d0",), delta=0, liveness_steps=0)
    cut, aside = frozenset({(2, 0, 0)}), frozenset({(4, 1, 0)})
    at_start, at_pickup = {"d0": Flier((0, 0, 0), 100.0, 95.0)}, {"d0": Flier((1, 0, 0), 100.0, 95.0)}
    Monitors(config).liveness(1, blocked=cut, fleet=at_start)  # the corridor is cut: excused
    with pytest.raises(Violation, match=r"\(d\) mail \['m'\]"):
        Monitors(config).liveness(1, blocked=aside, fleet=at_start)
    carrying = Monitors(config)
    carrying.action("d0", MailPickedUp(request))
    with pytest.raises(Violation, match=r"\(d\)"):  # on board, the way to the drop-off is open
        carrying.liveness(1, blocked=aside, fleet=at_pickup)
    carrying.liveness(1, blocked=cut, fleet=at_pickup)
    carrying.liveness(1, blocked=frozenset({request.dropoff}), fleet=at_pickup)  # a vehicle down on the drop-off


def test_liveness_excuses_mail_no_drone_can_fly_once_a_vehicle_down_takes_its_charger() -> None:
    """A vehicle down on the charger a drone needed: with 3 steps of battery left it can deliver
    and reach the other charger only if that one is free."""
    ws = Workspace.build(size=(9, 1, 1), charging_stations=((0, 0, 0), (8, 0, 0)))
    request = MailRequest("m", (6, 0, 0), (7, 0, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((5, 0, 0), (8, 0, 0)), (request,), ("d0",), delta=0, liveness_steps=0)
    low = {"d0": Flier((5, 0, 0), 23.0, 95.0)}
    with pytest.raises(Violation, match=r"\(d\)"):
        Monitors(config).liveness(1, blocked=frozenset({(0, 0, 0)}), fleet=low)
    Monitors(config).liveness(1, blocked=frozenset({(8, 0, 0)}), fleet=low)


@pytest.mark.parametrize(("drones", "gone", "owed"), [
    (2, {"d0"}, False), (4, {"d0", "d3"}, False), (3, {"d0", "d1"}, False),
    (3, {"d0"}, True), (2, {"d1"}, True), (4, {"d2", "d3"}, True), (2, set(), True)])
def test_liveness_owes_mail_only_while_the_agents_up_may_plan(drones: int, gone: set[str], owed: bool) -> None:
    """Found by sweep 30552: of two drones, d0's agent crashed and never restarted, and d1 held the mail
    for good. A crash cannot be told from a partition: only a majority of the fleet's agents, or half of
    it with its first drone by name, may plan, and nothing is owed until such a side is up."""
    ws = Workspace.build(size=(5, 1, 1))
    request = MailRequest("m", (1, 0, 0), (3, 0, 0), 5)
    names = tuple(f"d{i}" for i in range(drones))
    config = WorldConfig(ws, names, tuple((i % 5, 0, 0) for i in range(drones)), (request,), (names[-1],), delta=0,
                         liveness_steps=0)
    in_service = {d: Flier((4, 0, 0), 100.0, 95.0) for d in names if d not in gone}
    if owed:
        with pytest.raises(Violation, match=r"\(d\) mail \['m'\]"):
            Monitors(config).liveness(1, fleet=in_service, agents_gone=frozenset(gone))
    else:
        Monitors(config).liveness(1, fleet=in_service, agents_gone=frozenset(gone))


@pytest.mark.parametrize("moves", [0, 1])
def test_liveness_holds_a_drone_whose_battery_affords_no_move_off_a_charger_as_down(moves: int) -> None:
    """A drone resting on the drop-off with the battery for less than one move (a leg's overhead and a
    step) never leaves it: the mail is excused. With one move more, it can, and the mail is owed."""
    ws = Workspace.build(size=(9, 1, 1), charging_stations=((0, 0, 0), (8, 0, 0)))
    request = MailRequest("m", (2, 0, 0), (4, 0, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((1, 0, 0), (4, 0, 0)), (request,), ("d0",), delta=0, liveness_steps=0)
    overhead = 3
    level = config.battery.safe_threshold + config.battery.drain_per_step * (overhead + moves) + 0.5
    fleet = {"d0": Flier((1, 0, 0), 100.0, 95.0, overhead), "d1": Flier((4, 0, 0), level, 95.0, overhead)}
    if moves:
        with pytest.raises(Violation, match=r"\(d\) mail \['m'\]"):
            Monitors(config).liveness(1, fleet=fleet)
    else:
        Monitors(config).liveness(1, fleet=fleet)


def test_the_liveness_bound_runs_from_the_fields_last_change() -> None:
    """Found by a crash sweep (seed 8003): a crashed agent's vehicle held a drop-off, and its restart
    came after (d)'s bound had run out, counted from the last request: the mail was owed at once."""
    world = Explorer(Scenario(drones=3, requests=0, delta=1, seed=2, crashes=1, partitions=1)).world()
    world.apply(("crash", 0))
    world.inflight = [m for m in world.inflight if not isinstance(m.message, Left)]  # as if every peer saw it
    world.steps = dict.fromkeys(world.config.drones, 40)
    world.apply(("restart", 0))
    assert world.last_injection_step == 40
    world.steps = dict.fromkeys(world.config.drones, 55)
    world.apply(("partition", 1))
    world.apply(("heal", 0))
    assert world.last_injection_step == 55


def test_a_drone_that_made_way_stays_out_until_the_peer_could_get_there() -> None:
    """Found by CI's sweep 31023: a charger in a corner behind a parking cell, with a vehicle down beside
    it. The parked drone made way when asked, went home 16 steps later, before the asker (which parks
    first, between tries) got there, and walled the charger in again, for good."""
    scenario = Scenario(drones=4, requests=4, delta=0, seed=196631, grid=(16, 16, 1), obstacles=0.2)
    outcome = Explorer(scenario).run(Strategy.RANDOM, schedules=60, max_depth=5000, seed=196631)
    assert outcome.violation is None, str(outcome.violation)


def test_mail_on_board_is_charged_for_where_a_full_battery_delivers_it() -> None:
    """Found by sweep 10083: d3 took mail while one charger was busy (the nearest then counted), picked it
    up, and once both were free the rule asked for the second nearest: no charger staged the delivery,
    and d3 charged in full at the far one, for good."""
    scenario = Scenario(drones=4, requests=4, delta=0, seed=533698, grid=(16, 16, 1), obstacles=0.2, partitions=2)
    outcome = Explorer(scenario).run(Strategy.PCT, schedules=30, max_depth=5000, seed=533698)
    assert outcome.violation is None, str(outcome.violation)
