"""One drone's whole stack under the operator's commands: pause, resume, recall and land.
"""

from __future__ import annotations

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneAction, DroneStack, StackConfig
from drona_gcs.stack.mail import (
    GoTo,
    MailDelivered,
    MailPickedUp,
    MailRejected,
    MailRequest,
)
from drona_gcs.stack.protocol import State
from tests.drona_gcs.stack.drone_helpers import MAIL, WS, fly, ideal, of, state_of


# ------------------------------------------------------------------ operator's commands
def test_a_paused_drone_starts_no_mail_and_takes_it_up_again_when_resumed() -> None:
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    stack.command("pause", "pause by ops")
    _, actions = fly(ideal, 30, stack)
    assert of(MailPickedUp, actions) == [] and stack.mail.queue == [MAIL] and stack.commanded == "pause"
    stack.command("resume", "resume by ops")
    _, actions = fly(ideal, 40, stack)
    assert of(MailDelivered, actions) == [MailDelivered(MAIL)] and stack.commanded is None


def test_a_paused_drone_still_delivers_the_mail_on_board() -> None:
    stack, actions = fly(ideal, 1)
    for _ in range(60):
        actions += stack.step(stack.executor.step + 1, 100.0, stack.executor.cell)
        if of(MailPickedUp, actions) and stack.commanded is None:
            stack.command("pause", "pause by ops")
    assert stack.commanded == "pause" and of(MailDelivered, actions) == [MailDelivered(MAIL)]


def test_a_recalled_drone_hands_back_the_mail_not_on_board() -> None:
    stack, _ = fly(ideal, 2)  # planning its way to the pickup
    handed = stack.command("recall", "recall by ops")
    assert [(a.request, a.reason) for a in of(MailRejected, handed)] == [(MAIL, "recall by ops")]
    _, actions = fly(ideal, 40, stack)
    assert of(MailPickedUp, actions) == [] and stack.mail.current is None


def test_a_drone_landed_by_the_operator_mid_flight_stops_through_a_round_and_stays() -> None:
    """Flying a plan, it plans its rest anew (a Reroute: a round every peer answers) to stay at the
    cell its plan reaches once a new plan may start, then holds there: no leg at all until resumed."""
    far = MailRequest("far", pickup=(5, 5, 0), dropoff=(0, 5, 0), priority=5)
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    stack.assign(far)
    actions: list[DroneAction] = []

    def boundary() -> None:
        actions.extend(stack.step(stack.executor.step + 1, 100.0, stack.executor.cell))

    while stack.protocol.state is not State.EXECUTING:
        boundary()
    for _ in range(3):  # a few cells along
        boundary()
    plan = stack.protocol.trajectory
    assert plan is not None
    stop = plan.at(stack.now + stack.protocol.lead_steps)
    landed = stack.command("land", "land by ops")
    assert [a.request for a in of(MailRejected, landed)] == [far]
    assert stack.protocol.trajectory is not None and stack.protocol.trajectory.last == stop  # alone: planned at once
    for _ in range(40):
        boundary()
    assert stack.executor.cell == stop != plan.last and stack.landed
    assert state_of(stack.protocol) is State.WAIT_FOR_TASK and not of(GoTo, actions[-40:])
