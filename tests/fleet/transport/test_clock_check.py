"""The fleet's clock check: offsets from the round trip, and skew judged right.
"""

from __future__ import annotations

import asyncio
import socket

import pytest

from fleet.agent.clocksync import ClockCheck, OffsetSample
from fleet.sim.ports import free_port
from fleet.transport.node import Reply, ZenohNode
from fleet.transport.settings import ZenohSettings


def test_offset_is_measured_from_the_round_trip_midpoint() -> None:
    sample = OffsetSample.measure(sent=100.0, peer_time=100.31, received=100.02)
    assert sample.offset_s == pytest.approx(0.30)
    assert sample.error_s == pytest.approx(0.01)


def test_skew_is_an_alarm_only_when_provably_beyond_beta() -> None:
    check = ClockCheck(beta_s=0.2)
    check.observe("d2", OffsetSample(0.205, 0.01))  # could be 0.195: within beta
    check.observe("d3", OffsetSample(-0.15, 0.001))
    assert check.alarm() is None
    check.observe("d4", OffsetSample(-0.35, 0.01))
    alarm = check.alarm()
    assert alarm is not None and "d4" in alarm and "-350.0 ms" in alarm
    check.forget("d4")
    assert check.alarm() is None


def test_the_offsets_a_drone_states_follow_each_sample_and_forgotten_peer() -> None:
    check = ClockCheck(beta_s=0.2)
    check.observe("d3", OffsetSample(0.0300004, 0.01))
    check.observe("d2", OffsetSample(-0.1, 0.02))
    assert check.offsets_s() == {"d2": -0.1, "d3": 0.03}
    check.observe("d2", OffsetSample(-0.05, 0.001))  # tighter: it is the one judged and stated
    check.forget("d3")
    assert check.offsets_s() == {"d2": -0.05}


def test_the_clock_off_is_the_one_most_peers_disagree_with() -> None:
    """One skewed clock must not stall the fleet: the drones whose clocks agree plan on around it, and
    it alone holds. With two drones neither can tell which clock is off: both hold."""
    others = ClockCheck(beta_s=0.2)
    others.observe("d2", OffsetSample(0.01, 0.001))
    others.observe("d3", OffsetSample(2.0, 0.001))
    assert not others.mine_is_off() and "d3 out of the fleet's bound" in (others.alarm() or "")
    skewed = ClockCheck(beta_s=0.2)
    skewed.observe("d1", OffsetSample(-2.0, 0.001))
    skewed.observe("d2", OffsetSample(-1.99, 0.001))
    assert skewed.mine_is_off() and "mine is off" in (skewed.alarm() or "")
    pair = ClockCheck(beta_s=0.2)
    pair.observe("d2", OffsetSample(2.0, 0.001))
    assert pair.mine_is_off(fleet=1)
    first = ClockCheck(beta_s=0.2)  # only the skewed peer answered yet, of two
    first.observe("d3", OffsetSample(2.0, 0.001))
    assert not first.mine_is_off(fleet=2)


def test_beta_zero_does_not_alarm_on_loopback_noise() -> None:
    check = ClockCheck(beta_s=0.0)
    check.observe("d2", OffsetSample(0.00004, 0.0001))
    assert check.violations() == {}


def test_a_query_under_way_ends_when_its_session_closes() -> None:
    """A peer that never answers must not hang a closing agent (every wait is bounded)."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"

    async def scenario() -> list[Reply]:
        silent = await ZenohNode.open(ZenohSettings(listen=(endpoint,)), "silent")
        asker = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "asker")
        held: list[object] = []  # queries kept unanswered: the asker waits up to its 30 s timeout
        silent._declared.append(silent.session.declare_queryable("t/q", held.append))
        try:
            await asyncio.sleep(0.3)  # the link forms (no event to wait on in zenoh-python for it)
            query = asyncio.ensure_future(asker.get("t/q", b"", 30.0))
            await asyncio.sleep(0.3)
            assert not query.done() and held
            await asker.close()
            return await asyncio.wait_for(query, 5.0)
        finally:
            held.clear()
            await asker.close()
            await silent.close()

    assert asyncio.run(scenario()) == []


def test_one_slow_answer_neither_hides_a_skew_nor_clears_the_alarm() -> None:
    check = ClockCheck(beta_s=0.05)
    check.observe("d2", OffsetSample(0.2, 0.001))  # a tight sample: 200 ms off
    assert check.alarm() is not None
    check.observe("d2", OffsetSample(0.2, 0.4))  # the peer was busy: a round trip of 800 ms
    assert check.alarm() is not None
