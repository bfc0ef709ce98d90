"""One drone's whole stack making way: drones on a ring whose only way is where another is parked.
"""

from __future__ import annotations

import pytest

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneAction, DroneStack, StackConfig, yield_spot
from drona_gcs.stack.mail import (
    GoTo,
    MailDelivered,
    MailRequest,
    Phase,
)
from drona_gcs.stack.messages import Message
from drona_gcs.stack.protocol import (
    NewTask,
    StartExecuting,
    State,
)
from drona_gcs.workspace import Cell, Workspace
from tests.drona_gcs.stack.drone_helpers import drain, of, route

# ------------------------------------------------------------ making way
#: A ring around a wall: from the pickup (2, 0) to the drop-off (3, 2), the way is by (0, 1) or
#: by (6, 1). A vehicle down rests on one, a drone parks on the other: together they wall it off.
RING_MAIL = MailRequest("m1", pickup=(2, 0, 0), dropoff=(3, 2, 0), priority=5)


def ring(parked_at: Cell) -> Workspace:
    return Workspace.build(size=(7, 3, 1), obstacles=frozenset((x, 1, 0) for x in range(1, 6)),
                           drones={"d1": (2, 0, 0), "d2": (0, 1, 0), "d3": (6, 1, 0)},
                           parking=(parked_at,))


def fleet_on_the_ring(ws: Workspace, down: str, steps: int) -> dict[str, list[DroneAction]]:
    """d1 carries RING_MAIL; ``down``'s vehicle came down where it started; every message arrives at once."""
    config = StackConfig(ws, SafePlanner(ws))
    stacks = {d: DroneStack(d, config, dict(ws.drones)) for d in ws.drones}
    early = stacks[down].vehicle_down("a failsafe", ws.drones[down])
    stacks["d1"].assign(RING_MAIL)
    done: dict[str, list[DroneAction]] = {d: [] for d in stacks}
    inbox: list[tuple[str, Message]] = []
    for peer in set(stacks) - {down}:  # its announcement that it stays there for good
        done[peer] += stacks[peer].peer_down(down, ws.drones[down])
    done[down] += early

    def post(sender: str, actions: list[DroneAction]) -> None:
        done[sender] += actions
        route(stacks, inbox, sender, actions)

    for step in range(steps):
        for drone, stack in stacks.items():
            post(drone, stack.step(step, 100.0, stack.executor.cell, may_plan=drone != down))
        drain(stacks, inbox, done)
    return done


@pytest.mark.parametrize("down", ["d2", "d3"])
def test_a_drone_parked_on_the_only_way_makes_way_for_mail_on_board(down: str) -> None:
    """The paper leaves MRMP incomplete: drones resting for good can wall a goal off. Found by the
    systematic tester: a vehicle down and a parked drone walled a drop-off off, and the mail on
    board waited for good. The drone whose leg found no plan asks those resting on a way to leave it
    (first the shortest; then around cells that stayed taken, as a vehicle down does)."""
    parked = "d3" if down == "d2" else "d2"
    ws = ring(parked_at=(6, 1, 0) if parked == "d3" else (0, 1, 0))
    done = fleet_on_the_ring(ws, down, 120)
    assert of(MailDelivered, done["d1"]) == [MailDelivered(RING_MAIL)]
    moves = [a for a in done[parked] if isinstance(a, GoTo)]
    assert moves[0].purpose is Phase.MAKING_WAY and moves[0].goal != ws.drones[parked]
    assert moves[-1].purpose is Phase.TO_PARKING  # and home again afterwards


def test_a_goal_that_found_no_plan_asks_its_way_clear_after_legs_elsewhere() -> None:
    """Found by a random sweep (seed 921887): a charger walled in by resting drones found no plan; a
    leg to a parking cell came between, and the next try at the charger no longer asked its way
    clear (only the last leg's goal was remembered). The drone went between charger and parking
    for good, and the mail it held waited."""
    ws = Workspace.build(size=(4, 2, 1), obstacles=frozenset({(0, 1, 0), (1, 1, 0)}),
                         charging_stations=((0, 0, 0),), parking=((3, 1, 0),),
                         drones={"d1": (3, 0, 0), "d2": (1, 0, 0)})
    stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
    stack.peer_left("d2")  # at rest on the only way to the charger
    charger, parking = GoTo((0, 0, 0), None, Phase.TO_CHARGER), GoTo((3, 1, 0), None, Phase.TO_PARKING)
    assert stack._way_to_clear(charger) == ()  # a first try asks nothing
    stack._protocol(NewTask(stack._task(charger, 0, 0)))
    assert stack.protocol.state is State.WAIT_FOR_TASK  # cut off: no plan
    flown = stack._protocol(NewTask(stack._task(parking, 1, 1)))
    assert any(isinstance(a, StartExecuting) for a in flown)
    assert (1, 0, 0) in stack._way_to_clear(charger)


def test_a_drone_boxed_in_on_a_way_makes_way_to_a_charger_when_nothing_else_is_left() -> None:
    """Found by the 60 s sweep: boxed in by a parked drone and a vehicle down, a drone asked to make
    way found no cell but a charger, stayed, and the mail behind it waited for good."""
    corridor = Workspace.build(size=(4, 1, 1), charging_stations=((0, 0, 0),), drones={"d1": (1, 0, 0)})
    way = frozenset({(1, 0, 0), (2, 0, 0), (3, 0, 0)})  # where it rests is on the way
    assert yield_spot(corridor, (1, 0, 0), way, ()) == (0, 0, 0)
    assert yield_spot(corridor, (1, 0, 0), way | {(0, 0, 0)}, ()) is None
    wide = Workspace.build(size=(4, 2, 1), charging_stations=((0, 0, 0),), drones={"d1": (1, 0, 0)})
    assert yield_spot(wide, (1, 0, 0), way, ()) == (1, 1, 0)  # a free cell first, though farther


@pytest.mark.parametrize("gone", ["down", "departed"])
def test_a_way_asked_clear_goes_around_a_drone_that_cannot_leave_after_legs_elsewhere(gone: str) -> None:
    """Found by a sweep (seed 30638, config 905545): the shortest way to a charger crossed a vehicle
    down, which cannot leave. A leg elsewhere flown between two tries forgot that the way stayed
    shut, so every try asked that way again, never the one by the drone parked on the other; the
    drone went between charger and parking for good, and its mail waited. A departed drone cannot
    leave either, until it is back."""
    ws = Workspace.build(size=(5, 3, 1), obstacles=frozenset({(1, 1, 0), (2, 1, 0), (3, 1, 0)}),
                         charging_stations=((4, 0, 0),), parking=((0, 1, 0),),
                         drones={"d1": (0, 0, 0), "d2": (2, 0, 0), "d3": (2, 2, 0)})
    config = StackConfig(ws, SafePlanner(ws))
    stacks = {d: DroneStack(d, config, dict(ws.drones)) for d in ws.drones}
    if gone == "down":  # on the shortest way; d3 rests on the other
        stacks["d2"].vehicle_down("a failsafe", (2, 0, 0))
        for peer in ("d1", "d3"):
            stacks[peer].peer_down("d2", (2, 0, 0))
    else:
        del stacks["d2"]
        for peer in ("d1", "d3"):
            stacks[peer].peer_left("d2")
    d1 = stacks["d1"]
    done: dict[str, list[DroneAction]] = {d: [] for d in stacks}
    charger, parking = GoTo((4, 0, 0), None, Phase.TO_CHARGER), GoTo((0, 1, 0), None, Phase.TO_PARKING)

    def settle(actions: list[DroneAction]) -> None:
        inbox: list[tuple[str, Message]] = []
        done["d1"] += actions
        route(stacks, inbox, "d1", actions)
        drain(stacks, inbox, done)

    settle(d1._protocol(NewTask(d1._task(charger, 0, 0))))
    assert d1.protocol.state is State.WAIT_FOR_TASK and not of(StartExecuting, done["d1"])  # cut off: no plan
    settle(d1._protocol(NewTask(d1._task(parking, 1, 1))))
    assert of(StartExecuting, done["d1"])  # a leg flown in between
    way = d1._way_to_clear(charger)
    assert (2, 2, 0) in way and (2, 0, 0) not in way
