"""``drona bench coordination --json``: a short run of real agents, vehicles and Zenoh on loopback
gives one strict-JSON row (a missing figure is null, never NaN) with the layout it ran."""

from __future__ import annotations

import asyncio
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from drona_gcs.stack.protocol import State
from drona_gcs.workspace_files import workspace_from_mapping
from fleet.bench import BenchError
from fleet.bench.coordination import audit_records, bench_workspace, default_processes, gather_records
from fleet.bench.latency import PlanLatencies, _keep_busy, between_rounds
from fleet.cli import main
from fleet.transport.fleet_client import FleetClient
from fleet.transport.keys import FleetKeys
from fleet.transport.wire import DroneState
from tests.fakes.node import FakeNode


def _strict(constant: str) -> object:
    raise ValueError(f"not JSON: {constant}")


class _Fleet:
    """A fleet client whose drones answer with a fixed mode each."""

    def __init__(self, modes: dict[str, State]) -> None:
        self.modes, self.asked = modes, 0

    async def states(self) -> dict[str, DroneState]:
        self.asked += 1
        return {d: DroneState(drone=d, step=1, cell=[0, 0, 0], mode=m.value, phase="idle", landed=False)
                for d, m in self.modes.items()}


def test_a_fleet_never_between_rounds_is_measured_anyway_saying_which_drones_were_busy(
        capsys: pytest.CaptureFixture[str]) -> None:
    """The benchmark waits for the fleet between rounds, but not for ever; the figures then count part
    of a round (or mail given to drones not yet parked), and the user must be told which drones."""
    busy = _Fleet({"d1": State.WAIT_FOR_TASK, "d2": State.EXECUTING, "d3": State.COORDINATING})
    states = asyncio.run(between_rounds(busy, 0.1, idle=True))  # type: ignore[arg-type]
    assert set(states) == {"d1", "d2", "d3"} and busy.asked > 1
    assert "after 0.1 s, drones still flying or coordinating: d2, d3; measuring anyway" in capsys.readouterr().err
    # Between rounds a plan flown does not count; and a fleet between rounds is taken at once, silently.
    flying = _Fleet({"d1": State.WAIT_FOR_TASK, "d2": State.EXECUTING})
    assert set(asyncio.run(between_rounds(flying, 5.0))) == {"d1", "d2"}  # type: ignore[arg-type]
    assert flying.asked == 1 and capsys.readouterr().err == ""


def test_a_fleet_that_does_not_take_its_mail_is_a_bench_error_naming_the_drone() -> None:
    """128 drones in two processes answered their first orders after the client's 2 s: the bench died
    with a traceback of the task group. It waits longer, and says which drone did not answer, and how
    long it waited."""
    workspace = workspace_from_mapping(yaml.safe_load(bench_workspace(4)))
    node, keys = FakeNode(), FleetKeys("bench")  # no drone answers on it
    with pytest.raises(BenchError, match=r"^drone d1 did not answer the mail order b1 within 10 s$"):
        asyncio.run(_keep_busy(node, FleetClient(node, keys, "bench"), keys, workspace,  # type: ignore[arg-type]
                               ["d1"], 1.0, 1, {}))


def _state(drone: str, plans: int, ms: float | None) -> DroneState:
    return DroneState(drone=drone, step=1, cell=[0, 0, 0], mode=State.EXECUTING.value, phase="idle", landed=False,
                      plans=plans, coordination_ms=ms)


def test_only_plans_made_for_the_mail_count_each_once() -> None:
    """The moves to the parking cells at start-up are planned too, while the last process may still be
    joining: counted, they would measure start-up. A state repeats its drone's last plan: once only."""
    latencies = PlanLatencies()
    latencies.observe(_state("d1", 1, 900.0), now=1.0)  # parking, before the fleet was between rounds
    latencies.count_after({"d1": _state("d1", 2, 800.0), "d2": _state("d2", 0, None)})
    latencies.observe(_state("d1", 2, 800.0), now=2.0)  # still the parking plan
    latencies.observe(_state("d3", 5, 700.0), now=2.0)  # a drone not between rounds: not counted
    latencies.observe(_state("d1", 3, 12.0), now=3.0)
    latencies.observe(_state("d1", 3, 12.0), now=4.0)  # the same plan, stated again
    latencies.observe(_state("d2", 1, 30.0), now=5.0)
    latencies.observe(_state("d2", 2, None), now=6.0)  # no latency reported: nothing to count
    assert latencies.since() == [12.0, 30.0]
    assert latencies.since(4.0) == [30.0]  # when first seen, not when stated again
    assert latencies.first(until=5.0) == 12.0 and latencies.first(4.0) == 30.0  # the opening's, the rest's
    assert math.isnan(latencies.first(until=2.5))
    latencies.observe(_state("d1", 4, 5.0), now=7.0)
    assert latencies.first() == 12.0  # the first one seen, not the quickest
    assert latencies.first_seen() == {"d1": 3.0, "d2": 5.0}  # each drone's first plan counted


@pytest.mark.parametrize("agents", [4, 32, 64, 128, 200])
def test_the_bench_workspace_is_valid_at_every_size(agents: int) -> None:
    """`drona bench coordination --agents 64` did not start: drones parked beside a charger walled it off."""
    ws = workspace_from_mapping(yaml.safe_load(bench_workspace(agents)), name=f"bench-{agents}")
    assert len(ws.drones) == agents and len(ws.parking) == agents


def test_the_agents_records_are_gathered_and_audited(tmp_path: Path) -> None:
    """Each agent process records its drones; the bench gathers the parts into one file, with the
    workspace beside it, and audits it: two drones in one cell at one step is a violation. The user's
    files beside the record are left alone: the bench once gathered (and deleted) every ``run.jsonl.*``,
    a ``run.jsonl.err`` the user sent the bench's errors to included."""
    record, parts = tmp_path / "run.jsonl", tmp_path / "bench"
    parts.mkdir()
    mine = tmp_path / "run.jsonl.err"
    mine.write_text("the user's own file\n")
    line = '{{"step": {step}, "drone": "{drone}", "cell": [{x}, 0, 0], "planned": [{x}, 0, 0], "delta": 5}}\n'
    (parts / "flight.d1").write_text(line.format(step=1, drone="d1", x=2) + line.format(step=2, drone="d1", x=3))
    (parts / "flight.d3").write_text(line.format(step=1, drone="d3", x=4) + line.format(step=2, drone="d3", x=3))
    gather_records(record, sorted(parts.glob("flight.*")))
    verdict = audit_records(record, bench_workspace(4))
    assert "4 records" in verdict and "delta 5" in verdict and "separation violations, 0 jumps" in verdict, verdict
    assert len(record.read_text().splitlines()) == 4 and mine.read_text() == "the user's own file\n"
    assert (tmp_path / "run.jsonl.workspace.yaml").read_text() == bench_workspace(4)


def test_a_record_cut_mid_line_by_a_kill_keeps_its_whole_lines(tmp_path: Path) -> None:
    """A process killed (``--fault kill``) may leave half a line: the record keeps the lines before it."""
    line = '{"step": 1, "drone": "d1", "cell": [2, 0, 0], "planned": [2, 0, 0], "delta": 3}\n'
    (tmp_path / "flight.d1").write_text(line + line[:30])
    (tmp_path / "flight.d2").write_text(line.replace("d1", "d2").replace("[2", "[4"))
    record = tmp_path / "run.jsonl"
    gather_records(record, sorted(tmp_path.glob("flight.*")))
    assert [json.loads(each)["drone"] for each in record.read_text().splitlines()] == ["d1", "d2"]


def _last_steps(record: Path) -> dict[str, int]:
    last: dict[str, int] = {}
    for line in record.read_text().splitlines():
        entry = json.loads(line)
        last[entry["drone"]] = max(entry["step"], last.get(entry["drone"], 0))
    return last


def test_a_short_run_with_a_drone_killed_gives_one_strict_json_row_and_records_that_audit(tmp_path: Path) -> None:
    """A short run gives one strict-JSON row (a missing figure is null, never NaN) with the layout it ran.
    With ``--fault kill`` the last drone's agent, in a process of its own, is killed mid-run: its flight
    record stops there while its vehicle, left hovering, is in the simulator's to the end; the others fly
    on; both records are audited, and the fault is in the row."""
    agents, record = 4, tmp_path / "run.jsonl"
    done = subprocess.run([sys.executable, "-m", "fleet.cli", "bench", "coordination", "--agents", str(agents),
                           "--seconds", "16", "--steady-after", "30", "--fault", "kill", "--fault-at", "3",
                           "--record", str(record), "--json"], check=False, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    row = json.loads(done.stdout.strip().splitlines()[-1], parse_constant=_strict)
    assert row["agents"] == agents
    # The struck drone has an agent process of its own, beside one per core for the rest.
    assert row["processes"] == min(len(os.sched_getaffinity(0)), agents - 1) == min(default_processes(), agents - 1)
    assert row["plans"] >= agents  # every drone was given mail at once
    assert 0 < row["p50_ms"] <= row["p99_ms"] <= row["max_ms"]
    # A plan proposed at once and held is 3(N-1) messages: its proposal, each ack and the decision. One
    # not held goes on as a round, 2(N-1) more ((N-1) when the whole fleet coordinates at once: a request
    # is its sender's answer to the drones before it in line, and a decision its sender's answer to those
    # after it); more only when a round ends with no plan and is tried again. N is 3 once d4 is killed.
    assert 3 * (agents - 2) <= row["messages_per_round"] <= 7 * (agents - 1), row
    assert row["steady_plans"] == 0 and row["steady_p50_ms"] is None  # nothing 30 s into a 16 s run
    assert row["cpu_ms_per_s_per_agent"] > 0
    assert 0 < row["reference_ms_before"] < 60_000 and 0 < row["reference_ms_after"] < 60_000
    # The opening burst: its head of the line flew first, and the agent processes worked meanwhile.
    assert 0 < row["opening_first_ms"] <= row["max_ms"]
    assert len(row["opening_cpu_ms"]) == row["processes"] and sum(row["opening_cpu_ms"]) > 0
    # From the mail given to each drone's first plan: at least its coordination, at most the whole run.
    assert row["opening_first_ms"] <= row["opening_last_first_plan_ms"] < 1000 * row["seconds"]
    assert 0 < row["opening_first_plan_p50_ms"] <= row["opening_last_first_plan_ms"]
    assert len(row["fault"]) == 1 and row["fault"][0].startswith("struck at "), row["fault"]
    flown, truth = _last_steps(record), _last_steps(record.with_suffix(".truth.jsonl"))
    others = min(flown[d] for d in ("d1", "d2", "d3"))
    assert flown["d4"] < others - 10, flown  # 13 s (26 steps) of mail after the kill
    assert truth["d4"] >= others, truth
    assert done.stderr.count(", safe, 0 jumps") == 2, done.stderr[-2000:]


@pytest.mark.parametrize(("flags", "said"), [
    (["--agents", "2", "--fault", "kill"], "--fault needs --agents >= 3"),
    (["--seconds", "40", "--fault", "vehicle", "--fault-at", "45"], "the fault over (--fault-at, and --fault-for"),
    (["--seconds", "60", "--fault", "partition", "--fault-at", "20", "--fault-for", "40"], "before --seconds (60)"),
])
def test_a_fault_that_cannot_strike_within_the_run_is_refused_before_anything_starts(
        flags: list[str], said: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "coordination", *flags]) == 2
    assert said in capsys.readouterr().err
