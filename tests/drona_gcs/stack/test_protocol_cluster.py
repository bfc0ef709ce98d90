"""Two or three protocol machines joined through
:class:`tests.drona_gcs.stack.cluster.ProtocolCluster`: under several message orders and random
schedules everyone starts, plans against what its peers had committed, and the flown trajectories
are safe by the independent checker.
"""

from __future__ import annotations

import random
from collections.abc import Mapping

import pytest

from drona_gcs.motion import Trajectory
from drona_gcs.safety import check_fleet, check_trajectory
from drona_gcs.stack.messages import (
    CurrentTraj,
    PlanAck,
    PlanProposal,
    ReqForCurrentTraj,
    Task,
    TaskId,
)
from drona_gcs.stack.protocol import (
    NewTask,
    PeerJoined,
    PeerLeft,
    State,
)
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.stack.cluster import ProtocolCluster, Started
from tests.drona_gcs.stack.protocol_helpers import GOAL, ID_A, OPEN, A, B, confirmed, machine, started

# ============================================================ whole clusters
CROSSING = Workspace.build(size=(5, 5, 1), obstacles=frozenset({(1, 1, 0), (3, 3, 0)}), beta_s=1.0,
                           lambda_s=0.0)  # delta 1
CLUSTER_STARTS = {"a": (0, 2, 0), "b": (2, 0, 0), "c": (4, 4, 0)}
CLUSTER_GOALS = {"a": (4, 2, 0), "b": (2, 4, 0), "c": (0, 0, 0)}  # three crossing ways
ORDERS: list[str | int] = ["fifo", "lifo", 0, 1, 2, 3, 4]  # an int is the seed of a random order


def run_round(cluster: ProtocolCluster, goals: Mapping[str, Cell], order: str | int) -> None:
    """Every drone gets its task at the same step, then the network delivers everything."""
    first = len(cluster.started)
    for drone, goal in goals.items():
        cluster.start_task(drone, goal)
    cluster.deliver_all(random.Random(order) if isinstance(order, int) else order)
    round_ = cluster.started[first:]
    assert sorted(s.drone for s in round_) == sorted(goals), "every drone starts exactly once"
    assert cluster.failed == []
    for s in round_:
        plan = s.action.trajectory
        assert (plan.first, plan.last, plan.start_step) == (
            cluster.protocols[s.drone].location, goals[s.drone], cluster.now + cluster.lead_steps)
        # Psi holds what every peer had committed when I planned ...
        assert_holds_committed(cluster, s, range(cluster.now + 30))
    # ... and of every two plans, one was made against the other: the paper's safety argument (as
    # what was flown, or as a proposal, held besides what its drone flew before)
    for i, one in enumerate(round_):
        for other in round_[i + 1:]:
            assert made_against(one, other) or made_against(other, one)
            assert cluster.trajectory(one.drone) == one.action.trajectory
    flown = {s.drone: s.action.trajectory for s in round_}
    assert check_fleet(cluster.workspace, flown, cluster.delta) == []


def held_as(psi: Mapping[str, Trajectory], peer: str) -> list[Trajectory]:
    """What a plan's Psi held for ``peer``: what it answered, and its proposal not yet decided."""
    return [psi[key] for key in (peer, f"{peer}?") if key in psi]


def made_against(plan: Started, later: Started) -> bool:
    """Whether ``later`` was planned holding ``plan`` (flown, or proposed)."""
    return plan.action.trajectory in held_as(later.action.psi, plan.drone)


def assert_holds_committed(cluster: ProtocolCluster, s: Started, horizon: range) -> None:
    """Psi held, for every peer, what it had committed when ``s`` started (the same positions: a
    location's stamp may differ), or that peer's plan was made against ``s``'s, proposed then; and
    nothing but the peers' answers and proposals."""
    assert {key.rstrip("?") for key in s.action.psi} == set(s.peers_then)
    for peer, committed in s.peers_then.items():
        cells = [committed.at(t) for t in horizon]
        if any([held.at(t) for t in horizon] == cells for held in held_as(s.action.psi, peer)):
            continue
        theirs = [other for other in cluster.started if other.drone == peer and other.action.trajectory == committed]
        assert theirs and made_against(s, theirs[-1]), peer


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("drones", [("a", "b"), ("a", "c"), ("a", "b", "c")], ids="+".join)
def test_simultaneous_tasks_all_start_safely(drones: tuple[str, ...], order: str | int) -> None:
    cluster = ProtocolCluster(CROSSING, {d: CLUSTER_STARTS[d] for d in drones})
    assert cluster.delta == 1 and cluster.lead_steps == 2
    run_round(cluster, {d: CLUSTER_GOALS[d] for d in drones}, order)
    # the highest priority (lowest id) plans first (with equal stamps, the smallest name): against
    # nobody's proposal, and every other plan against it
    first = next(s for s in cluster.started if s.drone == min(drones))
    assert not any(key.endswith("?") for key in first.action.psi)
    assert all(made_against(first, other) for other in cluster.started if other is not first)


@pytest.mark.parametrize("order", ORDERS)
def test_a_second_round_plans_against_the_finished_first(order: str | int) -> None:
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    run_round(cluster, CLUSTER_GOALS, order)
    cluster.now = max(t.end_step for t in cluster.executed().values()) + 1
    for drone in CLUSTER_STARTS:
        cluster.complete(drone)
    run_round(cluster, CLUSTER_STARTS, order)  # and back home: the idle drones answer with their finished plans
    assert {s.drone: s.action.trajectory.first for s in cluster.started[3:]} == CLUSTER_GOALS


def test_a_drone_that_answered_a_request_ranks_below_it() -> None:
    """The hybrid clock at work: c answers b's request, then gets a task at the same physical step.
    By name c would lose to b anyway, so let a (the smallest name) be the one that answered."""
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    task_b = cluster.start_task("b", CLUSTER_GOALS["b"])
    for _ in range(3):  # b's broadcast reaches a, b and c
        cluster.deliver()
    task_a = cluster.start_task("a", CLUSTER_GOALS["a"])
    assert task_a.id > task_b.id  # a saw b's stamp
    cluster.deliver_all("lifo")
    [a] = [s for s in cluster.started if s.drone == "a"]
    [b] = [s for s in cluster.started if s.drone == "b"]
    assert made_against(b, a) and not made_against(a, b)  # b planned first
    assert check_fleet(CROSSING, cluster.executed(), cluster.delta) == []


def test_a_later_task_plans_around_a_drone_already_flying() -> None:
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    cluster.start_task("a", CLUSTER_GOALS["a"])
    cluster.deliver_all()
    cluster.now = 2  # a is under way
    cluster.start_task("b", CLUSTER_GOALS["b"])
    cluster.deliver_all("lifo")
    a, b = cluster.started
    assert b.action.psi["a"] == a.action.trajectory  # the executing drone answered with its plan
    assert b.action.task.id > a.action.task.id
    flown = {**cluster.executed(), "c": cluster.trajectory("c")}  # c stays where it is
    assert check_fleet(CROSSING, flown, cluster.delta) == []


def deliver_from(cluster: ProtocolCluster, sender: str, to: str, kind: type, task_id: TaskId | None = None) -> None:
    """Deliver the oldest message of type ``kind`` in flight from ``sender`` to ``to`` (a request: of ``task_id``)."""
    index = next(i for i, (s, t, m) in enumerate(cluster.network) if (s, t) == (sender, to) and isinstance(m, kind)
                 and (task_id is None or (isinstance(m, ReqForCurrentTraj) and m.task_id == task_id)))
    cluster.deliver(index)


def test_a_request_overtaken_by_its_senders_next_one_holds_up_no_one() -> None:
    """The issue tracker's deadlock end to end: b's request for a round that is over reaches a after its
    request for the next round, which ranks below a's task. Both still start, against what the other
    had committed, and safely."""
    cluster = ProtocolCluster(CROSSING, CLUSTER_STARTS)
    old = cluster.start_task("b", CLUSTER_GOALS["b"]).id
    deliver_from(cluster, "b", "c", ReqForCurrentTraj)  # c answers b; b's request to a is held up
    cluster.now = 2
    mine = cluster.start_task("a", CLUSTER_GOALS["a"]).id  # ranks below b's first task
    deliver_from(cluster, "a", "b", ReqForCurrentTraj)  # b holds a; a's request to c is held up
    deliver_from(cluster, "c", "b", CurrentTraj)  # b plans, and answers a with its plan once a and c hold it
    for peer in ("a", "c"):
        deliver_from(cluster, "b", peer, PlanProposal)
        deliver_from(cluster, peer, "b", PlanAck)
    deliver_from(cluster, "b", "a", CurrentTraj)
    cluster.now = cluster.trajectory("b").end_step
    cluster.complete("b")
    new = cluster.start_task("b", CLUSTER_STARTS["b"]).id  # b saw a's stamp: ranks below a's task
    assert old < mine < new
    deliver_from(cluster, "b", "a", ReqForCurrentTraj, new)  # its answer to a, waiting for a's plan
    deliver_from(cluster, "b", "a", ReqForCurrentTraj, old)  # late
    cluster.deliver_all()
    assert {d: p.state for d, p in cluster.protocols.items()} == {  # nothing in flight: nobody waits
        "a": State.EXECUTING, "b": State.EXECUTING, "c": State.WAIT_FOR_TASK}
    assert [(s.drone, s.action.task.id) for s in cluster.started] == [("b", old), ("a", mine), ("b", new)]
    horizon = range(max(t.end_step for t in cluster.executed().values()) + cluster.delta + 2)
    for s in cluster.started:  # Psi held what each peer had committed
        assert_holds_committed(cluster, s, horizon)
    assert made_against(cluster.started[1], cluster.started[2])
    assert check_fleet(CROSSING, cluster.executed(), cluster.delta) == []


def test_a_rejoined_peer_that_leaves_again_stays_an_obstacle_where_it_announced_itself() -> None:
    proto = machine({"a": A, "b": B})
    proto.handle(PeerLeft("b"), 0)
    back_at = (2, 0, 0)  # on a's shortest way to its goal
    proto.handle(PeerJoined("b", back_at), 1)
    proto.handle(NewTask(Task(ID_A, GOAL)), 2)
    action = started(confirmed(proto, proto.handle(PeerLeft("b"), 3)))  # gone again before answering
    assert check_trajectory(OPEN, action.trajectory, {"b": Trajectory.stationary(back_at, 1)}, 0) == []


# ============================================================ random schedules
def flown_paths(cluster: ProtocolCluster, horizon: int) -> dict[str, Trajectory]:
    """Where each drone is at every step 0..horizon: its latest started plan, else where it began."""
    paths = {}
    for drone, proto in cluster.protocols.items():
        plans = [s.action.trajectory for s in cluster.started if s.drone == drone]
        here = plans[0].first if plans else proto.location
        cells = []
        for t in range(horizon + 1):
            begun = [p for p in plans if p.start_step <= t]
            cells.append(begun[-1].at(t) if begun else here)
        paths[drone] = Trajectory(0, tuple(cells))
    return paths


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("n", [2, 3, 4])
def test_random_schedules_of_tasks_messages_and_time(n: int, seed: int) -> None:
    """Tasks to idle drones at random moments, messages delivered in random order, time going on
    and plans completing: Psi is always what the peers had committed, nobody stays stuck
    coordinating, and what the fleet flies is safe."""
    rng = random.Random(seed)
    starts = dict(list({**CLUSTER_STARTS, "d": (0, 0, 0)}.items())[:n])
    cluster = ProtocolCluster(CROSSING, starts)
    for _ in range(300):
        idle = [d for d, p in cluster.protocols.items() if p.state is State.WAIT_FOR_TASK]
        roll = rng.random()
        if roll < 0.5 and cluster.network:
            cluster.deliver(rng.randrange(len(cluster.network)))
        elif roll < 0.7 and idle:
            cluster.start_task(rng.choice(idle), rng.choice(CROSSING.free_cells))
        else:
            cluster.now += 1
            for drone, proto in cluster.protocols.items():
                if proto.state is State.EXECUTING and proto.trajectory and proto.trajectory.end_step <= cluster.now:
                    cluster.complete(drone)
    cluster.deliver_all(rng)
    assert all(p.state is not State.COORDINATING for p in cluster.protocols.values())
    assert len(cluster.started) >= n  # the schedule did something
    horizon = max(s.action.trajectory.end_step for s in cluster.started) + cluster.delta + 2
    for s in cluster.started:
        assert_holds_committed(cluster, s, range(horizon))
    assert check_fleet(CROSSING, flown_paths(cluster, horizon), cluster.delta) == []
