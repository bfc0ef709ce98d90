"""The wire's building blocks: its version, its error, the strict struct every message is, and the
cells, task ids and trajectories the messages carry."""

from __future__ import annotations

from typing import Annotated, Final

import msgspec

from drona_gcs.errors import DronaError
from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import TICK_LIMIT, TaskId

#: 2: a Zenoh message may carry several envelopes, one per line (fleet.transport.node);
#: 3: ``cur_traj_to``, one answer to several drones;
#: 4: ``req_traj`` carries the requester's trajectory (its answer to the drones before it in line);
#: 5: protocol messages carry ``holds``, the cells a drone whose vehicle is lost holds besides its trajectory;
#: 6: ``req_traj`` carries ``asked``, the peers its round waits for, and ``clear``, a way the requester
#: asks resting drones to leave; task ids carry the ``epoch`` (incarnation) of the agent that made them;
#: ``plan`` says ``grounded`` when a vehicle came down by itself;
#: 7: keys name their writer (``proto/<sender>/<to>``, ``answers/<sender>``, ``mail/status/<drone>/<mail>``).
#: 8: ``plan`` says ``braked``;
#: 9: ``propose``, ``ack`` and ``decide``: a plan is flown once every member holds it; ``plan`` says ``lost``.
#: 10: ``held`` lists mail handed back that no peer holds yet, and a status says ``handed_back``; ``refuse``.
#: 11: ``mail_clear``, the service's clearance to take a mail on board.
#: 13: a host's drones send to one drone on ``proto/<host>/<to>``, several messages in one.
#: 16: task ids carry their hybrid clock's ``tick``.
VERSION: Final = 16

CellList = Annotated[list[int], msgspec.Meta(min_length=3, max_length=3)]
#: A mail id is a Zenoh key chunk (mail/status/<id>); \Z, not $: "$" would let a final newline through.
MailId = Annotated[str, msgspec.Meta(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:-]+\Z")]
Priority = Annotated[int, msgspec.Meta(ge=0, le=9)]
#: A trajectory's cells are tuples as they come off the wire: a core Trajectory takes them as they are.
CellTuples = Annotated[tuple[tuple[int, int, int], ...], msgspec.Meta(min_length=1)]
Holds = tuple[tuple[int, int, int], ...]


class WireError(DronaError):
    """A payload that is not a valid message of this version."""


class WireStruct(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Every wire type: immutable, built by keyword, and no field it does not know (msgspec validates on
    decoding, strictly: no "12" for 12; a message built here is checked with :func:`checked`)."""


class WireBody(WireStruct, frozen=True, kw_only=True, tag_field="kind"):
    """An envelope's body, told apart by its ``kind``."""

    @property
    def kind(self) -> str:
        return str(type(self).__struct_config__.tag)


class WireTaskId(WireStruct, frozen=True, kw_only=True):
    stamp: int
    drone: str
    seq: int
    epoch: int = 0  #: the incarnation of the agent that made it
    tick: Annotated[int, msgspec.Meta(ge=0, le=TICK_LIMIT)] = 0  #: the hybrid clock's count within one stamp

    @classmethod
    def of(cls, task_id: TaskId) -> WireTaskId:
        return cls(stamp=task_id.stamp, drone=task_id.drone, seq=task_id.seq, epoch=task_id.epoch,
                   tick=task_id.tick)

    def core(self) -> TaskId:
        return TaskId(self.stamp, self.drone, self.seq, self.epoch, self.tick)


class WireTrajectory(WireStruct, frozen=True, kw_only=True):
    start_step: int
    cells: CellTuples

    @classmethod
    def of(cls, trajectory: Trajectory) -> WireTrajectory:
        return cls(start_step=trajectory.start_step, cells=trajectory.cells)

    def core(self) -> Trajectory:
        return Trajectory(self.start_step, self.cells)
