"""The systematic tester finds every seeded bug by the monitors each should trip, and the code
that flies carries none.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

import drona_gcs.planner
import drona_gcs.stack
from drona_gcs.stack.mail import MailPlanner
from drona_gcs.stack.protocol import CoordinationProtocol
from drona_gcs.verify.explore import Explorer, Scenario, Strategy
from drona_gcs.verify.mutants import SEEDED_BUGS
from tests.drona_gcs.verify.verify_helpers import NEEDS

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


def test_the_code_that_flies_carries_no_seeded_bug() -> None:
    """Seeded bugs live in the tester (drona_gcs.verify.mutants), never in the stack's handlers."""
    flown = [*Path(drona_gcs.stack.__file__).parent.glob("*.py"),
             *Path(drona_gcs.planner.__file__).parent.glob("*.py")]
    hooks = [(path.name, bug) for path in flown for bug in SEEDED_BUGS if bug in path.read_text()]
    assert hooks == []
    for machine in (CoordinationProtocol, MailPlanner):
        assert "bugs" not in {f.name for f in dataclasses.fields(machine)}
