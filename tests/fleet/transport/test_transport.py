"""The fleet's wire format, keys and clock check: what crosses Zenoh is validated, and skew is judged right."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import re
import socket
import sys
import threading
import time

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import CurrentTraj, ReqForCurrentTraj, TaskId
from drona_gcs.workspace import Workspace
from fleet.agent.clocksync import ClockCheck, OffsetSample
from fleet.sim.ports import free_port
from fleet.sim.transport import UdpLink
from fleet.transport import inbox as inbox_module
from fleet.transport.gateway import ZenohGateway
from fleet.transport.gather import Gathered
from fleet.transport.inbox import ORDINARY_WAITS_AT_MOST_S, Inbox
from fleet.transport.keys import FleetKeys, check_name
from fleet.transport.node import Reply, SampleHandler, ZenohNode
from fleet.transport.settings import ZenohSettings
from fleet.transport.wire import (
    VERSION,
    MailOrder,
    WireError,
    answers,
    checked,
    decode,
    encode,
    from_core,
    to_core,
    to_json,
)
from fleet.vehicle.urls import open_transport, parse_link_url

TASK = TaskId(12, "d1", 3)


@pytest.mark.parametrize("message", [
    ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), ("d2", "d3")),
    CurrentTraj("d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), TASK),
])
def test_protocol_messages_round_trip(message: object) -> None:
    envelope = decode(encode("d1", 5.5, from_core(message)))  # type: ignore[arg-type]
    assert envelope.sender == "d1" and envelope.sent_at == 5.5
    assert to_core(envelope, "d2") == message


def test_one_answer_to_several_drones_is_each_ones_answer_and_nothing_to_the_others() -> None:
    trajectory = Trajectory(40, ((1, 2, 0), (2, 2, 0)))
    asked_by_d3, asked_by_d4 = TaskId(12, "d3", 1), TaskId(13, "d4", 2)
    envelope = decode(encode("d1", 5.5, answers(trajectory, {"d3": asked_by_d3, "d4": asked_by_d4})))
    assert to_core(envelope, "d3") == CurrentTraj("d1", trajectory, asked_by_d3)
    assert to_core(envelope, "d4") == CurrentTraj("d1", trajectory, asked_by_d4)
    assert to_core(envelope, "d5") is None


def envelope(body: dict[str, object], **over: object) -> bytes:
    return json.dumps({"v": VERSION, "sender": "d2", "sent_at": 1.0, "body": body, **over}).encode()


@pytest.mark.parametrize("payload, problem", [
    (b"not json", "JSON is malformed"),
    (b'{"v": 13, "sender": "d\xff", "sent_at": 1.0, "body": {"kind": "clock_ping"}}', "not UTF-8"),
    (envelope({"kind": "clock_ping"}, v=3), "Invalid enum value 3 - at `$.v`"),
    (envelope({"kind": "teleport"}), "Invalid value 'teleport' - at `$.body.kind`"),
    (envelope({"kind": "req_traj", "task_id": {"stamp": "12", "drone": "d1", "seq": 1}}),
     "Expected `int`, got `str` - at `$.body.task_id.stamp`"),
    (envelope({"kind": "cur_traj_to", "replies": {}, "trajectory": {"start_step": 3, "cells": [[1, 1, 0]]}}),
     "at `$.body.replies`"),
    (envelope({"kind": "req_traj", "task_id": {"stamp": 1, "drone": "d1", "seq": 1}, "extra": 1}),
     "unknown field `extra`"),
    (envelope({"kind": "req_traj", "task_id": {"stamp": 1, "drone": "d1", "seq": 1}}),
     "missing required field `trajectory` - at `$.body`"),  # a drone before it in line takes it as its answer
    (envelope({"kind": "cur_traj", "in_reply_to": {"stamp": 1, "drone": "d1", "seq": 1},
               "trajectory": {"start_step": 3, "cells": []}}),
     "at `$.body.trajectory.cells`"),
    (envelope({"kind": "mail", "id": "m/1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5}),
     "at `$.body.id`"),
    (envelope({"kind": "mail", "id": "m1\n", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5}),
     "at `$.body.id`"),  # a Zenoh key chunk: no newline, even a final one
    (envelope({"kind": "held", "drone": "d1", "mail": [{"id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0],
                                                        "priority": 42, "stage": "queued"}]}),
     "at `$.body.mail[0].priority`"),  # what an heir takes over is checked as an order is
    (envelope({"kind": "mail", "id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 10}),
     "Expected `int` <= 9 - at `$.body.priority`"),
])
def test_a_malformed_or_foreign_payload_is_refused_naming_what_is_wrong(payload: bytes, problem: str) -> None:
    with pytest.raises(WireError, match="malformed message") as caught:
        decode(payload)
    assert problem in str(caught.value)


def test_a_payload_handed_to_every_drone_of_a_process_is_validated_once() -> None:
    payload = encode("d1", 2.0, from_core(CurrentTraj("d1", Trajectory(3, ((1, 1, 0), (1, 2, 0))), TASK)))
    first = decode(payload)
    assert decode(bytes(bytearray(payload))) is first  # equal (not the same) bytes: validated already
    broken = payload.replace(b'"cells"', b'"cels"')
    for _ in range(2):  # a bad payload is refused every time, not remembered as good
        with pytest.raises(WireError, match="cels"):
            decode(broken)


def test_the_wire_format_is_the_documented_json() -> None:
    """Other tools read these bytes: the envelope's fields in order, the body tagged by its kind."""
    request = ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), ("d2",))
    payload = encode("d1", 5.5, from_core(request))
    assert payload == (b'{"v":13,"sender":"d1","sent_at":5.5,"body":{"kind":"req_traj",'
                       b'"task_id":{"stamp":%d,"drone":"%s","seq":%d,"epoch":0},'
                       b'"trajectory":{"start_step":40,"cells":[[1,2,0],[2,2,0]]},"asked":["d2"],"holds":[],"clear":[]}}'
                       % (TASK.stamp, TASK.drone.encode(), TASK.seq))


def test_the_cells_a_lost_vehicle_holds_travel_with_requests_and_answers() -> None:
    """A drone whose vehicle is lost names the cells it may be in; a peer's stack must get them as sent."""
    held = ((1, 2, 0), (2, 2, 0), (3, 2, 0))
    request = ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0), (2, 2, 0))), ("d2",), held)
    assert to_core(decode(encode("d1", 5.5, from_core(request))), "d2") == request
    asking = ReqForCurrentTraj(TASK, "d1", Trajectory(40, ((1, 2, 0),)), ("d2",), clear=((2, 2, 0), (3, 2, 0)))
    assert to_core(decode(encode("d1", 5.5, from_core(asking))), "d2") == asking
    answer = CurrentTraj("d1", Trajectory(40, ((1, 2, 0),)), TASK, held)
    assert to_core(decode(encode("d1", 5.5, from_core(answer))), "d2") == answer
    joined = answers(answer.trajectory, {"d2": TASK, "d3": TASK}, held)
    assert to_core(decode(encode("d1", 5.5, joined)), "d3") == answer


def test_a_message_built_by_hand_is_checked_as_one_from_the_wire() -> None:
    order = checked(MailOrder, id="m1", pickup=[1, 2, 0], dropoff=[3, 4, 0], priority=5)
    assert decode(encode("cli", 0.0, order)).body == order
    assert to_json(order) == {"id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5, "note": None}
    for fields, problem in (({"pickup": [1, 2]}, "at `$.pickup`"), ({"priority": 12}, "at `$.priority`"),
                            ({"id": "m 1"}, "at `$.id`")):
        with pytest.raises(WireError, match=re.escape(problem)):
            checked(MailOrder, **{"id": "m1", "pickup": [1, 2, 0], "dropoff": [3, 4, 0], "priority": 5, **fields})


def test_a_non_protocol_body_is_not_taken_for_a_protocol_message() -> None:
    order = MailOrder(id="m1", pickup=[1, 2, 0], dropoff=[3, 4, 0], priority=5)
    with pytest.raises(WireError, match="not a protocol message"):
        to_core(decode(encode("cli", 0.0, order)), "d1")


def test_keys_live_under_the_fleet_and_names_must_be_single_chunks() -> None:
    keys = FleetKeys("north")
    assert keys.proto("d1", "d2") == "drona/north/proto/d2/d1"
    assert keys.alive() == "drona/north/alive/*"
    assert keys.last_chunk(keys.status(mail="m-1")) == "m-1"
    # Whoever writes a key is named in it: the access control lets only that drone write there.
    written = [keys.proto("d1", "d2"), keys.proto("all", "d2"), keys.answers("d2"), keys.plan("d2"),
               keys.state("d2"), keys.held("d2"), keys.status("d2", "m-1"), keys.alive("d2")]
    assert {keys.writer(key) for key in written} == {"d2"}
    for bad in ("a/b", "*", "", "d 1", "d1\n"):
        with pytest.raises(ValueError, match="Zenoh key chunk"):
            check_name("drone", bad)


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


def test_drones_sharing_a_session_each_get_every_message_and_leave_alone() -> None:
    """Views of one session: a subscription per view (one Zenoh subscriber underneath), local and
    remote puts reach each view once, a view that closes stops hearing and its token goes, and the
    others (and the session) carry on."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"

    async def scenario() -> None:
        host = await ZenohNode.open(ZenohSettings(listen=(endpoint,)), "host")
        outside = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "outside")
        a, b = host.view("a"), host.view("b")
        heard: dict[str, list[bytes]] = {"a": [], "b": []}
        got = asyncio.Event()

        def hear(name: str) -> SampleHandler:
            def on(key: str, payload: bytes) -> None:
                heard[name].append(payload)
                got.set()
            return on

        async def settle(count: int) -> None:
            while min(len(v) for v in heard.values()) < count:
                got.clear()
                await asyncio.wait_for(got.wait(), 5)

        alive: set[str] = set()
        changed = asyncio.Event()

        def on_alive(key: str, up: bool) -> None:
            (alive.add if up else alive.discard)(key)
            changed.set()

        async def until_alive(expected: set[str]) -> None:
            while alive != expected:
                changed.clear()
                await asyncio.wait_for(changed.wait(), 5)

        try:
            a.subscribe("t/all", hear("a"))
            b.subscribe("t/all", hear("b"))
            a.token("t/alive/a")
            b.token("t/alive/b")
            outside.watch_liveliness("t/alive/**", on_alive)
            await until_alive({"t/alive/a", "t/alive/b"})
            a.put("t/all", b"local")
            await settle(1)
            for _ in range(50):  # the outside session learns the subscription with the link
                outside.put("t/all", b"remote")
                await asyncio.sleep(0.05)
                if len(heard["b"]) > 1:
                    break
            await settle(2)
            assert heard["a"][0] == heard["b"][0] == b"local"
            assert heard["a"].count(b"local") == 1 and heard["b"].count(b"local") == 1
            assert b"remote" in heard["a"] and b"remote" in heard["b"]

            await a.close()
            await until_alive({"t/alive/b"})
            before = len(heard["a"])
            b.put("t/all", b"after")
            while b"after" not in heard["b"]:
                got.clear()
                await asyncio.wait_for(got.wait(), 5)
            assert len(heard["a"]) == before  # a left: it hears nothing more
            assert not host.closed and not b.closed
        finally:
            await b.close()
            await host.close()
            await outside.close()

    asyncio.run(scenario())


@pytest.mark.parametrize(("now", "max_frames"), [(False, None), (True, None), (False, 2)])
def test_the_answers_of_a_sessions_drones_to_one_request_travel_as_one_message(now: bool,
                                                                               max_frames: int | None) -> None:
    """Three drones share a session and each answers a request to everyone: the requester gets the
    three answers, each handed to its handler alone, in one Zenoh message (gathered). Put ``now`` (a
    plan proposed while a decision is handed round: the next drone in line waits on it), each goes
    at once, alone. A session that takes at most ``max_frames`` messages a sample sends no more in one."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"

    async def scenario() -> tuple[list[bytes], list[bytes]]:
        host = await ZenohNode.open(ZenohSettings(listen=(endpoint,), max_frames=max_frames), "host")
        asker = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "asker")
        answers: list[bytes] = []
        messages: list[bytes] = []  # what Zenoh carried, before the node splits it
        got = asyncio.Event()

        def on_answer(key: str, payload: bytes) -> None:
            answers.append(payload)
            got.set()

        def answering(view: ZenohNode) -> SampleHandler:
            return lambda key, payload: view.put("t/answer", view.name.encode(), now=now)

        try:
            for name in ("a", "b", "c"):
                view = host.view(name)
                view.subscribe("t/all", answering(view), gather=True)
            asker.subscribe("t/answer", on_answer)
            asker._declared.append(asker.session.declare_subscriber(
                "t/answer", lambda sample: messages.append(sample.payload.to_bytes())))
            for _ in range(100):  # until the host's subscription has reached the asker
                asker.put("t/all", b"request")
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(got.wait(), 0.05)
                if answers:
                    break
            while len(answers) < 3:
                got.clear()
                await asyncio.wait_for(got.wait(), 5)
            return answers, messages
        finally:
            await asker.close()
            await host.close()

    answers, messages = asyncio.run(scenario())
    assert sorted(answers[:3]) == [b"a", b"b", b"c"]
    if now:
        assert messages[:3] == answers[:3]
    elif max_frames is None:
        assert messages[0].split(b"\n") == answers[:3]
    else:
        assert [m.split(b"\n") for m in messages[:2]] == [answers[:2], answers[2:3]]


def test_gathered_puts_join_by_key_and_never_send_a_nodes_put_before_its_earlier_one() -> None:
    """d2 and d3 (one host) ack on one key: one message. d3 then answers on its own key, and acks again on
    the first: joined to the first message, that ack would go out before d3's answer."""
    gathered = Gathered()
    gathered.add("d2", "proto/pair/d1", b"ack d2")
    gathered.add("d3", "proto/pair/d1", b"ack d3")
    gathered.add("d3", "answers/d3", b"answer d3")
    gathered.add("d3", "proto/pair/d1", b"again d3")
    gathered.add("d2", "proto/pair/d1", b"again d2")
    assert gathered.runs == [("proto/pair/d1", [b"ack d2", b"ack d3"]), ("answers/d3", [b"answer d3"]),
                             ("proto/pair/d1", [b"again d3", b"again d2"])]


def test_a_put_that_goes_at_once_sends_what_its_node_gathered_before_it() -> None:
    """d3 acks a proposal (gathered), then proposes its own plan at once: its ack goes first, with what was
    gathered before it; what comes after starts anew."""
    gathered = Gathered()
    gathered.add("d2", "proto/pair/d1", b"ack d2")
    gathered.add("d3", "proto/pair/d1", b"ack d3")
    gathered.add("d4", "answers/d4", b"answer d4")
    assert gathered.due("d3") == [("proto/pair/d1", [b"ack d2", b"ack d3"])]
    assert gathered.due("d5") == []  # nothing of d5's gathered: nothing to send first
    gathered.add("d2", "proto/pair/d1", b"again d2")
    assert gathered.due() == [("answers/d4", [b"answer d4"]), ("proto/pair/d1", [b"again d2"])]


def test_a_put_at_once_leaves_after_what_its_node_put_before_in_the_round() -> None:
    """Over real sessions: a drone handed a request to everyone answers one peer (gathered), then puts a
    plan at once; the peer gets the answer first."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"

    async def scenario() -> list[bytes]:
        host = await ZenohNode.open(ZenohSettings(listen=(endpoint,)), "host")
        peer = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "peer")
        got: list[bytes] = []
        try:
            view = host.view("a")

            def on_request(key: str, payload: bytes) -> None:
                view.put("t/answer", b"answer")
                view.put("t/plan", b"plan", now=True)

            view.subscribe("t/all", on_request, gather=True)
            peer._declared.append(peer.session.declare_subscriber(
                "t/*", lambda sample: got.append(sample.payload.to_bytes()) if str(sample.key_expr) != "t/all"
                else None))
            for _ in range(100):  # until the host's subscription has reached the peer
                peer.put("t/all", b"request")
                await asyncio.sleep(0.05)
                if len(got) >= 2:
                    break
            return got
        finally:
            await peer.close()
            await host.close()

    got = asyncio.run(scenario())
    assert got[:2] == [b"answer", b"plan"]


#: A fleet peer in a process of its own, as an agent is: it listens where the gateway connects, says
#: "up", and closes its session when its stdin ends, then exits.
PEER = """
import sys, zenoh
from fleet.transport.settings import ZenohSettings
session = zenoh.open(ZenohSettings(listen=(sys.argv[1],)).config())
print("up", flush=True)
sys.stdin.read()
session.close()
"""


@pytest.mark.parametrize("leaves", ["closes its session", "is killed"])
def test_the_service_gateway_is_open_only_while_linked_to_the_fleet(leaves: str) -> None:
    """``/readyz`` reads it: an open session that no peer is linked to reaches no drone.

    The peer runs in its own process because a peer leaves with its process. In one process, Zenoh
    (1.10.2) can keep a link up after ``close``: the gateway reconnects at once, and a link accepted
    while the session closes lives on, answering keep-alives (measured: 5 of 270 closes, one still up
    20 s later). The process exiting ends it, as it does for a real agent."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    ws = Workspace.build(size=(2, 2, 1), cell_size_m=1.0, tau_s=1.0)

    async def until(gateway: ZenohGateway, linked: bool) -> bool:
        for _ in range(100):  # polled, as /readyz asks it
            if gateway.is_open() is linked:
                return True
            await asyncio.sleep(0.05)
        return False

    async def start_peer() -> asyncio.subprocess.Process:
        peer = await asyncio.create_subprocess_exec(
            sys.executable, "-c", PEER, endpoint, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE)
        assert peer.stdout is not None
        assert await asyncio.wait_for(peer.stdout.readline(), 30) == b"up\n", "the peer never came up"
        return peer

    async def stop_peer(peer: asyncio.subprocess.Process) -> None:
        assert peer.stdin is not None
        if leaves == "is killed":
            peer.kill()
        else:
            peer.stdin.close()
        assert await asyncio.wait_for(peer.wait(), 30) == (-9 if leaves == "is killed" else 0)

    async def scenario() -> tuple[bool, bool, bool, bool]:
        gateway = ZenohGateway(ws, argparse.Namespace(fleet="t", connect=[endpoint], zenoh_config=None))
        running = asyncio.create_task(gateway.run())
        peer: asyncio.subprocess.Process | None = None
        try:
            await asyncio.wait_for(gateway.ready.wait(), 10)
            alone = gateway.is_open()
            peer = await start_peer()
            linked = await until(gateway, True)
            await stop_peer(peer)
            cut = await until(gateway, False)
        finally:
            if peer is not None and peer.returncode is None:
                peer.kill()
                await peer.wait()
            running.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await running
        return alone, linked, cut, gateway.is_open()

    alone, linked, cut, after = asyncio.run(scenario())
    assert not alone, "open with nobody to link to"
    assert linked, "a peer came up where the gateway connects: never linked"
    assert cut, f"the peer {leaves}: still linked"
    assert not after


def test_a_subscription_that_goes_first_is_handed_its_samples_before_ordinary_ones_waiting(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """What goes first (the protocol's messages, fleet.agent.drone) must not wait behind what can
    (announced plans, states): three ordinary samples and then a first one arrive while the loop is
    busy; the first one is handled first, the others in their order. So is one that arrives while an
    ordinary one is being handled: before the next."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    # The order by kind alone: no ordinary sample is to wait long enough here to go first by age.
    monkeypatch.setattr(inbox_module, "ORDINARY_WAITS_AT_MOST_S", 60.0)

    async def scenario() -> list[bytes]:
        host = await ZenohNode.open(ZenohSettings(listen=(endpoint,)), "host")
        outside = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "outside")
        handled: list[bytes] = []
        done, linked = asyncio.Event(), asyncio.Event()

        def send_while_busy(*keys: str, waiting: int) -> None:
            """From another thread, while the loop is held here until Zenoh (on its own threads) has
            handed every sample to the inbox: ``waiting`` items in it then."""
            def send() -> None:
                for k in keys:
                    outside.put(k, k.encode())

            sender = threading.Thread(target=send)
            sender.start()
            sender.join()
            deadline = time.monotonic() + 5
            while len(host._inbox._first) + len(host._inbox._ordinary) < waiting and time.monotonic() < deadline:
                time.sleep(0.005)

        def on_sample(key: str, payload: bytes) -> None:
            if key == "t/ping":
                linked.set()
                return
            handled.append(payload)
            if payload == b"t/plan/go":
                send_while_busy("t/plan/1", "t/plan/2", "t/plan/3", "t/answer/1", waiting=4)
            elif payload == b"t/plan/1":
                send_while_busy("t/answer/2", waiting=3)  # and plans 2 and 3
            if len(handled) == 6:
                done.set()

        try:
            host.subscribe("t/plan/*", on_sample)
            host.subscribe("t/answer/*", on_sample, first=True)
            host.subscribe("t/ping", on_sample)
            for _ in range(100):  # until the host's subscriptions have reached the outside session
                outside.put("t/ping", b"")
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(linked.wait(), 0.05)
                if linked.is_set():
                    break
            outside.put("t/plan/go", b"t/plan/go")
            await asyncio.wait_for(done.wait(), 10)
            return handled
        finally:
            await outside.close()
            await host.close()

    assert asyncio.run(scenario()) == [b"t/plan/go", b"t/answer/1", b"t/plan/1", b"t/answer/2",
                                       b"t/plan/2", b"t/plan/3"]


@pytest.mark.parametrize("event_loop", ["asyncio", "uvloop"])
def test_udp_links_given_a_host_name_send_on_either_event_loop(event_loop: str) -> None:
    """uvloop's sendto looks no name up: the fake vehicle's link and a udpout:// link to "localhost"
    must still reach their peer (the processes run on uvloop, fleet/runtime.py)."""
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5)
    port = receiver.getsockname()[1]

    async def send_both() -> None:
        vehicle_side = await UdpLink.open("localhost", port, lambda: lambda data: None)
        ground_side = await open_transport(parse_link_url(f"udpout://localhost:{port}"), lambda data: None,
                                           lambda why: None)
        try:
            vehicle_side.send(b"from the vehicle")
            ground_side.send(b"from the ground")
            await asyncio.sleep(0.05)  # the datagrams are on their way: nothing to wait on but the socket
        finally:
            vehicle_side.close()
            ground_side.close()

    try:
        if event_loop == "uvloop":
            uvloop = pytest.importorskip("uvloop", reason="uvloop is not installed here")
            uvloop.run(send_both())
        else:
            asyncio.run(send_both())
        assert {receiver.recv(64), receiver.recv(64)} == {b"from the vehicle", b"from the ground"}
    finally:
        receiver.close()


def test_an_ordinary_item_that_waited_too_long_goes_before_first_ones() -> None:
    """Protocol messages go first, but not for ever: a process busy coordinating for long must
    still take mail orders and answer queries."""
    async def scenario() -> list[str]:
        inbox, handled = Inbox(asyncio.get_running_loop()), list[str]()
        inbox.put(False, "t", handled.append, ("old",))
        time.sleep(ORDINARY_WAITS_AT_MOST_S * 1.5)  # the loop busy: nothing is taken meanwhile
        inbox.put(True, "t", handled.append, ("first 1",))
        inbox.put(True, "t", handled.append, ("first 2",))
        inbox.put(False, "t", handled.append, ("new",))
        for _ in range(8):  # one item per turn of the loop
            await asyncio.sleep(0)
        return handled

    assert asyncio.run(scenario()) == ["old", "first 1", "first 2", "new"]
