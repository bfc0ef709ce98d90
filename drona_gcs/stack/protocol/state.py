"""The coordination protocol's states, and the shape of an entry of its one table (:data:`.machine.TRANSITIONS`)."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass

from drona_gcs.stack.protocol.actions import Action


class State(enum.Enum):
    WAIT_FOR_TASK = "WaitForTaskRequest"  #: idle at its location, answering with it
    COORDINATING = "CoordinateAndGeneratePlan"  #: collecting every peer's trajectory
    EXECUTING = "WaitForPlanCompletion"  #: flying its plan, answering with it
    REROUTING = "RerouteWhileExecuting"  #: flying its plan, collecting trajectories to plan its rest anew
    CONFIRMING = "ConfirmPlan"  #: planned; flies the plan once every member holds it


#: Handlers take (protocol, event of the row's type, now); Callable[..., ...] since each takes its own type.
Handler = Callable[..., list[Action]]


@dataclass(frozen=True)
class Move:
    """What a state does with an event: the handler that takes it, and every state taking it may lead to,
    on the way or to stay (none: the state does not change)."""

    handler: Handler
    targets: frozenset[State] = frozenset()


@dataclass(frozen=True)
class Taking:
    """The event a protocol is taking, in the state that took it, and where the table lets it lead."""

    state: State
    event: type
    targets: frozenset[State]

