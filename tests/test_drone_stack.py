"""One drone's whole stack (:class:`~drona_gcs.stack.drone.DroneStack`), driven step by step with the cell
telemetry puts its vehicle in: what it reports must be what the vehicle did, not what the plan said.

A lone drone on an open grid (no peers, so each task plans at once) takes one mail; the test plays
its vehicle, ideal or not.
"""

from __future__ import annotations

from collections.abc import Callable

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import CONFIRM_STEPS, DroneAction, DroneStack, LegNotFlown, StackConfig
from drona_gcs.stack.mail import MAX_MISSES, MailDelivered, MailPickedUp, MailRejected, MailRequest
from drona_gcs.stack.protocol import State
from drona_gcs.workspace import Cell, Workspace

WS = Workspace.build(size=(6, 6, 1), drones={"d1": (0, 0, 0)})
MAIL = MailRequest("m1", pickup=(3, 0, 0), dropoff=(3, 3, 0), priority=5)
#: How the test's vehicle flies: from the stack and the step, the cell telemetry puts it in (None: none).
Vehicle = Callable[[DroneStack, int], Cell | None]


def ideal(stack: DroneStack, step: int) -> Cell | None:
    """Where the last step took it: the executor's cell before the boundary."""
    return stack.executor.cell


def stuck_at_start(stack: DroneStack, step: int) -> Cell | None:
    """Never left its start (a take-off that never happened): seen in its start cell."""
    return (0, 0, 0)


def fly(vehicle: Vehicle, steps: int, stack: DroneStack | None = None) -> tuple[DroneStack, list[DroneAction]]:
    stack = stack or DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    if not stack.mail.queue and stack.mail.current is None:
        stack.assign(MAIL)
    actions: list[DroneAction] = []
    for step in range(stack.executor.step + 1, stack.executor.step + 1 + steps):
        actions += stack.step(step, 100.0, vehicle(stack, step))
    return stack, actions


def of(kind: type, actions: list[DroneAction]) -> list[DroneAction]:
    return [a for a in actions if isinstance(a, kind)]


def test_an_ideal_vehicle_picks_up_and_delivers_once_seen_at_each_cell() -> None:
    _, actions = fly(ideal, 40)
    assert of(MailPickedUp, actions) == [MailPickedUp(MAIL)] and of(MailDelivered, actions) == [MailDelivered(MAIL)]
    assert of(LegNotFlown, actions) == []


def test_a_vehicle_that_never_flew_picks_nothing_up_and_the_mail_is_handed_back() -> None:
    """The plan to the pickup ends, yet telemetry still puts the vehicle at its start: no pickup is
    reported. Each plan that ends so is a leg not flown; after MAX_MISSES the mail goes back."""
    _, actions = fly(stuck_at_start, 80)
    assert of(MailPickedUp, actions) == [] and of(MailDelivered, actions) == []
    missed = of(LegNotFlown, actions)
    assert missed[:MAX_MISSES] == [LegNotFlown(MAIL.pickup, (0, 0, 0))] * MAX_MISSES
    assert of(MailRejected, actions)[0].request == MAIL  # type: ignore[union-attr]
    assert "never reached the pickup" in of(MailRejected, actions)[0].reason  # type: ignore[union-attr]


def test_a_vehicle_late_by_a_step_still_picks_up_when_it_gets_there() -> None:
    """Seen at each cell one boundary after the plan put it there: within CONFIRM_STEPS, so the mail
    is picked up and delivered, each when the vehicle is seen at the cell."""
    trail: list[Cell] = []

    def late(stack: DroneStack, step: int) -> Cell | None:
        trail.append(stack.executor.cell)
        return trail[-2] if len(trail) > 1 else trail[-1]

    _, actions = fly(late, 60)
    assert CONFIRM_STEPS >= 2
    assert of(MailPickedUp, actions) == [MailPickedUp(MAIL)] and of(MailDelivered, actions) == [MailDelivered(MAIL)]


def test_a_lost_vehicle_plans_nothing_and_back_in_a_held_cell_the_drone_rests_there() -> None:
    stack, _ = fly(ideal, 3)  # under way to the pickup
    assert stack.protocol.state is State.EXECUTING and not stack.mail.carrying
    trajectory = stack.protocol.trajectory
    assert trajectory is not None
    seen = stack.executor.cell
    handed = stack.vehicle_lost(stack.now, seen, "its vehicle is lost")
    assert handed == [MailRejected(MAIL, "its vehicle is lost")]  # another drone may fly it
    assert set(stack.protocol.holds()) >= {seen, *trajectory.suffix_from(stack.now).cells}
    stack, actions = fly(lambda s, k: None, 30, stack)  # nothing seen while lost: nothing reported
    assert of(MailPickedUp, actions) == []
    assert stack.protocol.state is State.WAIT_FOR_TASK  # the plan ran out; no new one while lost
    stack.vehicle_back((2, 0, 0), landed=False)
    assert (stack.executor.cell, stack.protocol.location, stack.protocol.holds()) == ((2, 0, 0), (2, 0, 0), ())
    stack, actions = fly(ideal, 40, stack)  # given the mail again, it flies it from there
    assert of(MailDelivered, actions) == [MailDelivered(MAIL)]
