"""The systematic tester: it finds every seeded bug, replays exactly, and passes the clean stack."""

from __future__ import annotations

from pathlib import Path

import pytest

from drona_gcs.errors import DronaError, ProblemError
from drona_gcs.verify.explore import SEEDED_BUGS, Explorer, Scenario, Strategy, decode_token, encode_token
from fleet.cli import main

#: Which monitor each seeded bug should trip: (a) stale Psi, (b) collision, (d) a request never
#: delivered, (e) battery.
EXPECTED = {
    "stale-trajectory": {"a", "b"},
    # Requests are answers to the drones before them in line: ranked the wrong way round, a drone
    # may wait for good, and hover until its battery runs low.
    "tie-break-reversed": {"a", "b", "d", "e"},
    "answer-while-coordinating": {"a", "b"},
    "no-battery-check": {"e"},
    "skip-delta": {"b"},
}


def test_every_seeded_bug_has_an_expectation() -> None:
    assert set(EXPECTED) == set(SEEDED_BUGS)


@pytest.mark.parametrize("bug", sorted(SEEDED_BUGS))
@pytest.mark.parametrize("strategy", [Strategy.RANDOM, Strategy.PCT])
def test_each_seeded_bug_is_found(bug: str, strategy: Strategy) -> None:
    explorer = Explorer(Scenario(drones=4, requests=6, delta=1, seed=0, bugs=(bug,)))
    outcome = explorer.run(strategy, schedules=300, max_depth=4000, seed=1)
    assert outcome.violation is not None, f"{bug} not found in {outcome.schedules} schedules"
    assert outcome.violation.monitor in EXPECTED[bug], str(outcome.violation)
    assert outcome.choices and outcome.trace


@pytest.mark.parametrize("bug", sorted(SEEDED_BUGS))
def test_replaying_a_token_reproduces_the_same_trace(bug: str) -> None:
    scenario = Scenario(drones=3, requests=5, delta=1, seed=3, bugs=(bug,))
    found = Explorer(scenario).run(Strategy.RANDOM, schedules=300, max_depth=4000, seed=2)
    assert found.violation is not None
    scenario_back, choices = decode_token(encode_token(scenario, found.choices))
    assert scenario_back == scenario and choices == found.choices
    again = Explorer(scenario_back).replay(choices)
    assert again.trace == found.trace
    assert str(again.violation) == str(found.violation)


@pytest.mark.parametrize(("drones", "delta", "seed"), [(2, 0, 1), (3, 1, 2), (4, 1, 0), (4, 2, 5)])
def test_clean_stack_passes_random_and_pct_exploration(drones: int, delta: int, seed: int) -> None:
    explorer = Explorer(Scenario(drones=drones, requests=6, delta=delta, seed=seed))
    for strategy in (Strategy.RANDOM, Strategy.PCT):
        outcome = explorer.run(strategy, schedules=25, max_depth=6000, seed=seed)
        assert outcome.violation is None, "\n".join([str(outcome.violation), *outcome.trace[-30:]])
        assert outcome.schedules == 25


def test_clean_stack_passes_exhaustive_dfs_to_a_small_depth() -> None:
    outcome = Explorer(Scenario(drones=2, requests=1, delta=1, seed=0)).run(Strategy.DFS, 0, 12, 0)
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


@pytest.mark.parametrize("name", ["16_4", "Delta", "Exp1", "Exp6", "32_32"])
def test_clean_stack_on_the_original_drona_workspaces(name: str, shared_dir: Path) -> None:
    path = shared_dir / "drona-workspaces" / name / "Workspace.xml"
    explorer = Explorer(Scenario(drones=2, requests=4, delta=1, seed=1, workspace_path=str(path)))
    outcome = explorer.run(Strategy.RANDOM, schedules=10, max_depth=6000, seed=1)
    assert outcome.violation is None, str(outcome.violation)
    assert outcome.schedules == 10
