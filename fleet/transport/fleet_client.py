"""Talking to a fleet from outside it (``drona mail``, the service): read states, give mail, follow it.

A client is a Zenoh session that listens nowhere: it connects to the agents
(or to a router) and learns the rest of the mesh by gossip.
"""

from __future__ import annotations

import asyncio
import time

from drona_gcs.dispatch import Candidate, rank_drones
from drona_gcs.errors import DronaError
from drona_gcs.stack.protocol import State
from fleet.transport.keys import FleetKeys
from fleet.transport.node import ZenohNode
from fleet.transport.wire import DroneState, MailAck, MailOrder, WireError, decode, encode

QUERY_TIMEOUT_S = 2.0


class FleetUnavailable(DronaError):
    """No drone answered, or none would take the mail."""


class FleetClient:
    def __init__(self, node: ZenohNode, keys: FleetKeys, name: str) -> None:
        self.node, self.keys, self.name = node, keys, name

    async def states(self) -> dict[str, DroneState]:
        """Every live drone's state, as it answers now."""
        replies = await self.node.get(self.keys.state(), b"", QUERY_TIMEOUT_S)
        states: dict[str, DroneState] = {}
        for reply in replies:
            try:
                body = decode(reply.payload).body
            except WireError:
                continue  # a foreign answer: not a drone of ours
            if isinstance(body, DroneState):
                states[body.drone] = body
        return states

    async def wait_for_drones(self, timeout_s: float) -> dict[str, DroneState]:
        """States, once at least one drone answers (the mesh forms within a moment of opening)."""
        deadline = time.monotonic() + timeout_s
        pause = 0.1
        while True:
            states = await self.states()
            if states or time.monotonic() >= deadline:
                return states
            await asyncio.sleep(min(pause, max(0.0, deadline - time.monotonic())))  # retry with back-off
            pause = min(pause * 2, 1.0)

    async def assign(self, drone: str, order: MailOrder, timeout_s: float = QUERY_TIMEOUT_S) -> MailAck:
        replies = await self.node.get(self.keys.assign(drone), encode(self.name, time.time(), order),
                                      timeout_s, block=True)
        for reply in replies:
            try:
                body = decode(reply.payload).body
            except WireError:
                continue
            if isinstance(body, MailAck) and body.id == order.id:
                return body
        raise FleetUnavailable(f"drone {drone} did not answer the mail order {order.id} within {timeout_s:g} s")

    async def dispatch(self, order: MailOrder, drone: str | None, timeout_s: float) -> MailAck:
        """Give ``order`` to ``drone``, or to the best candidate among the live drones that takes it (the
        next while they refuse; every refusal, if all do)."""
        states = await self.wait_for_drones(timeout_s)
        if drone is not None:
            if drone not in states:
                raise FleetUnavailable(f"drone {drone} of fleet {self.keys.fleet!r} did not answer")
            return await self.assign(drone, order)
        pickup = (order.pickup[0], order.pickup[1], order.pickup[2])
        refused: list[MailAck] = []
        for name in rank_drones([candidate(s) for s in states.values()], pickup):
            ack = await self.assign(name, order)
            if ack.accepted:
                return ack
            refused.append(ack)
        if not refused:
            raise FleetUnavailable(f"no drone of fleet {self.keys.fleet!r} answered within {timeout_s:g} s")
        why = "; ".join(f"{ack.drone}: {ack.reason}" for ack in refused)
        return MailAck(id=order.id, drone=refused[0].drone, accepted=False, reason=f"every drone refused it ({why})")


def candidate(state: DroneState) -> Candidate:
    busy = state.mode != State.WAIT_FOR_TASK.value
    cell = (state.cell[0], state.cell[1], state.cell[2])
    return Candidate(state.drone, cell, len(state.mail), busy, state.health.ok)

