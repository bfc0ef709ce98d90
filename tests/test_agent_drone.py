"""One drone's agent (fleet.agent.drone) with its stack, over a recording transport and a scripted vehicle."""

from __future__ import annotations

import asyncio

from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.workspace import Workspace
from fleet.agent.drone import DroneAgent
from fleet.executor import StepReport
from fleet.transport.keys import FleetKeys
from fleet.transport.wire import MailOrder, MailStatus, MailStatusReport, decode
from fleet.vehicle.link import Autopilot, LandedState, Position, Telemetry

#: With a parking cell: an idle drone that may plan flies there (a drone that is down must not).
WS = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0)}, parking=((7, 7, 0),))
FRAME = GeoFrame(WS)
KEYS = FleetKeys("t")


class RecordingNode:
    """What the agent puts, by key (the mail desk and the protocol only put)."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, bytes]] = []

    def put(self, key: str, payload: bytes, once: bool = False) -> None:
        self.puts.append((key, payload))

    def statuses(self, mail_id: str) -> list[tuple[MailStatus, str]]:
        reports = [decode(p).body for k, p in self.puts if k == KEYS.status(mail_id)]
        return [(r.status, r.reason) for r in reports if isinstance(r, MailStatusReport)]


class ScriptedVehicle:
    """A vehicle whose telemetry the test sets: over (0, 0, 0), armed in the air until it comes down."""

    def __init__(self) -> None:
        self.down = False

    def telemetry(self) -> Telemetry:
        landed = LandedState.ON_GROUND if self.down else LandedState.IN_AIR
        return Telemetry(Autopilot.ARDUPILOT, not self.down, "GUIDED", self.last_position(), None, None,
                         None, 90, 16.0, 3, 10, landed, 1.0)

    def last_position(self) -> Position:
        return Position(FRAME.cell_to_ned((0, 0, 0)), 1.0)

    def last_global(self) -> None:
        return None


def test_a_vehicle_down_by_itself_hands_its_mail_back_and_the_drone_starts_no_task() -> None:
    """A failsafe or a pilot lands the vehicle under a flying plan: the stack must not go on to
    report a pickup (or a delivery) the vehicle never made, nor start the next mail."""
    async def scenario() -> tuple[RecordingNode, DroneAgent, list[object]]:
        node, vehicle = RecordingNode(), ScriptedVehicle()
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle, FRAME, lambda: 1000.0)  # type: ignore[arg-type]
        agent.mail.take(MailOrder(id="first", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        agent.mail.take(MailOrder(id="next", pickup=[2, 4, 0], dropoff=[6, 1, 0], priority=1))
        later: list[object] = []
        for step in range(16):
            actions = agent.tick(step)
            if step == 3:  # taken up for its plan, then down by itself
                agent.vehicle.airborne = True
                vehicle.down = True
            report = StepReport(step, agent.stack.executor.cell, (0, 0, 0), 0.0, False, 0.0)
            agent.on_step(report, actions)
            if step > 3:
                later += actions
            await asyncio.sleep(0)  # the mail desk reports on the loop
        try:
            agent.mail.take(MailOrder(id="refused", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=5))
        except ProblemError as exc:
            later.append(exc)
        return node, agent, later

    node, agent, later = asyncio.run(scenario())
    why = "drone d1's vehicle came down by itself in [0, 0, 0]"
    assert node.statuses("first") == [(MailStatus.ACCEPTED, ""), (MailStatus.STARTED, ""),
                                      (MailStatus.REJECTED, why)]
    assert node.statuses("next") == [(MailStatus.ACCEPTED, ""), (MailStatus.REJECTED, why)]
    assert agent.mail.held() == []
    assert "came down" in agent.alarms["down"]
    kinds = {type(a).__name__ for a in later if not isinstance(a, Exception)}
    assert not kinds & {"GoTo", "MailStarted", "MailPickedUp", "MailDelivered"}, kinds
    assert "Completed" in kinds  # the leg under way was flown to its end, with no mail
    refusal = [str(a) for a in later if isinstance(a, Exception)]
    assert refusal == ["drone d1 takes no mail: its vehicle came down by itself"]
