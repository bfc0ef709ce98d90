"""The fleet's Zenoh node: drones sharing a session, answers that travel as one message, and
gathered puts sent in order.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket

import pytest
import zenoh

from fleet.sim.ports import free_port
from fleet.transport.gather import Gathered
from fleet.transport.node import SampleHandler, ZenohNode
from fleet.transport.settings import ZenohSettings


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


def test_a_put_reaches_its_own_sessions_subscribers_on_the_loop_at_once() -> None:
    """Two drones of one host: what one puts is handed to the other at the loop's next turn, in the order
    put, and once, not after a trip through Zenoh's threads (a busy process starves them for
    milliseconds, and the next drone in line waits on that message), also when it subscribed after a
    put with nobody to hear it. Then a session elsewhere subscribes: it gets each put too, and the
    drone still gets each once."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"

    async def scenario() -> tuple[list[bytes], list[bytes]]:
        host = await ZenohNode.open(ZenohSettings(listen=(endpoint,)), "host")
        outside = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "outside")
        a, b = host.view("a"), host.view("b")
        local: list[bytes] = []
        remote: list[bytes] = []
        got = asyncio.Event()

        def on_remote(key: str, payload: bytes) -> None:
            remote.append(payload)
            got.set()

        try:
            a.put("t/proto/a/b", b"before")  # nobody here hears it yet; a subscription then must
            b.subscribe("t/proto/*/b", lambda key, payload: local.append(payload), first=True)
            for i in range(20):  # nothing else feeds this loop meanwhile
                a.put("t/proto/a/b", b"%d" % i)
                await asyncio.sleep(0)
                assert local[-1:] == [b"%d" % i], f"put {i} not handed over at the loop's next turn: {local}"
            outside.subscribe("t/proto/*/b", on_remote)
            for _ in range(100):  # until the outside subscription has reached the host
                a.put("t/proto/a/b", b"probe")
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(got.wait(), 0.05)
                if remote:
                    break
            a.put("t/proto/a/b", b"last")
            while b"last" not in remote:
                got.clear()
                await asyncio.wait_for(got.wait(), 5)
            await asyncio.sleep(0.2)  # a second copy through Zenoh would have come by now
            return local, remote
        finally:
            await outside.close()
            await a.close()
            await b.close()
            await host.close()

    local, remote = asyncio.run(scenario())
    probes = local.count(b"probe")
    assert local == [*(b"%d" % i for i in range(20)), *[b"probe"] * probes, b"last"]
    assert remote[-1:] == [b"last"] and remote.count(b"last") == 1


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
            loop = asyncio.get_running_loop()

            def on_message(sample: zenoh.Sample) -> None:  # on a thread of its own
                messages.append(sample.payload.to_bytes())
                loop.call_soon_threadsafe(got.set)

            asker._declared.append(asker.session.declare_subscriber("t/answer", on_message))
            for _ in range(100):  # until the host's subscription has reached the asker
                asker.put("t/all", b"request")
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(got.wait(), 0.05)
                if answers:
                    break
            # The raw subscriber's thread may lag the node's: wait for both to have all three.
            while len(answers) < 3 or sum(len(m.split(b"\n")) for m in messages) < 3:
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


def test_a_node_hears_when_a_subscriber_elsewhere_starts_and_stops_matching_a_key() -> None:
    """The event a drone sends its reports again on: the subscription itself reaching it, not its
    owner's token. Nothing matches until the peer subscribes to a key expression that covers the key;
    closing that peer ends the match."""
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"

    async def scenario() -> list[bool]:
        drone = await ZenohNode.open(ZenohSettings(listen=(endpoint,)), "drone")
        service = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "service")
        seen: list[bool] = []
        changed = asyncio.Event()

        def on_change(matching: bool) -> None:
            seen.append(matching)
            changed.set()

        async def changes(count: int) -> None:
            while len(seen) < count:
                changed.clear()
                await asyncio.wait_for(changed.wait(), 10)

        try:
            drone.on_matching("t/status/d1/any", on_change)
            service.subscribe("t/other/*", lambda key, payload: None)  # no match: nothing said
            service.token("t/service")
            service.subscribe("t/status/*/*", lambda key, payload: None)
            await changes(1)
            await service.close()
            await changes(2)
        finally:
            await service.close()
            await drone.close()
        return seen

    assert asyncio.run(scenario()) == [True, False]
