"""What the world's network carries besides the protocol's messages, and how its trace words them
and the drones' actions."""

from __future__ import annotations

from dataclasses import dataclass

from drona_gcs.motion import Trajectory
from drona_gcs.stack.battery import BatteryLow, BatteryRecharged
from drona_gcs.stack.mail import GoTo, MailDelivered, MailLost, MailPickedUp, MailRejected, MailStarted
from drona_gcs.stack.messages import CurrentTraj, Message, PlanDecision, ReqForCurrentTraj
from drona_gcs.stack.protocol import Braked, RerouteFailed, StartExecuting, TaskFailed, Threatened
from drona_gcs.verify.network import Joined, Left
from drona_gcs.verify.verdicts import cell_text, cells_text
from drona_gcs.workspace import Cell


@dataclass(frozen=True)
class Announce:
    """The sender's new plan, as every drone reads it (the answers on ``answers``, or ``plan/<me>``)."""

    trajectory: Trajectory
    grounded: bool = False  #: the sender's vehicle came down: it stays at the trajectory's end for good
    braked: bool = False  #: the sender cut its plan short of a cell held for good (read as any plan)


@dataclass(frozen=True)
class Holds:
    """The cells the sender's vehicle may be in, held for good (none: no more), as ``plan/<me>`` says."""

    cells: tuple[Cell, ...]
    for_now: bool = False  #: late or its clock off, not lost
    seq: tuple[int, int] = (0, 0)  #: which of the sender's holds (Holding.seq)


@dataclass(frozen=True)
class Clear:
    """The service holds ``mail_id`` as the receiver's from now on: it may take it on board."""

    mail_id: str


#: The sender of the service's clearances (``drona serve``: the drone's mail/clear query).
SERVICE = "service"

Notice = Message | Announce | Holds | Left | Joined | Clear


def describe(message: Notice) -> str:
    """A message as the trace prints it."""
    name = type(message).__name__
    if isinstance(message, CurrentTraj):
        return f"{name}(from {message.sender}, re {message.in_reply_to}, {cells_text(message.trajectory)})"
    if isinstance(message, Announce) and message.grounded:
        return f"{name}(vehicle down in {cell_text(message.trajectory.last)})"
    if isinstance(message, Announce):
        return f"{name}({cells_text(message.trajectory)})"
    if isinstance(message, Holds):
        return f"{name}({' '.join(map(cell_text, message.cells)) or 'none'})"
    if isinstance(message, Left):
        return f"{name}(silent since step {message.since})"
    if isinstance(message, Joined):
        return name
    if isinstance(message, Clear):
        return f"{name}({message.mail_id})"
    if isinstance(message, PlanDecision):
        return f"{name}(task {message.task_id} of {message.sender}: {'flown' if message.flown else 'dropped'})"
    if isinstance(message, ReqForCurrentTraj) and message.clear:
        way = " ".join(map(cell_text, message.clear))
        return f"{name}(task {message.task_id} of {message.sender}, asks to clear {way})"
    return f"{name}(task {message.task_id} of {message.sender})"


def note(action: object) -> str:
    """A line of the trace for the actions worth reading; empty for the rest."""
    if isinstance(action, StartExecuting):
        t = action.trajectory
        return f"plans task {action.task.id}: {cells_text(t, len(t.cells))}"
    if isinstance(action, TaskFailed):
        return f"no plan for task {action.task.id} to {cell_text(action.task.goal)}: {action.reason}"
    if isinstance(action, Threatened):
        return f"{action.departed} may hold {cell_text(action.cells[0])} of my plan for good: plans its rest anew"
    if isinstance(action, RerouteFailed):
        return f"no new plan for the rest of mine (task {action.task.id}): {action.reason}"
    if isinstance(action, Braked):
        t = action.trajectory
        return f"brakes short of {cell_text(action.held)}, held for good: holds {cell_text(t.last)} from {t.end_step}"
    if isinstance(action, GoTo):
        by = f" within {action.flight_steps} steps of flight" if action.flight_steps is not None else ""
        return f"task planner: go to {cell_text(action.goal)} for {action.purpose.value}{by}"
    if isinstance(action, (MailStarted, MailPickedUp, MailDelivered)):
        return f"{type(action).__name__} {action.request.id}"
    if isinstance(action, (MailRejected, MailLost)):
        return f"{type(action).__name__} {action.request.id}: {action.reason}"
    if isinstance(action, (BatteryLow, BatteryRecharged)):
        return f"{type(action).__name__} at {action.level:.0f}%"
    return ""
