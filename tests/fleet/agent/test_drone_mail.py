"""One drone's agent and its mail: handed back when it cannot fly it, and adopted by an heir when a
drone is gone.
"""

from __future__ import annotations

import asyncio

import pytest

from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.workspace import Workspace
from fleet.agent.drone import DroneAgent
from fleet.setpoint_loop import StepReport
from fleet.transport.wire import HeldMail, MailOrder, MailStatus, MailStatusReport, MailView, decode, encode
from tests.fakes.node import FakeNetwork, FakeNode
from tests.fakes.vehicle import FakeVehicle
from tests.fleet.agent.drone_helpers import FRAME, KEYS, WS, statuses, vehicle_over_its_start


def test_a_drone_low_where_no_charger_is_hands_its_mail_back_and_takes_no_more() -> None:
    """Flown on ArduCopter SITL, whose battery ran low after 5 minutes in a workspace with no charger:
    the mail went round the low drones, each handing it back in turn. A drone that cannot fly mail
    says so and takes none, so the mail goes back to whoever gave it."""
    async def scenario() -> tuple[FakeNode, list[str]]:
        node, vehicle = FakeNode(), vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle, FRAME, lambda: 1000.0)
        agent.mail.take(MailOrder(id="queued", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        vehicle.battery_pct = 10
        for step in range(4):
            actions = agent.tick(step)
            agent.on_step(StepReport(step, agent.stack.executor.cell, (0, 0, 0), 0.0, False, 0.0), actions)
            await asyncio.sleep(0)  # the mail desk reports on the loop
        refused = []
        try:
            agent.mail.take(MailOrder(id="more", pickup=[2, 4, 0], dropoff=[6, 1, 0], priority=1))
        except ProblemError as exc:
            refused.append(str(exc))
        return node, refused

    node, refused = asyncio.run(scenario())
    why = "its battery is low, and the workspace has no charger"
    assert statuses(node, "queued") == [(MailStatus.ACCEPTED, ""), (MailStatus.HANDED_BACK, why)]
    assert refused == [f"drone d1 takes no mail: {why}"]


def _heir_of_d2(*more: MailView) -> tuple[FakeNode, DroneAgent]:
    """d1's agent (d2's heir: the smallest name), d2 and d3 alive, a lease of 4 steps, d2 holding mail
    ``q`` queued and ``more``."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0)})
    node = FakeNode()
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
    agent.lease_steps, agent.alive = 4, {"d2", "d3"}
    queued = MailView(id="q", pickup=[3, 3, 0], dropoff=[5, 5, 0], priority=5, stage="queued")
    agent.mail._on_peer_mail(KEYS.held("d2"), encode("d2", 1000.0, HeldMail(drone="d2", mail=[queued, *more])))
    return node, agent


@pytest.mark.parametrize("in_touch", [True, False], ids=["majority", "cut-off"])
def test_the_heir_adopts_a_gone_drones_mail_a_lease_later_and_only_with_a_majority(in_touch: bool) -> None:
    """Issue 25: one owner per mail. A drone that left may only be cut off, flying on: the heir waits a
    lease (by then that drone has handed back what it had not picked up) and adopts only in touch with
    most of the fleet (the other side cannot be). What it carried stays its own, never failed and then
    delivered, until the operator releases it."""
    async def scenario() -> FakeNode:
        node, agent = _heir_of_d2(MailView(id="c", pickup=[6, 0, 0], dropoff=[6, 6, 0], priority=5, stage="carrying"))
        if not in_touch:
            agent._on_liveliness(KEYS.alive("d3"), False)
        agent._on_liveliness(KEYS.alive("d2"), False)
        for step in range(4):
            agent.tick(step)
            assert statuses(node, "q") == []  # within the lease: d2 may be cut off, handing it back
        agent.tick(4)
        agent.mail.released("d2", agent.alive)
        return node

    node = asyncio.run(scenario())
    assert statuses(node, "q") == ([(MailStatus.ACCEPTED, ""), (MailStatus.REASSIGNED, "drone d2 left")]
                                  if in_touch else [])
    assert statuses(node, "c") == [(MailStatus.FAILED, "on board drone d2, released by the operator")]


def test_a_gone_drone_back_within_the_lease_keeps_its_mail() -> None:
    """Found in review: back before the heir's lease ran out, a drone still held its mail, and the heir
    adopted it all the same (two owners). Its return ends the orphans it held."""
    async def scenario() -> FakeNode:
        node, agent = _heir_of_d2()
        agent._on_liveliness(KEYS.alive("d2"), False)
        agent.tick(0)
        agent._on_liveliness(KEYS.alive("d2"), True)
        for step in range(1, 8):
            agent.tick(step)
        return node

    assert statuses(asyncio.run(scenario()), "q") == []


def test_peers_back_hear_what_a_drone_holds_once_at_the_next_boundary() -> None:
    """Each drone said what it holds again for every peer that joined, to every peer: 128 drones
    starting up sent 128 x 127 lists, each to every drone, and answered their first mail orders
    seconds late (the bench's client gave up on them). Peers back since a boundary hear it once, then."""
    async def scenario() -> list[int]:
        node, agent = _heir_of_d2()
        said = [len(node.bodies(KEYS.held("d1")))]
        for step in range(2):
            agent.tick(step)
            said.append(len(node.bodies(KEYS.held("d1"))))
        for up in (False, True):
            for peer in ("d2", "d3"):
                agent._on_liveliness(KEYS.alive(peer), up)
        said.append(len(node.bodies(KEYS.held("d1"))))
        agent.tick(2)
        said.append(len(node.bodies(KEYS.held("d1"))))
        return said

    assert asyncio.run(scenario()) == [0, 1, 1, 1, 2]


@pytest.mark.parametrize("in_touch, service", [(True, False), (False, False), (True, True)],
                         ids=["majority", "cut-off", "a-service-dispatches"])
def test_the_heir_takes_over_mail_a_live_drone_handed_back_at_once(in_touch: bool, service: bool) -> None:
    """A drone late, or whose vehicle is lost, hands back the mail it cannot fly now: with no service to
    reassign it (the suite's fleet, ``drona mail``) it was lost. It lists it handed back; its heir takes it
    over at the next boundary (it gave it up: no lease), in touch with most of the fleet; under a service,
    the service reassigns it."""
    async def scenario() -> FakeNode:
        handed = MailView(id="h", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=3, stage="handed_back")
        node, agent = _heir_of_d2(handed)
        agent.mail.adopt = not service
        if not in_touch:  # cut off from both since d2's list came
            agent._on_liveliness(KEYS.alive("d3"), False)
            agent._on_liveliness(KEYS.alive("d2"), False)
        agent.tick(0)
        agent.tick(1)
        return node

    node = asyncio.run(scenario())
    adopted = [(MailStatus.ACCEPTED, ""), (MailStatus.REASSIGNED, "drone d2 handed it back")]
    assert statuses(node, "h")[:2] == (adopted if in_touch and not service else [])
    assert statuses(node, "q") == []  # d2 holds it still


def test_an_heir_late_for_now_takes_the_mail_over_once_on_time_not_rejects_it() -> None:
    """Found by the fleets lane (the rogue test): d3 handed two mails back, late; its heir d1 was late at
    that moment too, rejected both, and no drone else would take them: never delivered. An heir that may
    take mail again later keeps the orphans until it may; one whose vehicle is down rejects at once."""
    async def scenario() -> tuple[list[tuple[MailStatus, str]], list[tuple[MailStatus, str]]]:
        handed = MailView(id="h", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=3, stage="handed_back")
        node, agent = _heir_of_d2(handed)
        agent.late = "its vehicle was not in [1, 0, 0] 0.3 s (lambda) after step 0 began"
        agent.tick(0)
        agent.tick(1)
        while_late = statuses(node, "h")
        agent.late = None
        agent.tick(2)
        return while_late, statuses(node, "h")

    while_late, after = asyncio.run(scenario())
    assert while_late == []
    assert after[:2] == [(MailStatus.ACCEPTED, ""), (MailStatus.REASSIGNED, "drone d2 handed it back")]


@pytest.mark.parametrize("owner, heir", [("d2", "d1"), ("d1", "d2")])
def test_the_heir_is_the_smallest_live_name_but_the_owners_and_no_other_drone_adopts(owner: str, heir: str) -> None:
    """Each of d1, d2 and d3 hears ``owner`` hand mail back: only ``heir`` takes it over."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0)})
    handed = MailView(id="h", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=3, stage="handed_back")

    async def adopted_by(me: str) -> bool:
        node = FakeNode()
        stack = DroneStack(me, StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, FakeVehicle(GeoFrame(ws), ws.drones[me]), GeoFrame(ws), lambda: 1000.0)
        agent.alive = {"d1", "d2", "d3"} - {me}
        agent.mail._on_peer_mail(KEYS.held(owner), encode(owner, 1000.0, HeldMail(drone=owner, mail=[handed])))
        agent.tick(0)
        agent.tick(1)
        await asyncio.sleep(0)
        return any(isinstance(r, MailStatusReport) for r in node.bodies(KEYS.status(me, "h")))

    assert [me for me in ("d1", "d2", "d3") if me != owner and asyncio.run(adopted_by(me))] == [heir]


def test_mail_handed_back_is_adopted_only_while_no_peer_lists_it() -> None:
    """d2 lists mail handed back that d3 lists as its own: d3 took it over, d1 (the heir) leaves it.
    Once d3's newest list no longer holds it, d2's next list makes it d1's to take over."""
    async def scenario() -> list[tuple[MailStatus, str]]:
        handed = MailView(id="h", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=3, stage="handed_back")
        node, agent = _heir_of_d2()
        said = agent.mail._on_peer_mail
        taken = MailView(id="h", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=3, stage="queued")
        said(KEYS.held("d3"), encode("d3", 1000.0, HeldMail(drone="d3", mail=[taken])))
        said(KEYS.held("d2"), encode("d2", 1000.0, HeldMail(drone="d2", mail=[handed])))
        agent.tick(0)
        agent.tick(1)
        assert statuses(node, "h") == []
        said(KEYS.held("d3"), encode("d3", 1000.0, HeldMail(drone="d3", mail=[])))
        said(KEYS.held("d2"), encode("d2", 1000.0, HeldMail(drone="d2", mail=[handed])))
        agent.tick(2)
        return statuses(node, "h")

    adopted = [(MailStatus.ACCEPTED, ""), (MailStatus.REASSIGNED, "drone d2 handed it back")]
    assert asyncio.run(scenario())[:2] == adopted


def test_a_drone_lists_what_it_handed_back_until_a_peer_holds_it() -> None:
    """The heir learns what to take over from the list; once a peer lists the mail, it is the peer's."""
    async def scenario() -> tuple[list[list[str]], list[tuple[MailStatus, str]]]:
        node, agent = _heir_of_d2()
        agent.mail.take(MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        agent._carry_out(agent.stack.tracking_bound(True, "drone d1's vehicle is later than lambda"))
        await asyncio.sleep(0)
        lists = [[f"{m.id}:{m.stage}" for m in agent.mail.listed()]]
        taken = MailView(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9, stage="queued")
        agent.mail._on_peer_mail(KEYS.held("d3"), encode("d3", 1000.0, HeldMail(drone="d3", mail=[taken])))
        lists.append([f"{m.id}:{m.stage}" for m in agent.mail.listed()])
        return lists, statuses(node, "m")

    lists, reported = asyncio.run(scenario())
    assert lists == [["m:handed_back"], []]
    assert reported[-1] == (MailStatus.HANDED_BACK, "drone d1's vehicle is later than lambda")


def test_a_report_the_service_missed_goes_again_once_its_subscription_reaches_the_drone() -> None:
    """After a partition healed, the service's token came back before its subscription: the delivery,
    sent again when the token came, was lost, and the service failed the mail for want of news. The
    drone sends again once the subscription reaches it, whenever its token came."""
    async def scenario() -> list[tuple[str, bytes]]:
        network = FakeNetwork()
        service = FakeNode(network)
        service.token(KEYS.service())
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, FakeNode(network), KEYS, vehicle_over_its_start(), FRAME, lambda: 1000.0)
        agent.mail.adopt = False
        await agent.start()
        agent.mail.report("m", MailStatus.DELIVERED)  # nobody subscribed yet: lost
        await asyncio.sleep(0)
        heard: list[tuple[str, bytes]] = []
        service.subscribe(KEYS.status(), lambda key, payload: heard.append((key, payload)))
        for _ in range(3):
            await asyncio.sleep(0)
        return heard

    heard = asyncio.run(scenario())
    bodies = [decode(payload).body for _, payload in heard]
    assert [(b.id, b.status) for b in bodies if isinstance(b, MailStatusReport)] == [("m", MailStatus.DELIVERED)]
