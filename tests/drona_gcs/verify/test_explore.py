"""The systematic tester's exploration: it replays exactly, passes the clean stack by random, PCT
and exhaustive search, refuses bad scenarios and tokens, and runs from the CLI and in sweeps.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

import fleet.cli.verify as verify_cli
from drona_gcs.errors import DronaError, ProblemError
from drona_gcs.stack.battery import BatteryModel
from drona_gcs.verify.config import UPGRADE, _battery_for
from drona_gcs.verify.explore import Explorer, Scenario, Strategy, decode_token, encode_token
from drona_gcs.verify.mutants import SEEDED_BUGS
from drona_gcs.verify.sweep import configurations
from drona_gcs.workspace import Workspace
from fleet.cli import main
from tests.drona_gcs.verify.verify_helpers import NEEDS

#: Three drones seldom fly two plans across each other when a clock goes off: four, as in
#: test_seeded_bugs.py's test_each_seeded_bug_is_found.
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


def test_clean_stack_passes_exhaustive_dfs_to_a_small_depth() -> None:
    outcome = Explorer(Scenario(drones=2, requests=1, delta=1, seed=0, faults=False)).run(Strategy.DFS, 0, 12, 0)
    assert outcome.violation is None
    assert outcome.exhausted and outcome.states > 100


def test_dfs_finds_a_seeded_bug() -> None:
    # The field's faults (copies, vehicles down) are left to the random and PCT tests: with them, plain
    # DFS spends minutes on their schedules before this bug's.
    explorer = Explorer(Scenario(drones=2, requests=2, delta=1, seed=0, faults=False,
                                 bugs=("answer-while-coordinating",)))
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


def test_a_short_sweep_over_configurations_nobody_picked_is_clean(capsys: pytest.CaptureFixture[str]) -> None:
    """CI's short sweep, with the field's faults: a new sweep seed each run (DRONA_SWEEP_SEED replays
    one), and the network's delay drawn from it, so that no configuration is ever tuned for; the long
    one is a command (README)."""
    seed = int(os.environ.get("DRONA_SWEEP_SEED", random.randrange(1_000_000)))
    delay = random.Random(seed).randint(0, 5)
    code = main(["verify", "--sweep", "4", "--time-limit", "4", "--seed", str(seed), "--max-delay", str(delay),
                 "--quiet"])
    out = capsys.readouterr().out
    assert code == 0, f"DRONA_SWEEP_SEED={seed} (--max-delay {delay})\n{out}"
    assert f"sweep seed {seed}: 4 of 4 clean" in out


def test_a_sweep_draws_again_a_configuration_no_mail_can_be_given_in() -> None:
    """A draw of sweep 20041 (16x16, obstacles) has no pickup a charged drone can fly: it ended the
    whole sweep (and CI's short sweep, which draws its seed at random, could have drawn it)."""
    drawn = list(configurations(20041, 12))
    assert len(drawn) == 12
    for config in drawn:
        config.scenario.world_config(config.scenario.workspace())  # each can be explored


def test_a_sweep_runs_at_the_delay_and_with_the_bugs_asked_for(capsys: pytest.CaptureFixture[str]) -> None:
    """A sweep left ``--max-delay`` and ``--seed-bug`` out of every configuration it drew: sweeps said
    to run at a delay of 3 steps ran at 2."""
    drawn = list(configurations(30590, 6, max_delay=4, bugs=("skip-delta",)))
    assert {(c.scenario.max_delay, c.scenario.bugs) for c in drawn} == {(4, ("skip-delta",))}
    main(["verify", "--sweep", "1", "--time-limit", "1", "--seed", "5", "--max-delay", "3", "--seed-bug", "skip-delta",
          "--shrink", "0", "--quiet"])
    assert "messages within 3 steps, bugs skip-delta" in capsys.readouterr().out


@pytest.mark.parametrize(("mode", "flags"), [
    (["--sweep", "2"], ["--grid", "8x8", "--drones", "3"]),
    (["--table3"], ["--grid", "8x8", "--drones", "3"]),
    (["--table3"], ["--max-delay", "0", "--seed-bug", "skip-delta", "--crashes", "1"]),
])
def test_a_sweep_and_the_papers_table_refuse_what_they_set_themselves(
        mode: list[str], flags: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """Given anyway, ``--drones`` or ``--grid`` (and to the paper's table, a delay, a bug or a fault) was
    silently ignored: the run was not the one asked for."""
    assert main(["verify", *mode, *flags, "--time-limit", "0.2", "--max-depth", "3", "--quiet"]) == 2
    named = ", ".join(f for f in flags if f.startswith("--"))
    assert f"{mode[0]} sets {named} itself: leave them out" in " ".join(capsys.readouterr().err.split())
    assert main(["verify", "--sweep", "2", "--table3"]) == 2


def test_dfs_explores_at_no_delay_unless_told() -> None:
    parser = argparse.ArgumentParser()
    verify_cli.add_arguments(parser)

    def delay(*flags: str) -> int:
        return verify_cli._scenario(parser.parse_args(["--max-depth", "3", *flags])).max_delay

    assert (delay("--strategy", "dfs"), delay(), delay("--strategy", "dfs", "--max-delay", "3")) == (0, 2, 3)


@pytest.mark.parametrize("side", [8, 16, 32])
def test_a_slower_network_gives_each_leg_its_longer_lead(side: int) -> None:
    """At a delay of 3 steps or more, each of a mail's three legs takes a longer lead, and every draw on
    16x16 was refused (no mail a charged drone could fly): the mixed fleet's drone, which charges the
    least, affords those steps more, and a draw on 16x16 finds its mail."""
    workspace = Workspace.build(size=(side, side, 1))
    least = _battery_for(workspace).steps_affordable(UPGRADE.recharged_mark)
    for extra in range(1, 9):
        assert _battery_for(workspace, extra).steps_affordable(UPGRADE.recharged_mark) == least + 3 * extra
    rng = random.Random(side)
    for _ in range(3):
        scenario = Scenario(drones=4, requests=6, delta=rng.randrange(3), seed=rng.randrange(1_000_000),
                            grid=(16, 16, 1), obstacles=0.2, max_delay=rng.randint(3, 5))
        scenario.world_config(scenario.workspace())  # refused (ProblemError) when no mail is affordable


@pytest.mark.parametrize("side", [8, 16, 22, 32])
def test_the_default_delay_keeps_the_battery_the_sweeps_found_their_bugs_with(side: int) -> None:
    """The regression scenarios found by sweeps (at the default delay) must stay as they were found: the
    default battery where it crosses the grid and back, else one draining slower by just that much."""
    workspace = Workspace.build(size=(side, side, 1))
    default = BatteryModel()
    need = 2 * (2 * side + 1 - 3) + default.margin_steps
    affordable = default.steps_affordable(95.0)
    drain = math.floor(default.drain_per_step * affordable / need * 2**20) / 2**20  # exact in floating point
    kept = default if need <= affordable else BatteryModel(drain_per_step=drain)
    assert _battery_for(workspace) == kept
    scenario = Scenario(drones=4, requests=4, seed=7, grid=(side, side, 1))
    assert scenario.world_config(scenario.workspace()).battery == kept


@pytest.mark.parametrize("side", [8, 16, 22, 32])
def test_a_drone_flown_as_far_as_its_battery_affords_ends_at_the_threshold_not_below(side: int) -> None:
    """From every level the world's battery reaches (100 % drained step by step, and charged again), flying
    the steps the planner affords, by the world's arithmetic, ends at or above the threshold: a drain such
    as 70 / 82.5 a step does not add up exactly, and a sweep found a drone a rounding error below it."""
    workspace = Workspace.build(size=(side, side, 1))
    for extra in range(9):
        model = _battery_for(workspace, extra)
        levels, level = {100.0}, 100.0
        while level > model.safe_threshold:
            level = max(0.0, level - model.drain_per_step)
            levels |= {level, *(min(100.0, level + k * model.charge_per_step) for k in range(1, 20))}
        for start in (s for s in levels if s >= model.safe_threshold):
            level = start
            for _ in range(model.steps_affordable(start)):
                level -= model.drain_per_step
            assert level >= model.safe_threshold, f"extra lead {extra}: {start}% flown to {level}%"


def test_a_counterexample_is_the_same_whatever_the_hash_seed() -> None:
    """Two processes with different string hashing find the same trace, naming the same peers."""
    def run(hash_seed: str) -> list[str]:
        command = [sys.executable, "-m", "fleet.cli", "verify", "--grid", "8x8", "--drones", "5", "--requests", "6",
                   "--seed", "11", "--seed-bug", "stale-trajectory", "--strategy", "pct", "--time-limit", "20",
                   "--quiet", "--shrink", "0"]
        done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False,
                              env={**os.environ, "PYTHONHASHSEED": hash_seed})
        assert done.returncode == 1, f"exit {done.returncode}: {done.stdout}{done.stderr}"  # 1: a violation
        return done.stdout.splitlines()[1:]  # the first line has timings

    first = run("1")
    assert any("VIOLATION" in line for line in first), first
    assert run("2") == first


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
