"""``drona bench mavlink`` on a tiny fleet: it runs, stops by itself and reports sane figures.

Real MAVLink bytes on 127.0.0.1: 4 fake vehicles in a ``drona sim-vehicle`` subprocess and 4
links for 2 s of telemetry, then 2 setpoint loops at tau 0.2 s. A smoke test of the benchmark,
not of the targets (those need the full 128-vehicle run on a quiet machine).
"""

from __future__ import annotations

import json
import time

import pytest

from fleet.bench.mavlink import expected_rate
from fleet.cli import main as drona_main

TINY = ["bench", "mavlink", "--vehicles", "4", "--seconds", "2", "--warmup", "1", "--loops", "2", "--tau", "0.2",
        "--boundaries", "5"]


def test_a_tiny_run_reports_every_field_with_sane_values(capsys: pytest.CaptureFixture[str]) -> None:
    started = time.monotonic()
    assert drona_main([*TINY, "--json"]) == 0
    assert time.monotonic() - started < 30
    rows = {row["bench"]: row for row in map(json.loads, capsys.readouterr().out.splitlines())}
    assert set(rows) == {"telemetry", "setpoint_jitter"}

    t = rows["telemetry"]
    assert t["vehicles"] == 4 and t["stream_hz"] == 10.0
    assert t["expected_per_link"] == pytest.approx(expected_rate(10.0))
    # Four vehicles are nothing for a machine: every link gets (nearly) all it asked for, promptly.
    assert 0.8 * t["expected_per_link"] <= t["min_per_link"] <= t["mean_per_link"] <= 1.1 * t["expected_per_link"]
    assert t["links_behind"] == 0 and t["keeps_up"] is True
    assert abs(t["delay_growth_ms_max"]) < 50
    assert 0 <= t["position_age_ms_max"] < 1000
    assert t["links_cpu_s_per_s"] > 0 and t["links_cpu_ms_per_vehicle"] > 0
    assert t["vehicles_cpu_s_per_s"] is None or t["vehicles_cpu_s_per_s"] > 0
    assert t["rx_drops"] in (None, 0)

    j = rows["setpoint_jitter"]
    assert (j["loops"], j["tau_s"], j["boundaries"], j["samples"]) == (2, 0.2, 5, 10)
    assert 0 <= j["late_ms_p50"] <= j["late_ms_p99"] <= j["late_ms_max"] < 200
    assert j["meets_target"] == (j["late_ms_p99"] <= j["target_p99_ms"])


def test_the_summary_names_the_targets(capsys: pytest.CaptureFixture[str]) -> None:
    assert drona_main(["bench", "mavlink", "--vehicles", "2", "--seconds", "1", "--warmup", "0.5",
                       "--only", "telemetry"]) == 0
    out = capsys.readouterr().out
    for text in ("Telemetry: 2 vehicles", "messages per link", "position delay growth", "CPU, vehicles' process",
                 "CPU, links' process", "ms/s per vehicle", "keeps up", "128 vehicles at 10 Hz"):
        assert text in out
    assert "Setpoint jitter" not in out


def test_bad_options_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert drona_main(["bench", "mavlink", "--vehicles", "0"]) == 2
    assert "--vehicles must be >= 1" in capsys.readouterr().err
