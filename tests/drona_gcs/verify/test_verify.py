"""The systematic tester: it finds every seeded bug, replays exactly, and passes the clean stack."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import random
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypedDict

import pytest

import drona_gcs.planner
import drona_gcs.stack
import fleet.cli.verify as verify_cli
from drona_gcs.errors import DronaError, ProblemError
from drona_gcs.motion import Trajectory
from drona_gcs.stack.mail import MailPickedUp, MailPlanner, MailRequest, MailStarted
from drona_gcs.stack.messages import Task, TaskId
from drona_gcs.stack.protocol import Braked, CoordinationProtocol, Grounded, Present, StartExecuting
from drona_gcs.verify.explore import Explorer, Scenario, Strategy, decode_token, encode_token
from drona_gcs.verify.monitors import Flier, Monitors, Violation
from drona_gcs.verify.mutants import SEEDED_BUGS
from drona_gcs.verify.sweep import configurations
from drona_gcs.verify.world import Joined, Left, World, WorldConfig
from drona_gcs.workspace import Cell, Workspace
from fleet.cli import main

#: Which monitor each seeded bug should trip: (a) stale Psi, (b) collision, (d) a request never
#: delivered, (e) battery, (h) a mail with two owners.
EXPECTED = {
    "stale-trajectory": {"a", "b"},
    # Requests are answers to the drones before them in line: ranked the wrong way round, a drone
    # may wait for good, and hover until its battery runs low.
    "tie-break-reversed": {"a", "b", "d", "e"},
    "answer-while-coordinating": {"a", "b"},
    "no-battery-check": {"e"},
    "skip-delta": {"b"},
    "executor-early": {"g"},  # every drone early alike: only the plan it flies shows it
    "fly-unheld": {"a", "b"},
    # Issue 25's second owner: the service gives a cut-off drone's mail to another, which it takes too.
    "pickup-uncleared": {"h"},
    # A clock off by more than Delta: plans made in step with it meet once it keeps its offset.
    "skew-blind": {"b"},
}


class Needs(TypedDict, total=False):
    """The faults of a :class:`Scenario` a bug needs."""

    partitions: int
    skews: int


#: The fault that makes a bug show (none but for these).
NEEDS: dict[str, Needs] = {"fly-unheld": {"partitions": 1}, "pickup-uncleared": {"partitions": 1},
                           "skew-blind": {"skews": 1}}


def test_every_seeded_bug_has_an_expectation() -> None:
    assert set(EXPECTED) == set(SEEDED_BUGS)


@pytest.mark.parametrize("bug", sorted(SEEDED_BUGS))
@pytest.mark.parametrize("strategy", [Strategy.RANDOM, Strategy.PCT])
def test_each_seeded_bug_is_found(bug: str, strategy: Strategy) -> None:
    # Without the field's faults, so that each bug is what the monitor sees.
    explorer = Explorer(Scenario(drones=4, requests=6, delta=1, seed=0, bugs=(bug,), faults=False,
                                 **NEEDS.get(bug, {})))
    outcome = explorer.run(strategy, schedules=300, max_depth=4000, seed=1)
    assert outcome.violation is not None, f"{bug} not found in {outcome.schedules} schedules"
    assert outcome.violation.monitor in EXPECTED[bug], str(outcome.violation)
    assert outcome.choices and outcome.trace


#: Three drones seldom fly two plans across each other when a clock goes off: four, as in the test above.
REPLAY_DRONES = {"skew-blind": 4}


@pytest.mark.parametrize("bug", sorted(SEEDED_BUGS))
def test_replaying_a_token_reproduces_the_same_trace(bug: str) -> None:
    scenario = Scenario(drones=REPLAY_DRONES.get(bug, 3), requests=5, delta=1, seed=3, bugs=(bug,),
                        **NEEDS.get(bug, {}))
    found = Explorer(scenario).run(Strategy.RANDOM, schedules=300, max_depth=4000, seed=2)
    assert found.violation is not None
    scenario_back, choices = decode_token(encode_token(scenario, found.choices))
    assert scenario_back == scenario and choices == found.choices
    again = Explorer(scenario_back).replay(choices)
    assert again.trace == found.trace
    assert str(again.violation) == str(found.violation)


@pytest.mark.parametrize(("drones", "delta", "seed"), [(2, 0, 1), (3, 1, 2), (4, 1, 0), (4, 2, 5)])
def test_clean_stack_passes_random_and_pct_exploration(drones: int, delta: int, seed: int) -> None:
    explorer = Explorer(Scenario(drones=drones, requests=6, delta=delta, seed=seed, faults=False))
    for strategy in (Strategy.RANDOM, Strategy.PCT):
        outcome = explorer.run(strategy, schedules=25, max_depth=6000, seed=seed)
        assert outcome.violation is None, "\n".join([str(outcome.violation), *outcome.trace[-30:]])
        assert outcome.schedules == 25


@pytest.mark.parametrize(("drones", "delta", "seed"), [(4, 1, 0), (4, 2, 5)])
def test_clean_stack_stays_live_under_the_fields_faults(drones: int, delta: int, seed: int) -> None:
    explorer = Explorer(Scenario(drones=drones, requests=6, delta=delta, seed=seed))
    for strategy in (Strategy.RANDOM, Strategy.PCT):
        outcome = explorer.run(strategy, schedules=25, max_depth=6000, seed=seed)
        assert outcome.violation is None, "\n".join([str(outcome.violation), *outcome.trace[-30:]])


def test_the_fault_model_duplicates_cancels_and_downs_within_its_bounds() -> None:
    """Every schedule may duplicate messages, cancel a mail and bring a vehicle down, never beyond the
    bounds; with faults off, none of it happens."""
    seen = {"duplicates": 0, "cancel": 0, "down": 0}
    for seed in range(10):
        world, rng = Explorer(Scenario(drones=3, requests=4, delta=1, seed=seed)).world(), random.Random(seed)
        with contextlib.suppress(Violation):
            for _ in range(3000):
                if world.finished:
                    break
                world.apply(rng.choice(world.enabled()))
        counts = {"duplicates": sum("net: duplicates" in line for line in world.trace),
                  "cancel": sum("env: cancel" in line for line in world.trace),
                  "down": sum("came down by itself" in line for line in world.trace)}
        assert counts["duplicates"] <= 2 and counts["cancel"] <= 1 and counts["down"] <= 1, counts
        seen = {k: seen[k] + counts[k] for k in seen}
    assert all(count > 0 for count in seen.values()), seen
    quiet = Explorer(Scenario(drones=3, requests=4, delta=1, seed=0, faults=False)).world()
    assert not any(kind in ("duplicate", "cancel", "down") for kind, _ in quiet.enabled())


def test_the_fault_model_puts_a_clock_off_only_once_every_clock_check_has_found_it() -> None:
    """With --skews, a drone's clock may go off while plans cross: every drone's clock check says so within
    VERDICT_STEPS, in any order; until all have, the clocks keep within Delta, and after, that clock keeps
    Delta of the others' shifted by its offset. It never combines with crashes or partitions."""
    shifted = 0
    for seed in range(8):
        world, rng = Explorer(Scenario(drones=4, requests=5, delta=1, seed=seed, skews=1)).world(), random.Random(seed)
        with contextlib.suppress(Violation):
            for _ in range(3000):
                if world.finished:
                    break
                kind, arg = move = rng.choice(world.enabled())
                world.apply(move)
                true = {d: s - (world.offsets[d] if d in world.unbound else 0) for d, s in world.steps.items()}
                if kind == "step":  # no clock steps more than Delta ahead of the others', read so
                    mover = world.config.drones[arg]
                    assert true[mover] - min(t for d, t in true.items() if d != mover) <= 1, (world.steps, true)
                if world.unbound:
                    [off] = world.unbound
                    assert all(world.told[d] == {off} for d in world.config.drones)
                    shifted += any(abs(world.steps[off] - s) > 1 for d, s in world.steps.items() if d != off)
        assert world.used.skews <= 1
    assert shifted
    quiet = Explorer(Scenario(drones=4, requests=5, delta=1, seed=0)).world()
    assert not any(kind in ("skew", "verdict") for kind, _ in quiet.enabled())
    with pytest.raises(ProblemError, match="skews do not combine"):
        Scenario(skews=1, crashes=1)


def test_the_fault_model_crashes_and_restarts_agents_as_the_field_does() -> None:
    """With --crashes, an agent may crash (messages to it lost, its peers see it leave) and restart
    once every peer saw it leave (a dead process closes its links at once); liveliness changes are
    never duplicated nor reordered."""
    seen = {"crash": 0, "restart": 0, "lost": 0}
    for seed in range(12):
        scenario = Scenario(drones=3, requests=3, delta=1, seed=seed, crashes=1)
        world, rng = Explorer(scenario).world(), random.Random(seed)
        with contextlib.suppress(Violation):
            for _ in range(3000):
                if world.finished:
                    break
                moves = world.enabled()
                leaving = {m.sender for m in world.inflight if isinstance(m.message, Left)}
                assert not any(kind == "restart" and world.config.drones[i] in leaving for kind, i in moves)
                world.apply(rng.choice(moves))
        trace = world.trace
        assert not any("duplicates Left" in line or "duplicates Joined" in line for line in trace)
        crashes = sum("its agent crashed;" in line for line in trace)
        assert crashes <= 1
        seen = {"crash": seen["crash"] + crashes,
                "restart": seen["restart"] + sum("agent restarts" in line for line in trace),
                "lost": seen["lost"] + sum(" lost" in line for line in trace)}
    assert all(count > 0 for count in seen.values()), seen
    assert not any(kind == "crash" for kind, _ in Explorer(Scenario(drones=3, requests=3, seed=0)).world().enabled())


def test_a_copy_of_what_a_crashed_agent_sent_still_comes_before_its_leave() -> None:
    """Found with the crash model: a duplicate made after the crash came after the leave, and a peer
    took it for a live agent's request (a dead session's messages all precede its close)."""
    world = Explorer(Scenario(drones=3, requests=2, delta=1, seed=0, crashes=1)).world()
    for _ in range(200):
        if any(m.sender == "d0" and not isinstance(m.message, Left) for m in world.inflight):
            break
        world.apply(next(m for m in world.enabled() if m[0] in ("step", "inject")))
    sent = next(m for m in world.inflight if m.sender == "d0")
    world.apply(("crash", 0))
    world.apply(("duplicate", sent.seq))
    copy = world.inflight[-1]
    left = next(m for m in world.inflight if m.to == copy.to and isinstance(m.message, Left))
    world.apply(("deliver", sent.seq))
    enabled = world.enabled()
    assert ("deliver", left.seq) not in enabled and ("deliver", copy.seq) in enabled
    world.apply(("deliver", copy.seq))
    assert ("deliver", left.seq) in world.enabled()


@pytest.mark.parametrize("drones, requests, delta, seed, strategy, obstacles, crashes", [
    (3, 4, 1, 3, Strategy.RANDOM, 0.2, 1),  # a restarted agent's first request was dropped as late
    (4, 4, 0, 649216, Strategy.PCT, 0.2, 1),  # planned around a plan whose agent died: flew into its vehicle
    (5, 4, 0, 150073, Strategy.PCT, 0.0, 1),  # a vehicle down on the goal of a plan flown: flew into it
    (3, 4, 1, 76051, Strategy.PCT, 0.2, 0),  # a vehicle down cut the goal off: flew on into it
])
def test_clean_stack_stays_safe_when_vehicles_come_down_and_agents_crash(
        drones: int, requests: int, delta: int, seed: int, strategy: Strategy, obstacles: float, crashes: int) -> None:
    """Found by sweeps (see each case); the stack must survive them all."""
    explorer = Explorer(Scenario(drones=drones, requests=requests, delta=delta, seed=seed, crashes=crashes,
                                 obstacles=obstacles))
    outcome = explorer.run(strategy, schedules=400, max_depth=5000, seed=seed)
    assert outcome.violation is None, str(outcome.violation)


def test_clean_stack_passes_exhaustive_dfs_to_a_small_depth() -> None:
    outcome = Explorer(Scenario(drones=2, requests=1, delta=1, seed=0, faults=False)).run(Strategy.DFS, 0, 12, 0)
    assert outcome.violation is None
    assert outcome.exhausted and outcome.states > 100


def test_dfs_finds_a_seeded_bug() -> None:
    explorer = Explorer(Scenario(drones=2, requests=2, delta=1, seed=0, bugs=("answer-while-coordinating",)))
    outcome = explorer.run(Strategy.DFS, 0, 40, 0)
    assert outcome.violation is not None and outcome.violation.monitor in {"a", "b"}
    assert Explorer(explorer.scenario).replay(outcome.choices).trace == outcome.trace


def test_bad_scenarios_and_tokens_are_refused() -> None:
    with pytest.raises(ProblemError, match="unknown seeded bug"):
        Scenario(bugs=("no-such-bug",))
    with pytest.raises(ProblemError):
        Scenario(drones=0)
    with pytest.raises(DronaError, match="not a replay token"):
        decode_token("garbage!!")


def test_cli_exit_codes_and_replay(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["verify", "--quiet", "--drones", "2", "--requests", "2", "--schedules", "5",
                 "--time-limit", "30"]) == 0
    assert "5 schedules" in capsys.readouterr().out
    assert main(["verify", "--quiet", "--seed-bug", "skip-delta", "--time-limit", "60"]) == 1
    out = capsys.readouterr().out
    assert "VIOLATION (b)" in out
    token = out.split("drona verify --replay ")[1].split()[0]
    assert main(["verify", "--replay", token]) == 1
    replayed = capsys.readouterr().out
    marker = "trace (who sent what, who stepped):"
    assert replayed.split(marker)[1] == out.split(marker)[1]
    assert main(["verify", "--quiet", "--grid", "8by8"]) == 2
    assert main(["verify", "--quiet", "--drones", "0"]) == 2
    assert main(["verify", "--quiet", "--workspace", "/nonexistent.yaml"]) == 2
    assert main(["verify", "--replay", "nonsense"]) == 2
    capsys.readouterr()
    assert main(["verify", "--replay", encode_token(Scenario(drones=2, requests=1), [999])]) == 2
    assert "replay token: choice 1 is move 1000, but only" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["16_4", "Delta", "Exp1", "Exp6", "32_32"])
def test_clean_stack_on_the_original_drona_workspaces(name: str, data_dir: Path) -> None:
    path = data_dir / "drona-workspaces" / name / "Workspace.xml"
    explorer = Explorer(Scenario(drones=2, requests=4, delta=1, seed=1, workspace_path=str(path)))
    outcome = explorer.run(Strategy.RANDOM, schedules=10, max_depth=6000, seed=1)
    assert outcome.violation is None, str(outcome.violation)
    assert outcome.schedules == 10


def test_a_reversed_mail_rank_is_found_by_the_order_monitor(monkeypatch: pytest.MonkeyPatch) -> None:
    """Monitor (c) ranks mail in its own code: a mutant that reverses the production rank (least urgent
    first) is found, where an oracle using that rank would reverse with it."""
    monkeypatch.setattr(MailRequest, "rank", property(lambda r: (r.priority, -r.seq)))
    outcome = Explorer(Scenario(drones=2, requests=6, delta=1, seed=0)).run(Strategy.RANDOM, schedules=50,
                                                                          max_depth=4000, seed=1)
    assert outcome.violation is not None and outcome.violation.monitor == "c", str(outcome.violation)


def test_a_plan_made_without_a_peer_is_found_by_the_consistency_monitor(monkeypatch: pytest.MonkeyPatch) -> None:
    """Monitor (a) takes each drone's commitment from what it started executing, not from the protocol: a
    mutant that leaves a peer out of Psi (it plans as if that drone were not there) is found."""
    real = StartExecuting.__init__

    def forget_a_peer(self: StartExecuting, task: object, trajectory: object, psi: dict[str, object]) -> None:
        real(self, task, trajectory, dict(list(psi.items())[1:]))  # type: ignore[arg-type]

    monkeypatch.setattr(StartExecuting, "__init__", forget_a_peer)
    outcome = Explorer(Scenario(drones=3, requests=4, delta=1, seed=0)).run(Strategy.RANDOM, schedules=5,
                                                                          max_depth=4000, seed=1)
    assert outcome.violation is not None and outcome.violation.monitor == "a", str(outcome.violation)


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


def test_a_short_sweep_over_configurations_nobody_picked_is_clean(capsys: pytest.CaptureFixture[str]) -> None:
    """CI's short sweep, with the field's faults: a new sweep seed each run (DRONA_SWEEP_SEED replays
    one), so that no configuration is ever tuned for; the long one is a command (README)."""
    seed = int(os.environ.get("DRONA_SWEEP_SEED", random.randrange(1_000_000)))
    code = main(["verify", "--sweep", "4", "--time-limit", "4", "--seed", str(seed), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0, f"DRONA_SWEEP_SEED={seed}\n{out}"
    assert f"sweep seed {seed}: 4 of 4 clean" in out


def test_a_sweep_draws_again_a_configuration_no_mail_can_be_given_in() -> None:
    """A draw of sweep 20041 (16x16, obstacles) has no pickup a charged drone can fly: it ended the
    whole sweep (and CI's short sweep, which draws its seed at random, could have drawn it)."""
    drawn = list(configurations(20041, 12))
    assert len(drawn) == 12
    for config in drawn:
        config.scenario.world_config(config.scenario.workspace())  # each can be explored


def test_the_code_that_flies_carries_no_seeded_bug() -> None:
    """Seeded bugs live in the tester (drona_gcs.verify.mutants), never in the stack's handlers."""
    flown = [*Path(drona_gcs.stack.__file__).parent.glob("*.py"),
             *Path(drona_gcs.planner.__file__).parent.glob("*.py")]
    hooks = [(path.name, bug) for path in flown for bug in SEEDED_BUGS if bug in path.read_text()]
    assert hooks == []
    for machine in (CoordinationProtocol, MailPlanner):
        assert "bugs" not in {f.name for f in dataclasses.fields(machine)}


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


def test_a_counterexample_is_the_same_whatever_the_hash_seed() -> None:
    """Two processes with different string hashing find the same trace, naming the same peers."""
    def run(hash_seed: str) -> list[str]:
        command = [sys.executable, "-m", "fleet.cli", "verify", "--grid", "8x8", "--drones", "5", "--requests", "6",
                   "--seed", "11", "--seed-bug", "stale-trajectory", "--strategy", "pct", "--time-limit", "20",
                   "--quiet", "--shrink", "0"]
        done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False,
                              env={**os.environ, "PYTHONHASHSEED": hash_seed})
        return done.stdout.splitlines()[1:]  # the first line has timings

    first = run("1")
    assert any("VIOLATION" in line for line in first), first
    assert run("2") == first


@pytest.mark.parametrize("rests_on_pickup", [True, False])
def test_the_order_monitor_lets_urgent_mail_wait_while_a_drone_rests_on_its_pickup(rests_on_pickup: bool) -> None:
    """(c): no path is open to a pickup another drone rests on (a vehicle down, for good perhaps),
    so less urgent mail may go first; with the pickup free, it may not."""
    ws = Workspace.build(size=(5, 3, 1))
    urgent, later = MailRequest("u", (2, 2, 0), (4, 2, 0), 9), MailRequest("l", (1, 0, 0), (3, 0, 0), 1, seq=1)
    peer = (2, 2, 0) if rests_on_pickup else (0, 2, 0)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), peer), (urgent, later), ("d0", "d0"), delta=0)
    monitors = Monitors(config)
    monitors.given_mail("d0", urgent)
    monitors.given_mail("d0", later)
    start = MailStarted(later, (urgent,))
    if rests_on_pickup:
        monitors.action("d0", start)
    else:
        with pytest.raises(Violation, match=r"\(c\) d0 started mail l"):
            monitors.action("d0", start)


def test_a_vehicle_down_stays_where_it_came_down_in_the_model() -> None:
    """The model flew a vehicle down along its plan, so no plan was ever seen to meet it: the
    separation monitor judged where the vehicle was not."""
    world = Explorer(Scenario(drones=3, requests=3, delta=1, seed=1)).world()
    for _ in range(400):
        flying = [i for i, d in enumerate(world.config.drones) if (plan := world.stacks[d].executor.trajectory)
                  is not None and world.steps[d] < plan.end_step - 2]
        if flying:
            break
        world.apply(next(m for m in world.enabled() if m[0] in ("step", "inject", "deliver")))
    drone = world.config.drones[flying[0]]
    where, seen = world.stacks[drone].executor.cell, len(world.monitors.history.get(drone, []))
    world.apply(("down", flying[0]))
    for _ in range(200):
        moves = world.enabled()
        ours = ([m for m in moves if m == ("step", flying[0])]
                or [m for m in moves if m[0] in ("step", "deliver", "inject")])
        if not ours:
            break
        world.apply(ours[0])
    assert len(world.monitors.history[drone]) > seen + 2 and set(world.monitors.history[drone][seen:]) == {where}


@pytest.mark.parametrize("asked", [True, False])
def test_mail_on_board_flies_off_a_way_only_when_asked_to(asked: bool) -> None:
    """(f): besides its drop-off and a charger, mail on board flies only off a way a peer asked the
    drone to leave, to a cell off that way."""
    ws = Workspace.build(size=(5, 3, 1))
    request = MailRequest("m", (0, 0, 0), (4, 2, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (4, 0, 0)), (request,), ("d0",), delta=0)
    monitors = Monitors(config)
    monitors.action("d0", MailPickedUp(request))
    if asked:
        monitors.asked_to_leave("d0", ((1, 0, 0), (0, 0, 0), (0, 1, 0)))
    off = Trajectory(3, ((0, 0, 0), (1, 0, 0), (1, 1, 0)))
    leave = StartExecuting(Task(TaskId(3, "d0", 2), (1, 1, 0)), off, {"d1": Trajectory(0, ((4, 0, 0),))})
    if asked:
        monitors.action("d0", leave)
    else:
        with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):
            monitors.action("d0", leave)


def test_mail_on_board_may_answer_any_way_asked_since_its_last_plan() -> None:
    """(f): a drone asked by two peers, that leaves the first one's way for a cell on the second's,
    still flies off a way it was asked to leave (sweep seed 5150, scenario 327244)."""
    ws = Workspace.build(size=(5, 3, 1))
    request = MailRequest("m", (0, 0, 0), (4, 2, 0), 5)
    config = WorldConfig(ws, ("d0", "d1", "d2"), ((0, 0, 0), (4, 0, 0), (4, 2, 0)), (request,), ("d0",), delta=0)
    monitors = Monitors(config)
    monitors.action("d0", MailPickedUp(request))
    monitors.asked_to_leave("d0", ((0, 0, 0), (0, 1, 0), (0, 2, 0)))
    monitors.asked_to_leave("d0", ((2, 0, 0), (1, 0, 0), (0, 0, 0)))
    off = Trajectory(3, ((0, 0, 0), (1, 0, 0)))
    others = {"d1": Trajectory(0, ((4, 0, 0),)), "d2": Trajectory(0, ((4, 2, 0),))}
    monitors.action("d0", StartExecuting(Task(TaskId(3, "d0", 2), (1, 0, 0)), off, others))
    with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):  # the ways asked end with the plan
        monitors.action("d0", StartExecuting(Task(TaskId(6, "d0", 3), (1, 1, 0)),
                                             Trajectory(6, ((1, 0, 0), (1, 1, 0))), others))


@pytest.mark.parametrize("rest_at", [(2, 0, 0), (1, 0, 0)])
def test_a_rest_said_at_the_end_of_a_plan_stands_for_that_plan_and_nowhere_else(rest_at: Cell) -> None:
    """(a): a drone whose clock is off says it rests once its plan ends (sweep 20182 with --skews 2); a
    plan made with that rest is made with what it is committed to. A rest said elsewhere is no such thing."""
    ws = Workspace.build(size=(5, 3, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 2, 0), (0, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    flown = Trajectory(1, ((0, 0, 0), (1, 0, 0), (2, 0, 0)))
    monitors.action("d1", StartExecuting(Task(TaskId(1, "d1", 1), (2, 0, 0)), flown,
                                         {"d0": Trajectory(0, ((0, 2, 0),))}))
    rest = Trajectory.stationary(rest_at, 3)
    if rest_at != flown.last:
        with pytest.raises(Violation, match=r"\(a\) d1 says it rests"):
            monitors.action("d1", Present("d0", rest, braked=False))
        return
    monitors.action("d1", Present("d0", rest, braked=False))
    monitors.action("d0", StartExecuting(Task(TaskId(2, "d0", 2), (4, 2, 0)),  # d0's clock behind d1's
                                         Trajectory(2, ((0, 2, 0), (1, 2, 0))), {"d1": rest}))


@pytest.mark.parametrize("told, collides", [(None, False), (1, False), (0, True)])
def test_a_drone_may_not_enter_a_vehicle_downs_cell_once_told(told: int | None, collides: bool) -> None:
    """(b): a vehicle that comes down where another drone's plan enters next is no protocol's to avoid
    before the news comes; told at its step s, a drone must not be in that cell at s + 1."""
    ws = Workspace.build(size=(5, 1, 1))
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (2, 0, 0)), (), (), delta=0)
    monitors = Monitors(config)
    monitors.vehicle_down("d1", (2, 0, 0), 0)
    if told is not None:
        monitors.heard_news("d0", "d1", told)
    flown = {"d0": [(1, 0, 0), (2, 0, 0), (2, 0, 0), (2, 0, 0)], "d1": [(2, 0, 0)] * 4}
    steps = {"d0": 0, "d1": 0}
    with pytest.raises(Violation, match=r"\(b\) d0 and d1: collision") if collides else contextlib.nullcontext():
        for step in range(4):
            for drone in ("d0", "d1"):
                steps[drone] = step
                monitors.position(drone, step, flown[drone][step], steps, flies=False)


def test_a_clones_task_planner_measures_ways_with_the_clones_state() -> None:
    """The exhaustive search clones worlds: a clone's task planner measured ways with the state of the
    stack it was first made for, so dfs explored budgets that ignored every vehicle down since."""
    world = Explorer(Scenario(drones=2, requests=1, delta=1, seed=0, obstacles=0.0)).world()
    child = world.clone_for(world.enabled()[0])
    drone = world.config.drones[0]
    x, y, z = start = world.stacks[drone].executor.cell
    way = 1 if x + 2 < world.config.workspace.nx else -1
    ahead, beyond = (x + way, y, z), (x + 2 * way, y, z)
    child.stacks[drone].protocol.peers_down["d9"] = ahead
    assert world.stacks[drone].mail.distance(start, beyond) == 2
    assert child.stacks[drone].mail.distance(start, beyond) == 4


def test_a_partition_cuts_messages_across_and_heals_in_time() -> None:
    """With --partitions, the network may cut a drone off: what crosses the cut is lost, each side
    sees the other leave and, once healed (within PARTITION_STEPS), join; nothing of it without."""
    world = Explorer(Scenario(drones=3, requests=3, delta=1, seed=4, partitions=1)).world()
    world.apply(("partition", 0))
    assert ("partition", 1) not in world.enabled() and ("heal", 0) in world.enabled()
    d0, d1 = world.config.drones[:2]
    world._post(d0, d1, Left(0))  # as a message, not the sessions' own news: it does not cross
    assert not any(m.sender == d0 and m.to == d1 and m.seq == world.sent for m in world.inflight)
    assert {(m.sender, m.to) for m in world.inflight if isinstance(m.message, Left)} == {
        (a, b) for a in world.config.drones for b in world.config.drones if (a == d0) != (b == d0)}
    heal_by = world.heal_by
    assert heal_by is not None
    world.inflight = []  # so that no message's deadline holds the clocks back
    world.steps = dict.fromkeys(world.config.drones, heal_by)
    assert not any(kind == "step" for kind, _ in world.enabled())  # no step beyond the deadline until it heals
    world.apply(("heal", 0))
    assert any(kind == "step" for kind, _ in world.enabled())
    assert world.apart == frozenset() and any(isinstance(m.message, Joined) for m in world.inflight)
    quiet = Explorer(Scenario(drones=3, requests=3, delta=1, seed=4)).world()
    assert not any(kind in ("partition", "heal") for kind, _ in quiet.enabled())


@pytest.mark.parametrize("bugs", [("fly-unheld",), ()], ids=["fly-unheld", "the-stack"])
def test_the_tester_finds_that_a_partition_can_put_drones_on_one_cell(bugs: tuple[str, ...]) -> None:
    """Issue 25's partition collision, found by the model: a drone cut off plans anew with nobody to
    ask, and the other side plans around where it last knew it. The stack flies a plan only once every
    member holds it, and plans only with a majority: the same schedules find nothing."""
    found = []
    for seed in (937387, 98507, 5596):
        scenario = Scenario(drones=3, requests=4, delta=0, seed=seed, partitions=1, bugs=bugs)
        outcome = Explorer(scenario).run(Strategy.RANDOM, schedules=200, max_depth=3000, seed=seed)
        found.append(outcome.violation is not None and outcome.violation.monitor in {"a", "b"})
    assert any(found) if bugs else not any(found), found


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


def test_an_agent_restarted_across_a_cut_holds_its_peers_as_gone_until_it_heals() -> None:
    """Found by a sweep with a crash and a partition (seed 9301): d0, cut off, crashed and restarted
    knowing every peer as a member; its request was lost across the cut, and the heal's join of a peer
    it never saw leave asked nothing again: it waited for good. As the agent does, a restarted drone
    holds the peers it cannot see as gone; the heal makes them members, and its round asks them."""
    world = Explorer(Scenario(drones=3, requests=0, delta=1, seed=2, crashes=1, partitions=1)).world()
    d0 = world.config.drones[0]
    world.apply(("partition", 0))
    world.apply(("crash", 0))
    world.inflight = [m for m in world.inflight if not isinstance(m.message, Left)]  # as if every peer saw it
    world.apply(("restart", 0))
    assert world.stacks[d0].protocol.members == set()
    world.inflight = []
    world.apply(("heal", 0))
    for message in [m for m in world.inflight if m.to == d0]:
        world.apply(("deliver", message.seq))
    assert world.stacks[d0].protocol.members == set(world.config.drones[1:])


@pytest.mark.parametrize(("given", "delta"), [([], 3), (["--delta", "1"], 1)])
def test_verify_on_a_workspace_explores_its_own_separation_window(tmp_path: Path, given: list[str],
                                                                   delta: int) -> None:
    """The window the tester explores is the one the fleet flies: ceil((beta + lambda) / tau)."""
    path = tmp_path / "ws.yaml"
    path.write_text("size: [4, 4, 1]\ntau_s: 0.5\nbeta_s: 0.2\nlambda_s: 0.9\ndrones: {d1: [0, 0, 0]}\n")
    parser = argparse.ArgumentParser()
    verify_cli.add_arguments(parser)
    scenario = verify_cli._scenario(parser.parse_args(["--workspace", str(path), "--max-depth", "100", *given]))
    assert scenario.delta == delta


def test_a_drone_that_stops_where_it_stands_short_of_a_held_cell_is_no_violation() -> None:
    """Found by sweep 9914: d0, carrying mail, had not left its first cell when a departed peer came to
    hold a cell of its plan; it stopped where it stood. Monitor (f) compared the plans only as long as
    the new one, a single cell, so it saw nothing made new and called the stop a detour."""
    scenario = Scenario(drones=6, requests=8, delta=1, seed=625805, grid=(8, 8, 1), obstacles=0.0, crashes=1,
                        partitions=1, max_delay=2)
    outcome = Explorer(scenario).run(Strategy.PCT, schedules=20, max_depth=5000, seed=625805)
    assert outcome.violation is None, str(outcome.violation)


def test_a_drone_that_stops_short_of_a_plan_it_last_knew_of_a_departed_peer_is_no_violation() -> None:
    """Found by sweep 10012: d4, cut off, braked short of a cell, and nobody heard; d1 then saw d4 leave
    and stopped short of the plan of d4's it knew. Monitor (f) judged the stop against d4's brake, which
    d1 could not know, and called it a detour."""
    scenario = Scenario(drones=5, requests=6, delta=2, seed=76641, grid=(8, 8, 1), obstacles=0.2, crashes=1,
                        partitions=1)
    outcome = Explorer(scenario).run(Strategy.PCT, schedules=80, max_depth=5000, seed=76641)
    assert outcome.violation is None, str(outcome.violation)


@pytest.mark.parametrize("d1_flies", [
    ((5, 1, 0), (5, 0, 0)),  # rests in (5, 0, 0), on d0's way, from step 6 (found in a sweep, seed 20072)
    ((5, 0, 0), (5, 1, 0)),  # crossed (5, 0, 0) at step 5, then silent (found in a sweep, seed 20092)
], ids=["rests-on-the-way", "crossed-the-way"])
def test_a_stop_short_of_a_cell_a_departed_drone_may_hold_is_no_detour(d1_flies: tuple[Cell, ...]) -> None:
    """Found by the tester under a partition: d1 was cut off, and d0 stopped short of a cell of d1's last
    plan, which d1 may hold for good. Monitor (f) took d1's cells only from shortly before the step where
    d0's new plan parts from the old one to d1's plan's end: it missed the cell d1 rests in after that end,
    and the cells d1's plan crossed before, and called the stop a detour."""
    ws = Workspace.build(size=(8, 8, 1))
    request = MailRequest("m", (0, 0, 0), (7, 0, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (5, 1, 0)), (request,), ("d0",), delta=1, liveness_steps=0)
    short = StartExecuting(Task(TaskId(12, "d0", 2), (7, 0, 0)), Trajectory(10, tuple((x, 0, 0) for x in range(4))),
                           {})  # parts from the old plan at step 14, in (3, 0, 0)

    def judged(saw_d1_leave: bool) -> None:
        monitors = Monitors(config)
        monitors.committed["d0"] = Trajectory(10, tuple((x, 0, 0) for x in range(8)))  # to the drop-off
        monitors.committed["d1"] = Trajectory(5, d1_flies)
        monitors.carrying["d0"] = request
        if saw_d1_leave:
            monitors.left("d0", "d1")
        monitors._carried_to_its_dropoff("d0", short)

    judged(saw_d1_leave=True)
    with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):  # nothing held for good on the way
        judged(saw_d1_leave=False)


@pytest.mark.parametrize("news", ["braked", "grounded", "off", "none"])
def test_a_stop_short_of_where_a_peer_braked_or_grounded_itself_is_no_detour(news: str) -> None:
    """Found by sweeps 20191 and 20201 with --skews 1: d1 braked (or, its battery spent, grounded itself)
    on the way to d0's drop-off, or was found off with a plan there before its last; d0 stopped short of
    it. Monitor (f) held only vehicles down, departed drones and the last plans of clocks off, and
    called the stop a detour."""
    ws = Workspace.build(size=(8, 8, 1))
    request = MailRequest("m", (0, 0, 0), (7, 0, 0), 5)
    config = WorldConfig(ws, ("d0", "d1"), ((0, 0, 0), (5, 1, 0)), (request,), ("d0",), delta=1, liveness_steps=0)
    monitors = Monitors(config)
    monitors.committed["d0"] = Trajectory(10, tuple((x, 0, 0) for x in range(8)))  # to the drop-off
    monitors.committed["d1"] = Trajectory(5, ((5, 1, 0), (5, 0, 0)))
    monitors.carrying["d0"] = request
    if news == "braked":
        monitors.action("d1", Braked(Trajectory(5, ((5, 1, 0), (5, 0, 0), (5, 0, 0))), (5, 1, 0)))
    elif news == "grounded":
        monitors.action("d1", Grounded(Trajectory.stationary((5, 0, 0), 6)))
    elif news == "off":  # found off after a plan since (sweep 20201): d0 may not know of that one yet
        later = Trajectory(7, ((5, 1, 0), (5, 2, 0)))
        psi = {"d0": monitors.committed["d0"]}
        monitors.action("d1", StartExecuting(Task(TaskId(6, "d1", 2), (5, 0, 0)), monitors.committed["d1"], psi))
        monitors.action("d1", StartExecuting(Task(TaskId(7, "d1", 3), (5, 2, 0)), later, psi))
        monitors.clock_verdict("d0", frozenset({"d1"}))
    monitors.heard_news("d0", "d1", 11)
    short = StartExecuting(Task(TaskId(12, "d0", 2), (7, 0, 0)), Trajectory(10, tuple((x, 0, 0) for x in range(4))),
                           {})  # parts from the old plan at step 14, in (3, 0, 0)
    if news == "none":
        with pytest.raises(Violation, match=r"\(f\) d0 carries mail m"):
            monitors._carried_to_its_dropoff("d0", short)
    else:
        monitors._carried_to_its_dropoff("d0", short)


def test_a_brake_announced_across_a_partition_reaches_the_peer_once_it_is_back() -> None:
    """Found by sweep 10033: d1 saw d4 leave and braked in the cell d4's plan ended in; the announcement
    was lost across the cut. The cut healed at once, d4 dropped d1's ghost when d1 joined again, and flew
    into d1. Now each tells a peer back what it flies (a brake as a brake), and holds it where it may be
    until it says."""
    scenario = Scenario(drones=6, requests=3, delta=1, seed=100028, grid=(8, 8, 1), obstacles=0.2, crashes=1,
                        partitions=1)
    outcome = Explorer(scenario).run(Strategy.PCT, schedules=30, max_depth=5000, seed=100028)
    assert outcome.violation is None, str(outcome.violation)


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


def test_the_service_gives_mail_handed_back_to_the_drone_with_the_least_in_hand() -> None:
    """Found by sweep 20021: two drones walled in and two more short of a charger handed their mail back,
    and the model's service gave each to the next drone by name. Only d5 flew, one mail after another, past
    the liveness bound. `drona serve` chooses by the fleet's rule (fewest held, idle, nearest): so does
    the model."""
    scenario = Scenario(drones=6, requests=9, delta=1, seed=161326, grid=(8, 8, 1), obstacles=0.2)
    outcome = Explorer(scenario).run(Strategy.RANDOM, schedules=30, max_depth=5000, seed=161326)
    assert outcome.violation is None, str(outcome.violation)


def _drive(world: World, until: Callable[[World], bool], rng: random.Random, moves: int = 3000) -> None:
    """Random moves but faults until ``until`` holds (bounded)."""
    for _ in range(moves):
        if until(world):
            return
        calm = [m for m in world.enabled() if m[0] in ("deliver", "step", "inject")]
        world.apply(rng.choice(calm))
    raise AssertionError("the world never got there")


def _given(world: World) -> bool:
    return bool(world.holder)


def _cleared_there(world: World) -> bool:
    return any(mail in (world.stacks[d].mail.cleared or set()) for mail, d in world.holder.items())


@pytest.mark.parametrize("cleared", [False, True])
def test_the_models_service_requeues_only_uncleared_mail_of_a_drone_cut_off(cleared: bool) -> None:
    """As ``drona serve``: a drone cut off hands back the mail it was not cleared for, and the service
    gives that to another drone; a mail cleared stays the cut-off drone's until the heal."""
    scenario = Scenario(drones=3, requests=1, delta=1, seed=4, partitions=1, faults=False)
    world = Explorer(scenario).world()
    _drive(world, _cleared_there if cleared else _given, random.Random(4))
    mail, drone = next(iter(world.holder.items()))
    world.apply(("partition", world.config.drones.index(drone)))
    if cleared:
        assert world.holder == {mail: drone} and not world.redispatch
    else:
        assert mail not in world.holder and [r.id for _, r, _ in world.redispatch] == [mail]
        held = world.stacks[drone].mail
        assert all(r.id != mail for r in held.queue) and (held.current is None or held.current.id != mail)
