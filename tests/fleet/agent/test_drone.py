"""One drone's agent (fleet.agent.drone) with its stack, over a recording transport and a scripted vehicle."""

from __future__ import annotations

import asyncio
import io
import json

import pytest

from drona_gcs.errors import ProblemError
from drona_gcs.geo import GeoFrame
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.stack.messages import CurrentTraj, Message, PlanAck, PlanDecision, ReqForCurrentTraj, TaskId
from drona_gcs.stack.protocol import Braked, State
from drona_gcs.workspace import Cell, Workspace
from fleet.agent.drone import DroneAgent
from fleet.setpoint_loop import Sample, StepReport
from fleet.transport.keys import FleetKeys
from fleet.transport.wire import (
    CommandAck,
    CommandAction,
    CurTraj,
    CurTrajTo,
    Decide,
    DroneState,
    Envelope,
    FleetCommand,
    HeldMail,
    MailOrder,
    MailStatus,
    MailStatusReport,
    MailView,
    PlanAnnounce,
    Propose,
    ReqTraj,
    WireTrajectory,
    answer_in,
    answering,
    answers,
    decode,
    encode,
    from_core,
    to_core,
)
from tests.fakes.node import FakeNetwork, FakeNode, FakeQuery
from tests.fakes.vehicle import FakeVehicle

#: With a parking cell: an idle drone that may plan flies there (a drone that is down must not).
WS = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0)}, parking=((7, 7, 0),))
FRAME = GeoFrame(WS)
KEYS = FleetKeys("t")


def statuses(node: FakeNode, mail_id: str) -> list[tuple[MailStatus, str]]:
    """What d1 reported of mail ``mail_id``, in order."""
    return [(r.status, r.reason) for r in node.bodies(KEYS.status("d1", mail_id)) if isinstance(r, MailStatusReport)]


def vehicle_over_its_start() -> FakeVehicle:
    """d1's vehicle, ready, armed and in the air over (0, 0, 0) of the 8 x 8 workspace."""
    return FakeVehicle(FRAME, (0, 0, 0))


def test_an_agent_started_among_its_peers_waits_only_for_those_alive_and_hears_them_leave() -> None:
    """Started on a network where d2 is alive and d3 never came: d3 is held where it stands and waited for
    no more, d2 is a member; the agent is alive itself once started, and its first state is out. When
    d2's token goes, d2 has left too."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0)})
    network = FakeNetwork()
    FakeNode(network).token(KEYS.alive("d2"))

    async def scenario() -> tuple[FakeNode, DroneAgent, set[str], set[str]]:
        node = FakeNode(network)
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
        await agent.start()
        await asyncio.sleep(0)  # the liveliness watched, as Zenoh hands it round
        gone_at_start = set(stack.protocol.ghosts)
        network.drop(KEYS.alive("d2"))
        await asyncio.sleep(0)
        return node, agent, gone_at_start, set(stack.protocol.ghosts)

    node, agent, gone_at_start, gone = asyncio.run(scenario())
    assert gone_at_start == {"d3"} and gone == {"d2", "d3"}
    assert KEYS.alive("d1") in network.tokens and agent.alive == set()
    assert [type(b) for b in node.bodies(KEYS.state("d1"))][:1] == [DroneState]


def test_a_vehicle_down_by_itself_hands_its_mail_back_and_the_drone_starts_no_task() -> None:
    """A failsafe or a pilot lands the vehicle under a flying plan: the stack must not go on to
    report a pickup (or a delivery) the vehicle never made, nor start the next mail."""
    async def scenario() -> tuple[FakeNode, DroneAgent, list[object]]:
        node, vehicle = FakeNode(), vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle, FRAME, lambda: 1000.0)
        agent.mail.take(MailOrder(id="first", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        agent.mail.take(MailOrder(id="next", pickup=[2, 4, 0], dropoff=[6, 1, 0], priority=1))
        later: list[object] = []
        for step in range(16):
            actions = agent.tick(step)
            if step == 3:  # taken up for its plan, then down by itself
                agent.vehicle.airborne = True
                vehicle.come_down()
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
    assert statuses(node, "first") == [(MailStatus.ACCEPTED, ""), (MailStatus.STARTED, ""),
                                      (MailStatus.HANDED_BACK, why)]
    assert statuses(node, "next") == [(MailStatus.ACCEPTED, ""), (MailStatus.HANDED_BACK, why)]
    assert agent.mail.held() == []
    assert "came down" in agent.alarms["down"]
    kinds = {type(a).__name__ for a in later if not isinstance(a, Exception)}
    assert not kinds & {"GoTo", "MailStarted", "MailPickedUp", "MailDelivered"}, kinds
    assert "Completed" not in kinds  # the plan under way is not flown on: the vehicle is on the ground
    assert agent.stack.executor.cell == (0, 0, 0) and agent.stack.executor.trajectory is None
    told = [decode(p).body for k, p in node.puts if k == KEYS.plan("d1")]
    assert any(isinstance(b, PlanAnnounce) and b.grounded and b.trajectory.cells == ((0, 0, 0),) for b in told)
    refusal = [str(a) for a in later if isinstance(a, Exception)]
    assert refusal == ["drone d1 takes no mail: its vehicle came down by itself"]


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


def test_a_departed_peer_last_heard_after_its_plan_holds_only_where_it_rested() -> None:
    """A killed agent's liveliness goes at once, but a cut link's only when the lease runs out, so the
    peer may have gone silent a lease ago: the rest of its plan from then on is held for good. Not
    from before it was last heard, though: a peer heard from after its plan ended is where it rested,
    and holding the cells it flew through before (a mail's pickup, say) would block them for good."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})
    frame = GeoFrame(ws)
    flown = Trajectory(10, tuple((7 - min(k, 7), min(max(k - 7, 0), 7), 0) for k in range(16)))  # steps 10..25

    async def scenario(heard_after_the_plan: bool) -> dict[str, Trajectory]:
        node = FakeNode()
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), frame, lambda: 1000.0)
        agent.lease_steps = 20
        for step in range(41):
            agent.tick(step)
            if step == 9:  # d2 announces the plan it flies from step 10
                announce = PlanAnnounce(trajectory=WireTrajectory.of(flown))
                agent._on_plan(KEYS.plan("d2"), encode("d2", 1000.0, announce))
        if heard_after_the_plan:  # d2 starts a round for a new task, then is killed
            request = ReqForCurrentTraj(TaskId(40, "d2", 2), "d2", flown, ("d1",))  # idle where its plan ended
            agent._on_protocol(KEYS.proto("all", "d2"), encode("d2", 1000.0, from_core(request)))
        agent._on_liveliness(KEYS.alive("d2"), False)
        return stack.protocol.ghost_obstacles()

    rested = asyncio.run(scenario(heard_after_the_plan=True))
    assert [t.cells for t in rested.values()] == [(flown.last,)]  # held: only where it rested
    # Not heard from since its plan: it may have stopped anywhere on the rest of it from a lease ago.
    unheard = asyncio.run(scenario(heard_after_the_plan=False))
    assert {t.last for t in unheard.values()} == set(flown.cells[40 - 20 - ws.delta - 1 - 10:])


def _coordinating(ws: Workspace, node: FakeNode, pickup: list[int],
                  dropoff: list[int]) -> tuple[DroneAgent, DroneStack, TaskId]:
    """Drone d1 of ``ws``, given a mail and past its first boundary: coordinating, its request out."""
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
    agent.mail.take(MailOrder(id="m", pickup=pickup, dropoff=dropoff, priority=1))
    agent.tick(0)
    mine = next(b.task_id.core() for k, p in node.puts if isinstance(b := decode(p).body, ReqTraj))
    return agent, stack, mine


def _protocol_state(stack: DroneStack) -> State:
    """The protocol's state now: read anew after a message (mypy keeps the state an earlier check found)."""
    return stack.protocol.state


def test_a_new_plan_answers_the_drones_that_waited_for_it_in_one_message_to_everyone() -> None:
    """Drones that asked while this one coordinated wait for its new plan; it goes to them in the plan's
    ``decide``, which every drone gets, not one message each (a fleet given mail at once chains every
    round through these answers). Each waiting drone reads its own answer out of it."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0), "d4": (0, 7, 0)})

    async def scenario(waiting: list[str]) -> list[tuple[str, Envelope]]:
        node = FakeNode()
        agent, stack, mine = _coordinating(ws, node, [3, 3, 0], [5, 5, 0])
        for peer in waiting:  # lower priorities (later stamps): they wait for my plan
            where = Trajectory.stationary(ws.drones[peer], 0)  # its answer too (see drona_gcs.stack.protocol)
            asked = tuple(sorted(set(ws.drones) - {peer}))
            request = ReqForCurrentTraj(TaskId(mine.stamp + 5, peer, 1), peer, where, asked)
            agent._on_protocol(KEYS.proto("all", peer), encode(peer, 1000.0, from_core(request)))
        for peer in sorted({"d2", "d3", "d4"} - set(waiting)):
            answer = CurrentTraj(peer, Trajectory.stationary(ws.drones[peer], 0), mine)
            agent._on_protocol(KEYS.proto("d1", peer), encode(peer, 1000.0, from_core(answer)))
        assert stack.protocol.state is State.CONFIRMING  # flown once every peer holds it
        node.puts.clear()
        for peer in ("d2", "d3", "d4"):
            ack = PlanAck(peer, mine, Trajectory.stationary(ws.drones[peer], 0))
            agent._on_protocol(KEYS.proto("d1", peer), encode(peer, 1000.0, from_core(ack)))
        assert _protocol_state(stack) is State.EXECUTING
        await asyncio.sleep(0)  # the plan's announcement, if any, goes out once the answers have
        protocol = (f"{KEYS.root}/proto/", f"{KEYS.root}/answers/", KEYS.plan("d1"))
        return [(k, decode(p)) for k, p in node.puts if k.startswith(protocol)]

    for waiting in (["d2", "d3"], ["d2"]):
        sent = asyncio.run(scenario(waiting))
        # Every drone is told the plan is flown, in one put to all that answers the waiting ones too.
        assert [key for key, _ in sent] == [KEYS.proto("all", "d1")]
        envelope = sent[0][1]
        assert isinstance(envelope.body, Decide) and envelope.body.flown
        assert set(envelope.body.replies) == set(waiting)
        for peer in waiting:
            answer = answer_in(envelope, peer)
            assert isinstance(answer, CurrentTraj) and answer.in_reply_to.drone == peer
            assert answer.trajectory.last == (3, 3, 0)  # the new plan, to the pickup
        assert answer_in(envelope, "d4") is None  # d4 did not wait: nothing in it for d4


def test_an_answer_to_other_drones_tells_this_one_the_senders_new_plan() -> None:
    """A ``cur_traj_to`` that does not name this drone still says where its sender now flies: the
    sender counts as heard from, so the plan it flies must be known here too. If it then leaves
    before its plan's announcement arrives, it is held along the new plan, not where the old one ended."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0)})
    old = Trajectory(2, ((7, 0, 0), (6, 0, 0), (5, 0, 0)))
    new = Trajectory(12, tuple((5, y, 0) for y in range(7)))  # steps 12..18, north along x = 5

    async def scenario() -> dict[str, Trajectory]:
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle_over_its_start(), GeoFrame(ws),
                           lambda: 1000.0)
        agent.lease_steps = 20
        for step in range(11):
            agent.tick(step)
            if step == 1:
                agent._on_plan(KEYS.plan("d2"), encode("d2", 1000.0, PlanAnnounce(trajectory=WireTrajectory.of(old))))
        to_d3 = answers(new, {"d3": TaskId(9, "d3", 1)})
        agent._on_protocol(KEYS.answers("d2"), encode("d2", 1000.0, to_d3))
        agent._on_liveliness(KEYS.alive("d2"), False)  # gone before the announcement of `new` came
        return stack.protocol.ghost_obstacles()

    held = {c for t in asyncio.run(scenario()).values() for c in t.cells}
    assert held == set(new.cells)  # without it: only where the old plan ended, (5, 0, 0)


def test_a_decision_that_answers_a_waiting_drone_lets_its_round_go_on() -> None:
    """A ``decide`` carries the answers to the drones that waited for the plan: a drone it names takes its
    answer from it and plans; a drone it does not name still waits for one."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})
    flown = Trajectory(1, ((7, 0, 0), (7, 1, 0), (7, 2, 0)))

    async def scenario(named: bool) -> State:
        agent, stack, mine = _coordinating(ws, FakeNode(), [5, 5, 0], [6, 6, 0])
        assert stack.protocol.state is State.COORDINATING
        replies = {"d1": mine} if named else {"d9": TaskId(mine.stamp, "d9", 1)}
        decided = answering(PlanDecision("d2", TaskId(mine.stamp - 1, "d2", 1), flown, flown=True), replies)
        agent._on_protocol(KEYS.proto("all", "d2"), encode("d2", 1000.0, decided))
        assert stack.protocol.known["d2"] == flown  # the plan flown, heard either way
        return stack.protocol.state

    assert asyncio.run(scenario(named=True)) is State.CONFIRMING  # planned: its proposal is out
    assert asyncio.run(scenario(named=False)) is State.COORDINATING


def test_answers_for_a_round_that_is_over_still_tell_the_senders_new_plan() -> None:
    """The answers key carries a new plan's only announcement (see the test above), so a drone it names
    whose round is already over (its request answered twice, or it gave up) must still learn from it
    where the sender now flies."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})
    new = Trajectory(12, tuple((7, y, 0) for y in range(7)))

    async def scenario() -> Trajectory:
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle_over_its_start(), GeoFrame(ws),
                           lambda: 1000.0)
        agent.tick(0)
        assert stack.protocol.state is State.WAIT_FOR_TASK  # no round of d1's under way
        late = answers(new, {"d1": TaskId(3, "d1", 1), "d9": TaskId(4, "d9", 1)})
        agent._on_protocol(KEYS.answers("d2"), encode("d2", 1000.0, late))
        return stack.protocol.known["d2"]

    assert asyncio.run(scenario()) == new


def _state_of(agent: DroneAgent) -> DroneState:
    return agent.state()


def test_a_drone_whose_vehicle_waits_for_its_position_says_so_and_takes_no_mail() -> None:
    """ArduCopter SITL needs about 45 s from boot to its position estimate: the drone is a member
    meanwhile, says ``waiting_for_position``, refuses mail with the reason, and takes it once ready."""
    async def scenario() -> None:
        vehicle = vehicle_over_its_start()
        vehicle.estimate = False
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, FRAME, lambda: 1000.0)
        agent.tick(0)
        view = agent.state().vehicle
        assert view is not None and view.status == "waiting_for_position"
        assert "position estimate" in view.reason
        order = MailOrder(id="m", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=5)
        try:
            agent.mail.take(order)
        except ProblemError as exc:
            assert "its vehicle is not ready: no position estimate" in str(exc)
        else:
            raise AssertionError("a drone whose vehicle has no position took mail")
        vehicle.estimate = True
        agent.tick(1)
        view = agent.state().vehicle
        assert view is not None and view.status == "ready"
        assert agent.mail.take(order)
        agent.tick(2)
        assert stack.protocol.state is not State.WAIT_FOR_TASK  # a task under way

    asyncio.run(scenario())


def test_a_lost_vehicle_is_its_drones_problem_and_back_in_a_held_cell_the_drone_carries_on() -> None:
    """The link goes silent mid-plan: the drone stays a member, raises vehicle_lost, hands back the mail
    it has not picked up, holds every cell its vehicle may be in (its answers say so) and takes no mail.
    The vehicle answers again, seen in one of those cells: the drone rests there and takes mail again."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 7, 0)})

    async def scenario() -> None:
        node, vehicle = FakeNode(), vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle, GeoFrame(ws), lambda: 1000.0)
        agent.mail.take(MailOrder(id="m", pickup=[4, 0, 0], dropoff=[6, 3, 0], priority=5))
        d2 = Trajectory.stationary((7, 7, 0), 0)
        for step in range(30):  # coordinate (d2 answers, then holds the plan), then fly the first steps
            if stack.executor.flying:
                break
            agent.tick(step)
            for _ in range(2):  # d2 answers the request, then holds the plan it brings
                for k, p in list(node.puts):
                    body = decode(p).body
                    if isinstance(body, ReqTraj) and k == KEYS.proto("all", "d1"):
                        reply: Message = CurrentTraj("d2", d2, body.task_id.core())
                    elif isinstance(body, Propose):
                        reply = PlanAck("d2", body.task_id.core(), d2)
                    else:
                        continue
                    agent._on_protocol(KEYS.proto("d1", "d2"), encode("d2", 1000.0, from_core(reply)))
                    node.puts.remove((k, p))
            vehicle.over(stack.executor.cell)
        assert stack.executor.flying
        agent.tick(step)
        plan = stack.protocol.trajectory
        assert plan is not None
        vehicle.over(stack.executor.cell)
        seen = stack.executor.cell
        agent.tick(step + 1)
        vehicle.lost = "vehicle 1 on udpin://127.0.0.1:14540: no HEARTBEAT for 3.1 s (timeout 3.0 s)"
        await asyncio.sleep(0)
        agent.tick(step + 2)
        await asyncio.sleep(0)
        assert agent.alarms["vehicle_lost"].startswith("vehicle_lost: vehicle 1 on udpin")
        assert statuses(node, "m")[-1] == (MailStatus.HANDED_BACK, "drone d1's vehicle is lost")
        assert set(stack.protocol.holds()) >= set(plan.suffix_from(step + 2).cells) | {seen}
        asked = ReqForCurrentTraj(TaskId(step + 50, "d2", 9), "d2", Trajectory.stationary((7, 7, 0), step), ("d1",))
        node.puts.clear()
        agent._on_protocol(KEYS.proto("all", "d2"), encode("d2", 1000.0, from_core(asked)))
        answer = to_core(decode(node.puts[-1][1]), "d2")
        assert isinstance(answer, CurrentTraj) and set(answer.holds) == set(stack.protocol.holds())
        with_mail = MailOrder(id="m2", pickup=[2, 2, 0], dropoff=[3, 5, 0], priority=5)
        try:
            agent.mail.take(with_mail)
        except ProblemError as exc:
            assert "its vehicle is lost" in str(exc)
        else:
            raise AssertionError("a drone whose vehicle is lost took mail")

        back = plan.cells[-2]  # it held on along its plan, and is seen there
        vehicle.lost = None
        vehicle.over(back, at=2.0)
        agent.tick(step + 3)
        assert "vehicle_lost" not in agent.alarms
        assert (stack.executor.cell, stack.protocol.location, stack.protocol.holds()) == (back, back, ())
        assert agent.mail.take(with_mail)

    asyncio.run(scenario())


def test_a_vehicle_back_outside_its_held_cells_leaves_its_drone_out_of_service() -> None:
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0)})

    async def scenario() -> None:
        vehicle = vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, GeoFrame(ws), lambda: 1000.0)
        agent.tick(0)
        vehicle.lost = "connection closed by the vehicle"
        agent.tick(1)
        vehicle.lost = None
        vehicle.over((5, 5, 0), at=2.0)  # in the air, far from its cell
        agent.tick(2)
        assert "not in a cell held for it" in agent.alarms["vehicle_lost"]
        assert stack.protocol.holds() != ()  # still held where it may be
        assert agent.mail.refusal is not None and "land it by hand" in agent.mail.refusal

    asyncio.run(scenario())


def test_the_flight_record_has_only_fresh_sightings_never_a_stale_or_lost_vehicle() -> None:
    """A cell is recorded at a sample only from a position reported since the previous one: a vehicle
    whose position stopped coming, or whose link is lost, leaves a gap (the audit counts it), never the
    last cell it was seen in (a killed ArduCopter SITL was recorded for 23 steps where it died)."""
    record, vehicle = io.StringIO(), vehicle_over_its_start()

    async def scenario() -> None:
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle, FRAME, lambda: 1000.0,
                           record)
        for step in range(8):
            if step not in (3, 4):  # no new position at steps 3 and 4
                vehicle.at += 1.0
            vehicle.lost = "no HEARTBEAT for 3.0 s" if step >= 6 else None
            actions = agent.tick(step)
            agent.on_step(StepReport(step, stack.executor.cell, (0, 0, 0), 0.0, False, 0.0), actions)
            agent.on_sample(Sample(step, stack.executor.cell, (0, 0, 0), 0.0))
            await asyncio.sleep(0)

    asyncio.run(scenario())
    steps = [json.loads(line)["step"] for line in record.getvalue().splitlines()]
    assert steps == [0, 1, 2, 5]


def test_a_peer_that_says_its_vehicle_came_down_is_an_obstacle_for_good() -> None:
    """``plan`` with ``grounded``: the peer stays at its trajectory's end, whatever it flew before."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})

    async def scenario() -> DroneStack:
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
        down = PlanAnnounce(trajectory=WireTrajectory.of(Trajectory.stationary((4, 4, 0), 3)), grounded=True)
        agent._on_plan(KEYS.plan("d2"), encode("d2", 1000.0, down))
        return stack

    stack = asyncio.run(scenario())
    assert stack.protocol.peers_down == {"d2": (4, 4, 0)}


def test_a_message_whose_sender_is_not_its_keys_writer_is_dropped() -> None:
    """The access control lets only drone dX write dX's keys; a message on them that names another
    sender is a forgery (or a peer's bug) and changes nothing: here d3 claims, on its own keys, that
    d2 flies somewhere else."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0)})
    lie = Trajectory(5, ((7, 0, 0), (6, 0, 0), (5, 0, 0)))

    def known_after(key: str, sender: str, body: PlanAnnounce | CurTrajTo) -> Trajectory | None:
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, vehicle_over_its_start(), GeoFrame(ws),
                           lambda: 1000.0)
        agent.tick(0)
        handler = agent._on_plan if isinstance(body, PlanAnnounce) else agent._on_protocol
        handler(key, encode(sender, 1000.0, body))
        return stack.protocol.known.get("d2")

    announce = PlanAnnounce(trajectory=WireTrajectory.of(lie))
    answer = answers(lie, {"d3": TaskId(9, "d3", 1)})
    assert known_after(KEYS.plan("d2"), "d2", announce) == lie  # d2 on its own key: believed
    assert known_after(KEYS.plan("d3"), "d2", announce) != lie
    assert known_after(KEYS.answers("d2"), "d2", answer) == lie
    assert known_after(KEYS.answers("d3"), "d2", answer) != lie


@pytest.mark.parametrize("host", [None, "pair"])
def test_a_hosts_drone_sends_to_one_drone_on_its_hosts_key(host: str | None) -> None:
    """A drone flown by a host (several in one session) answers on ``proto/<host>/<to>``: the answers of the
    host's drones to one request are then one put; flown alone, on its own key."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})
    node = FakeNode()
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0,
                       host=host)
    agent.tick(0)
    request = ReqForCurrentTraj(TaskId(5, "d2", 1), "d2", Trajectory.stationary((7, 0, 0), 0), ("d1",))
    agent._on_protocol(KEYS.proto("all", "d2"), encode("d2", 1000.0, from_core(request)))
    answered = [k for k, p in node.puts if isinstance(decode(p).body, CurTraj)]
    assert answered == [KEYS.proto("d2", host or "d1")]


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


def test_a_brake_goes_out_as_a_plan_that_says_braked_and_peers_take_it_so() -> None:
    """The agent publishes its cut plan on ``plan`` with ``braked``; a peer reading it holds the
    sender where it braked, over the older answer of that plan."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})
    cut = Trajectory(3, ((7, 0, 0), (6, 0, 0), (6, 0, 0)))

    async def scenario() -> tuple[FakeNode, DroneStack]:
        node, stack = FakeNode(), DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
        agent._on_plan(KEYS.plan("d2"), encode("d2", 1000.0, PlanAnnounce(trajectory=WireTrajectory.of(cut),
                                                                           braked=True)))
        agent._carry_out([Braked(Trajectory(0, ((0, 0, 0), (1, 0, 0), (1, 0, 0))), (2, 0, 0))])
        return node, stack

    node, stack = asyncio.run(scenario())
    assert stack.protocol.braked == {"d2": cut} and stack.protocol.known["d2"] == cut
    told = [decode(p).body for k, p in node.puts if k == KEYS.plan("d1")]
    assert [(b.braked, b.trajectory.cells) for b in told if isinstance(b, PlanAnnounce)] == [
        (True, ((0, 0, 0), (1, 0, 0), (1, 0, 0)))]


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
    assert [(a.accepted, a.reason) for a in replies if isinstance(a, CommandAck)] == [
        (True, ""), (False, "d3 is not a drone gone from the fleet: nothing to release")]


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


def test_a_vehicle_later_than_lambda_holds_where_its_plan_ends_and_takes_no_task_until_on_time() -> None:
    """Peers plan with a margin of lambda for a vehicle's lateness: past it, the margin is gone. The
    drone plans nothing more, hands back the mail not on board, and every peer holds the rest of its
    plan; once its vehicle is where that plan ended, it takes tasks again."""
    async def scenario() -> tuple[FakeNode, DroneAgent, list[str]]:
        node, vehicle = FakeNode(), vehicle_over_its_start()
        stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle, FRAME, lambda: 1000.0)
        agent.mail.take(MailOrder(id="first", pickup=[3, 0, 0], dropoff=[5, 5, 0], priority=9))
        seen: list[str] = []
        for step in range(40):
            agent.on_step(StepReport(step, stack.executor.cell, None, 0.0, False, 0.0), agent.tick(step))
            agent.vehicle.airborne = not seen[1:]
            if stack.executor.flying and stack.executor.cell != (0, 0, 0) and agent.late is None and not seen:
                agent.on_sample(Sample(step, stack.executor.cell, (0, 0, 0), None))  # still at the start
                seen.append(f"late: off since {stack.protocol.off_since}")
                with pytest.raises(ProblemError, match="its vehicle was not in"):
                    agent.mail.take(MailOrder(id="refused", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=5))
            elif seen and stack.executor.trajectory is None and agent.late is not None:
                # Seen in the cell of the step sampled (lambda ago), not yet where the plan ended: still late.
                vehicle.over((2, 0, 0), at=vehicle.at + 1.0)
                agent.on_sample(Sample(step, (2, 0, 0), (2, 0, 0), 0.4))
                assert agent.late is not None and stack.executor.cell != (2, 0, 0)
                vehicle.over(stack.executor.cell, at=vehicle.at + 1.0)
                agent.vehicle.airborne = False  # landed there (SITL found a drone late for good once landed)
                agent.on_sample(Sample(step, stack.executor.cell, stack.executor.cell, 0.4))
                agent.vehicle.airborne = True
                seen.append(f"on time: off since {stack.protocol.off_since}")
                agent.mail.take(MailOrder(id="again", pickup=[2, 2, 0], dropoff=[4, 4, 0], priority=5))
            await asyncio.sleep(0)
        return node, agent, seen

    node, agent, seen = asyncio.run(scenario())
    assert seen[0].startswith("late: off since ") and seen[0] != "late: off since None"
    assert seen[1:] == ["on time: off since None"]
    assert statuses(node, "first")[-1] == (MailStatus.HANDED_BACK, "drone d1's vehicle is later than lambda")
    assert statuses(node, "again")[0] == (MailStatus.ACCEPTED, "")
    assert "late" not in agent.alarms
