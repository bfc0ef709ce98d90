"""The fleet's inbox: subscriptions that go first, and ordinary items that waited too long.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time

import pytest

from fleet.sim.ports import free_port
from fleet.transport import inbox as inbox_module
from fleet.transport.inbox import ORDINARY_WAITS_AT_MOST_S, Inbox
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings


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


def test_the_backlog_is_how_long_the_oldest_item_still_waiting_has_waited() -> None:
    """What a drone reads before it starts a task: news of its peers waiting for a busy loop."""
    async def scenario() -> tuple[float, float, float]:
        inbox = Inbox(asyncio.get_running_loop())
        idle = inbox.backlog_s()
        inbox.put(False, "t", lambda: None, ())
        time.sleep(0.05)  # the loop busy: nothing is taken meanwhile
        inbox.put(True, "t", lambda: None, ())
        waited = inbox.backlog_s()
        for _ in range(4):
            await asyncio.sleep(0)
        return idle, waited, inbox.backlog_s()

    idle, waited, after = asyncio.run(scenario())
    assert idle == 0.0 and after == 0.0
    assert waited >= 0.05  # the ordinary item's wait, not the newer first one's


def test_urgent_items_go_before_first_ones_and_overdue_ordinary_ones() -> None:
    """A peer's brake or late vehicle waited behind the protocol's messages of a fleet coordinating at
    once (over 128 agents: seconds), while a drone flying had to act on it."""
    async def scenario() -> list[str]:
        inbox, handled = Inbox(asyncio.get_running_loop()), list[str]()
        inbox.put(False, "t", handled.append, ("old",))
        inbox.put(True, "t", handled.append, ("first",))
        time.sleep(ORDINARY_WAITS_AT_MOST_S * 1.5)  # the loop busy: "old" is overdue
        inbox.put(False, "t", handled.append, ("brake",), urgent=True)
        for _ in range(6):
            await asyncio.sleep(0)
        return handled

    assert asyncio.run(scenario()) == ["brake", "old", "first"]
