"""``drona bench coordination --json``: a short run of real agents, vehicles and Zenoh on loopback
gives one strict-JSON row (a missing figure is null, never NaN) with the layout it ran."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from fleet.bench_coordination import default_processes


def _strict(constant: str) -> object:
    raise ValueError(f"not JSON: {constant}")


def test_a_short_run_gives_one_strict_json_row_with_its_figures() -> None:
    agents = 4
    done = subprocess.run([sys.executable, "-m", "fleet.cli", "bench", "coordination", "--agents", str(agents),
                           "--seconds", "4", "--json"], check=False, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-2000:]
    row = json.loads(done.stdout.strip().splitlines()[-1], parse_constant=_strict)
    assert row["agents"] == agents
    assert row["processes"] == min(len(os.sched_getaffinity(0)), agents) == min(default_processes(), agents)
    assert row["plans"] >= agents  # every drone was given mail at once
    assert 0 < row["p50_ms"] <= row["p99_ms"] <= row["max_ms"]
    # a round is 2(N-1) messages; more only when a round ends with no plan and is tried again
    assert 2 * (agents - 1) <= row["messages_per_round"] <= 4 * (agents - 1)
    assert row["steady_plans"] == 0 and row["steady_p50_ms"] is None  # 4 s: nothing after the opening
    assert row["cpu_ms_per_s_per_agent"] > 0
