"""What one drone's stack is built with and says besides its machines' actions: the fleet's shared
configuration, the lead times, and the end of a leg (see :mod:`drona_gcs.stack.drone`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from drona_gcs.planner import SafePlanner
from drona_gcs.stack.battery import BatteryLow, BatteryModel, BatteryRecharged
from drona_gcs.stack.executor import Completed, Setpoint
from drona_gcs.stack.mail import MailAction, Phase
from drona_gcs.stack.protocol import Action as ProtocolAction
from drona_gcs.workspace import Cell, Workspace


def confirm_steps(workspace: Workspace) -> int:
    """Boundaries after a plan's end by which the vehicle must have been seen in its goal: it may
    enter it up to lambda late, and one more for a vehicle that trails by a cell (the lag alarm's)."""
    return math.ceil(workspace.lateness_s / workspace.tau_s) + 1


@dataclass(frozen=True)
class Arrival:
    """A plan ended at ``goal``; the leg counts once telemetry puts the vehicle there, by ``deadline``."""

    goal: Cell
    deadline: int


@dataclass(frozen=True)
class LegNotFlown:
    """A plan ended, yet telemetry never put the vehicle in its goal: the leg did not happen."""

    goal: Cell
    seen: Cell | None  #: where telemetry put the vehicle last (None: in no cell)


DroneAction = (ProtocolAction | Setpoint | Completed | MailAction | BatteryLow | BatteryRecharged
               | LegNotFlown)


CLIMB_RATE_M_S = 1.5  #: a cautious take-off climb rate, for the default lead time
ARM_AND_MODE_S = 2.0  #: mode change, arming and take-off command acknowledged
SPOOL_UP_S = 4.0  #: an accepted take-off to leaving the ground (ArduCopter SITL: about 3.5 s)


def default_lead_steps(workspace: Workspace, speedup: float = 1.0) -> int:
    """Delta + 1, plus the steps a landed drone needs to take off and climb into the grid (``speedup``: a
    fake vehicle's simulated seconds per second)."""
    climb_s = ARM_AND_MODE_S + SPOOL_UP_S + workspace.geo.layer0_alt_m / CLIMB_RATE_M_S
    return workspace.delta + 1 + math.ceil(climb_s / speedup / workspace.tau_s)


ROUND_S = 1.0  #: a coordination round, from the request to the last ack, with room (LAN p99: tenths of a second)


def default_hover_lead_steps(workspace: Workspace) -> int:
    """Delta + 1, plus the steps a round takes: a drone in the air climbs no more before its plan."""
    return workspace.delta + 1 + math.ceil(ROUND_S / workspace.tau_s)


def leg_overhead(lead_steps: int) -> int:
    """Steps of flight a leg takes besides its moves: the lead steps before its plan starts
    (climbing, or hovering) and the plan's first step, held in the start cell."""
    return lead_steps + 1


@dataclass(frozen=True)
class StackConfig:
    """What every drone of a fleet shares (immutable: copies of a simulated fleet share it)."""

    workspace: Workspace
    planner: SafePlanner
    battery: BatteryModel = field(default_factory=BatteryModel)
    low_mark: float = 40.0
    recharged_mark: float = 95.0
    lead_steps: int | None = None  #: steps between planning and a plan's start; default Delta + 1
    hover_lead_steps: int | None = None  #: the same for a drone in the air (at most ``lead_steps``); default that
    #: a task's plan is proposed at once, made against what the drone knows; off, every task asks first
    propose_at_once: bool = True

    def __deepcopy__(self, memo: dict[int, object]) -> StackConfig:
        return self


CUT_OFF = "cut off from most of the fleet"  #: why a drone out of touch with a majority hands its mail back
SERVICE_LOST = "out of touch with the service"  #: why a drone the service dispatches to hands its mail back

#: Legs that ask drones resting on their way to leave it; a drone going to park waits instead, unless it
#: leaves a charger (one waiting for that charger may be all that walls it in).
ASKING = frozenset({Phase.TO_PICKUP, Phase.TO_DROPOFF, Phase.TO_CHARGER})
