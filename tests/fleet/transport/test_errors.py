"""Zenoh's errors leave :class:`~fleet.transport.node.ZenohNode` as TransportError, saying what was being done."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from drona_gcs.errors import DronaError
from fleet.transport.node import TransportError, ZenohNode
from fleet.transport.settings import ZenohSettings

BAD_KEY = "drona//t"  #: an empty chunk: Zenoh refuses it


def failure(act: Callable[[ZenohNode], object]) -> TransportError:
    async def scenario() -> TransportError:
        node = await ZenohNode.open(ZenohSettings(), "n1")
        try:
            with pytest.raises(TransportError) as raised:
                outcome = act(node)
                if asyncio.iscoroutine(outcome):
                    await outcome
            return raised.value
        finally:
            await node.close()

    return asyncio.run(scenario())


@pytest.mark.parametrize(("act", "what"), [
    (lambda n: n.put(BAD_KEY, b"x"), f"n1: put on {BAD_KEY}"),
    (lambda n: n.subscribe(BAD_KEY, lambda k, p: None), f"n1: subscribe to {BAD_KEY}"),
    (lambda n: n.queryable(BAD_KEY, lambda k, p, q: None), f"n1: answer on {BAD_KEY}"),
    (lambda n: n.token(BAD_KEY), f"n1: declare token {BAD_KEY}"),
    (lambda n: n.get(BAD_KEY, b"", 1.0), "n1: ask"),
    (lambda n: n.alive(BAD_KEY, 1.0), "n1: ask"),
    (lambda n: n.watch_liveliness(BAD_KEY, lambda k, alive: None), f"n1: watch tokens {BAD_KEY}"),
], ids=["put", "subscribe", "queryable", "token", "get", "alive", "watch"])
def test_a_zenoh_error_is_a_transport_error_naming_what_was_done(act: Callable[[ZenohNode], object],
                                                                  what: str) -> None:
    error = failure(act)
    assert str(error).startswith(f"{what}: Invalid Key Expr")
    assert isinstance(error, DronaError) and isinstance(error.__cause__, zenoh.ZError)


def test_a_bad_configuration_names_the_file(tmp_path: Path) -> None:
    config = tmp_path / "zenoh.json5"
    config.write_text('{ mode: "peer", listen: { endpoints: ["nonsense"] } }')
    with pytest.raises(TransportError, match=f"Zenoh configuration in {config}"):
        ZenohSettings(config_file=config).config()


def test_a_subscription_zenoh_refused_is_not_kept() -> None:
    async def scenario() -> tuple[int, int]:
        node = await ZenohNode.open(ZenohSettings(), "n1")
        try:
            with pytest.raises(TransportError):
                node.subscribe(BAD_KEY, lambda k, p: None)
            refused = len(node._fanouts)
            node.subscribe("drona/t", lambda k, p: None)
            return refused, len(node._fanouts)
        finally:
            await node.close()

    assert asyncio.run(scenario()) == (0, 1)
