"""One drone's agent under the operator's commands: acknowledged, and a release of a departed drone's
cells.
"""

from __future__ import annotations

import asyncio

from drona_gcs.geo import GeoFrame
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.workspace import Cell, Workspace
from fleet.agent.drone import DroneAgent
from fleet.transport.wire import CommandAck, CommandAction, FleetCommand, MailOrder, MailStatus, decode, encode
from tests.fakes.node import FakeNode, FakeQuery
from tests.fleet.agent.drone_helpers import FRAME, KEYS, WS, statuses, vehicle_over_its_start


def test_an_operators_command_reaches_the_stack_and_is_acknowledged() -> None:
    """``command/<me>``: a recall hands back the mail not on board and the drone says so in its state."""
    query = FakeQuery()

    async def scenario() -> tuple[DroneAgent, FakeNode]:
        node = FakeNode()
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), FRAME, lambda: 1000.0)
        agent.mail.take(MailOrder(id="m", pickup=[3, 3, 0], dropoff=[5, 5, 0], priority=1))
        command = FleetCommand(action=CommandAction.RECALL, by="operator ops")
        agent._on_command(KEYS.command("d1"), encode("service", 1000.0, command), query)
        await asyncio.sleep(0)  # mail progress goes out after the work at hand
        return agent, node

    agent, node = asyncio.run(scenario())
    assert statuses(node, "m") == [(MailStatus.ACCEPTED, ""), (MailStatus.HANDED_BACK, "recall by operator ops")]
    assert agent.state().command == "recall"
    [(key, payload)] = query.replies
    ack = decode(payload).body
    assert key == KEYS.command("d1") and isinstance(ack, CommandAck) and ack.accepted and ack.drone == "d1"


def test_a_release_command_frees_a_departed_drones_cells_and_is_refused_for_a_member() -> None:
    """``release`` about a drone gone: the agent holds none of its cells; about a drone still in the
    fleet (as this agent sees it) it answers no, with the reason."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0)})
    query = FakeQuery()

    async def scenario() -> tuple[set[Cell], DroneStack]:
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
        stack.peer_left("d2")
        held = stack.taken_cells()
        for about in ("d2", "d3"):
            order = FleetCommand(action=CommandAction.RELEASE, by="operator ops", about=about)
            agent._on_command(KEYS.command("d1"), encode("service", 1000.0, order), query)
        return held, stack

    held, stack = asyncio.run(scenario())
    assert (7, 0, 0) in held and "d2" not in stack.protocol.ghosts and (7, 0, 0) not in stack.taken_cells()
    replies = [decode(payload).body for _, payload in query.replies]
    acks = [a for a in replies if isinstance(a, CommandAck)]
    assert acks == replies, f"every reply is a CommandAck: {replies}"
    assert [(a.accepted, a.reason) for a in acks] == [
        (True, ""), (False, "d3 is not a drone gone from the fleet: nothing to release")]
