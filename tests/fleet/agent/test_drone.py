"""One drone's agent (fleet.agent.drone) with its stack, over a recording transport and a scripted vehicle:
its peers, and the messages it sends and takes.
"""

from __future__ import annotations

import asyncio

import pytest

from drona_gcs.geo import GeoFrame
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.stack.messages import CurrentTraj, PlanAck, PlanDecision, PlanProposal, ReqForCurrentTraj, TaskId
from drona_gcs.stack.protocol import Braked, State
from drona_gcs.workspace import Workspace
from fleet.agent.admission import TaskBudget
from fleet.agent.drone import DroneAgent
from fleet.transport.wire import (
    CurTraj,
    CurTrajTo,
    Decide,
    DroneState,
    Envelope,
    MailOrder,
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
    proposing,
)
from tests.fakes.node import FakeNetwork, FakeNode
from tests.fleet.agent.drone_helpers import KEYS, vehicle_over_its_start


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
    """Drone d1 of ``ws`` (one that asks first), given a mail and past its first boundary: coordinating,
    its request out."""
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws), propose_at_once=False), dict(ws.drones))
    agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
    agent.mail.take(MailOrder(id="m", pickup=pickup, dropoff=dropoff, priority=1))
    agent.tick(0)
    mine = next(b.task_id.core() for k, p in node.puts if isinstance(b := decode(p).body, ReqTraj))
    return agent, stack, mine


def test_a_task_proposed_at_once_goes_to_everyone_in_one_put_and_asks_nobody() -> None:
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})

    async def scenario() -> tuple[list[tuple[str, object]], State]:
        node = FakeNode()
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
        agent.mail.take(MailOrder(id="m", pickup=[3, 3, 0], dropoff=[5, 5, 0], priority=1))
        agent.tick(0)
        return [(k, decode(p).body) for k, p in node.puts if k.startswith(f"{KEYS.root}/proto/")], stack.protocol.state

    sent, state = asyncio.run(scenario())
    assert [k for k, _ in sent] == [KEYS.proto("all", "d1")]
    assert isinstance(sent[0][1], Propose) and sent[0][1].direct and state is State.CONFIRMING


def _protocol_state(stack: DroneStack) -> State:
    """The protocol's state now: read anew after a message (mypy keeps the state an earlier check found)."""
    return stack.protocol.state


def test_a_new_plan_answers_the_drones_that_waited_for_it_in_one_message_to_everyone() -> None:
    """Drones that asked while this one coordinated wait for its new plan; it goes to them in the plan's
    ``propose``, which every drone gets, not one message each (a fleet given mail at once chains every
    round through these answers), with where this one is now: they hold both until the ``decide``.
    Each waiting drone reads its own answer out of it."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0), "d4": (0, 7, 0)})

    async def scenario(waiting: list[str]) -> tuple[list[tuple[str, Envelope]], list[tuple[str, Envelope]]]:
        node = FakeNode()
        agent, stack, mine = _coordinating(ws, node, [3, 3, 0], [5, 5, 0])
        for peer in waiting:  # lower priorities (later stamps): they wait for my plan
            where = Trajectory.stationary(ws.drones[peer], 0)  # its answer too (see drona_gcs.stack.protocol)
            asked = tuple(sorted(set(ws.drones) - {peer}))
            request = ReqForCurrentTraj(TaskId(mine.stamp + 5, peer, 1), peer, where, asked)
            agent._on_protocol(KEYS.proto("all", peer), encode(peer, 1000.0, from_core(request)))
        node.puts.clear()
        for peer in sorted({"d2", "d3", "d4"} - set(waiting)):
            answer = CurrentTraj(peer, Trajectory.stationary(ws.drones[peer], 0), mine)
            agent._on_protocol(KEYS.proto("d1", peer), encode(peer, 1000.0, from_core(answer)))
        assert stack.protocol.state is State.CONFIRMING  # flown once every peer holds it
        protocol = (f"{KEYS.root}/proto/", f"{KEYS.root}/answers/", KEYS.plan("d1"))
        proposed = [(k, decode(p)) for k, p in node.puts if k.startswith(protocol)]
        node.puts.clear()
        for peer in ("d2", "d3", "d4"):
            ack = PlanAck(peer, mine, Trajectory.stationary(ws.drones[peer], 0))
            agent._on_protocol(KEYS.proto("d1", peer), encode(peer, 1000.0, from_core(ack)))
        assert _protocol_state(stack) is State.EXECUTING
        await asyncio.sleep(0)  # the plan's announcement, if any, goes out once the answers have
        return proposed, [(k, decode(p)) for k, p in node.puts if k.startswith(protocol)]

    for waiting in (["d2", "d3"], ["d2"]):
        proposed, decided = asyncio.run(scenario(waiting))
        # The plan goes to every drone, in one put to all that answers the waiting ones too ...
        assert [key for key, _ in proposed] == [KEYS.proto("all", "d1")]
        envelope = proposed[0][1]
        assert isinstance(envelope.body, Propose) and set(envelope.body.replies) == set(waiting)
        for peer in waiting:
            answer = answer_in(envelope, peer)
            assert isinstance(answer, CurrentTraj) and answer.in_reply_to.drone == peer
            assert answer.trajectory.cells == ((0, 0, 0),)  # where d1 is: flown unless the plan is
            assert answer.proposal is not None and answer.proposal.trajectory.last == (3, 3, 0)  # to the pickup
        assert answer_in(envelope, "d4") is None  # d4 did not wait: nothing in it for d4
        # ... and every drone is told it is flown, in one put to all.
        assert [key for key, _ in decided] == [KEYS.proto("all", "d1")]
        assert isinstance(decided[0][1].body, Decide) and decided[0][1].body.flown
        assert decided[0][1].body.replies == {}


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


def test_a_proposal_that_answers_a_waiting_drone_lets_its_round_go_on() -> None:
    """A ``propose`` carries the answers to the drones that waited for the plan: a drone it names plans
    against both what the sender flies now and the plan; a drone it does not name still waits."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})
    plan = Trajectory(1, ((7, 0, 0), (7, 1, 0), (7, 2, 0)))

    async def scenario(named: bool) -> tuple[State, dict[str, Trajectory]]:
        agent, stack, mine = _coordinating(ws, FakeNode(), [5, 5, 0], [6, 6, 0])
        replies = {"d1": mine} if named else {"d9": TaskId(mine.stamp, "d9", 1)}
        proposal = PlanProposal("d2", TaskId(mine.stamp - 1, "d2", 1), plan, ("d1",))
        proposed = proposing(proposal, replies, Trajectory.stationary((7, 0, 0), 0))
        agent._on_protocol(KEYS.proto("all", "d2"), encode("d2", 1000.0, proposed))
        return stack.protocol.state, stack.protocol._undecided()

    state, undecided = asyncio.run(scenario(named=True))
    assert state is State.CONFIRMING and undecided == {"d2?": plan}  # planned, holding the proposal too
    assert asyncio.run(scenario(named=False))[0] is State.COORDINATING


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


class _Rounds(TaskBudget):
    """A host's budget that keeps what its rounds took."""

    def __init__(self) -> None:
        super().__init__(0.25, 0.2)
        self.took: list[float] = []

    def round_ended(self, took_s: float) -> None:
        self.took.append(took_s)
        super().round_ended(took_s)


@pytest.mark.parametrize("ending", ["flown", "failed"])
def test_a_round_tells_the_hosts_budget_how_long_it_took(ending: str) -> None:
    """The budget keeps rounds within their target only if every round ends there: a plan flown or none."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})

    async def scenario() -> tuple[State, list[float]]:
        node, now = FakeNode(), [1000.0]
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: now[0])
        agent.budget = budget = _Rounds()
        agent.mail.take(MailOrder(id="m", pickup=[3, 3, 0], dropoff=[5, 5, 0], priority=1))
        agent.tick(0)
        proposed = next(b for _, p in node.puts if isinstance(b := decode(p).body, Propose))
        now[0] += 0.04
        if ending == "flown":
            ack = PlanAck("d2", proposed.task_id.core(), Trajectory.stationary((7, 0, 0), 0), direct=True)
            agent._on_protocol(KEYS.proto("d1", "d2"), encode("d2", now[0], from_core(ack)))
        else:
            agent._on_liveliness(KEYS.alive("d2"), False)  # gone before it held the plan
        return stack.protocol.state, budget.took

    state, took = asyncio.run(scenario())
    assert state is (State.EXECUTING if ending == "flown" else State.WAIT_FOR_TASK)
    assert took == [pytest.approx(0.04)]


def test_holds_that_come_after_newer_ones_are_dropped_and_a_drones_holds_go_out_counted() -> None:
    """Sweep 30752 (``--skews 2 --max-delay 2``): a drone whose clock went off held three cells of its plan,
    then only the one it braked in. A peer got the two in the other order, held the three for good, and
    its task planner flew between two chargers with a mail for 628 steps. Each holds now goes out counted,
    and one older than what its sender said since is dropped."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})
    wide, narrow = ((7, 2, 0), (7, 1, 0), (7, 0, 0)), ((7, 0, 0),)

    def holds(cells: tuple[tuple[int, int, int], ...], seq: tuple[int, int]) -> bytes:
        return encode("d2", 1000.0, PlanAnnounce(trajectory=WireTrajectory.of(Trajectory.stationary((7, 0, 0), 0)),
                                                 lost=True, holds=cells, for_now=True, holds_seq=seq))

    async def scenario() -> tuple[FakeNode, DroneStack, tuple[tuple[int, int, int], ...]]:
        node, stack = FakeNode(), DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones), epoch=7)
        agent = DroneAgent(stack, node, KEYS, vehicle_over_its_start(), GeoFrame(ws), lambda: 1000.0)
        agent._on_plan(KEYS.plan("d2"), holds(narrow, (5, 2)))
        agent._on_plan(KEYS.plan("d2"), holds(wide, (5, 1)))  # sent first, come last
        held = stack.protocol.peers_lost["d2"]
        agent._on_plan(KEYS.plan("d2"), holds(wide, (6, 1)))  # its agent restarted: it counts anew
        agent._carry_out(stack.clock_bound(True, frozenset(), "my clock is off"))
        agent._carry_out(stack.vehicle_lost(0, (0, 0, 0), "lost"))
        return node, stack, held

    node, stack, held = asyncio.run(scenario())
    assert held == narrow and stack.protocol.peers_lost == {"d2": wide}
    told = [decode(p).body for k, p in node.puts if k == KEYS.plan("d1")]
    assert [b.holds_seq for b in told if isinstance(b, PlanAnnounce) and b.lost] == [(7, 1), (7, 2)]
