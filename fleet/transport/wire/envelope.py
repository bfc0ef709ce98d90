"""The envelope every payload is, its encoding and strict decoding, and the bounds a peer's message must
keep in this workspace."""

from __future__ import annotations

import collections
import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Final, Literal, TypeVar

import msgspec

from drona_gcs.stack.messages import TICK_LIMIT
from fleet.transport.wire.base import VERSION, WireError, WireStruct, WireTaskId, WireTrajectory
from fleet.transport.wire.protocol import Ack, CurTraj, CurTrajTo, Decide, PlanAnnounce, Propose, Refuse, ReqTraj
from fleet.transport.wire.queries import (
    ClockPing,
    ClockPong,
    CommandAck,
    FleetCommand,
    MailAck,
    MailCancel,
    MailClear,
    MailOrder,
    MailStatusReport,
)
from fleet.transport.wire.state import DroneState, HeldMail

Body = (ReqTraj | CurTraj | CurTrajTo | Propose | Ack | Refuse | Decide | PlanAnnounce | DroneState | HeldMail
        | MailOrder | MailCancel | MailClear | MailAck | MailStatusReport | ClockPing | ClockPong | FleetCommand
        | CommandAck)


class Envelope(WireStruct, frozen=True, kw_only=True):
    v: Literal[16] = VERSION
    sender: Annotated[str, msgspec.Meta(min_length=1)]
    sent_at: float
    body: Body


_ENCODER = msgspec.json.Encoder()
_DECODER = msgspec.json.Decoder(Envelope)


#: How far ahead of the receiver's step a task id's stamp may be. Stamps are the largest step a sender has
#: seen (a hybrid clock): within the fleet's skew; a stamp far beyond would drag every clock it reaches.
STAMP_AHEAD_STEPS: Final = 1000

#: Envelopes decoded, and bodies found within bounds, remembered for the drones of a process.
REMEMBERED: Final = 256


@dataclass(frozen=True)
class PeerBounds:
    """What a peer's protocol message or plan may carry in this workspace: cells inside it,
    trajectories no plan here can outgrow (a plan and the one it was spliced onto, each at most
    L_max long: twice that again for margin), task ids not far ahead of our clock."""

    size: tuple[int, int, int]
    max_cells: int

    @classmethod
    def of(cls, size: tuple[int, int, int], plan_length_limit: int) -> PeerBounds:
        return cls(size, 4 * (plan_length_limit + 1))

    def check(self, body: Body, now: int) -> None:
        """:class:`WireError` naming what is out of bounds. A body found within them is remembered: the
        drones of a process share each envelope decoded (see decode), and a later step cannot put it out."""
        seen = _WITHIN.get(id(body))
        if seen is not None and seen[0] is body and seen[1] == self and seen[2] <= now:
            return
        self._check(body, now)
        _WITHIN[id(body)] = (body, self, now)  # the body kept here keeps its id from being reused
        if len(_WITHIN) > REMEMBERED:
            _WITHIN.popitem(last=False)

    def _check(self, body: Body, now: int) -> None:
        for trajectory in (getattr(body, "trajectory", None), getattr(body, "current", None)):
            if isinstance(trajectory, WireTrajectory):
                if len(trajectory.cells) > self.max_cells:
                    raise WireError(f"a trajectory of {len(trajectory.cells)} cells: no plan here has more than "
                                    f"{self.max_cells}")
                self._inside(trajectory.cells)
        self._inside((*getattr(body, "holds", ()), *getattr(body, "clear", ())))
        if isinstance(body, Refuse):
            for drone, cells in body.gone.items():
                if len(cells) > self.max_cells:
                    raise WireError(f"{len(cells)} cells held for {drone!r}: no plan here has more than "
                                    f"{self.max_cells}")
                self._inside(cells)
        for task_id in _task_ids(body):
            stamp = task_id.stamp + (task_id.tick >= TICK_LIMIT)  # a clock that saw it moves its stamp on
            if stamp > now + STAMP_AHEAD_STEPS:
                raise WireError(f"task id stamp {stamp} is {stamp - now} steps ahead of this "
                                f"clock (at most {STAMP_AHEAD_STEPS})")

    def _inside(self, cells: Sequence[tuple[int, int, int]]) -> None:
        width, depth, height = self.size
        for cell in cells:
            x, y, z = cell
            if not (0 <= x < width and 0 <= y < depth and 0 <= z < height):
                raise WireError(f"cell {list(cell)} is outside the {'x'.join(map(str, self.size))} workspace")


_WITHIN: collections.OrderedDict[int, tuple[Body, PeerBounds, int]] = collections.OrderedDict()


def _task_ids(body: Body) -> list[WireTaskId]:
    if isinstance(body, (Decide, Propose)):
        return [body.task_id, *body.replies.values()]
    if isinstance(body, (ReqTraj, Ack, Refuse)):
        return [body.task_id]
    if isinstance(body, CurTraj):
        return [body.in_reply_to]
    if isinstance(body, CurTrajTo):
        return list(body.replies.values())
    return []


def encode(sender: str, sent_at: float, body: Body) -> bytes:
    return _ENCODER.encode(Envelope(sender=sender, sent_at=sent_at, body=body))


@functools.lru_cache(maxsize=REMEMBERED)
def decode(payload: bytes) -> Envelope:
    """The envelope in ``payload``; :class:`WireError` naming what is wrong otherwise.

    Remembered for the last few payloads: a message to everyone reaches every drone of a
    process as the same bytes (one Zenoh subscriber per process), and validating it once is
    enough. The drones then share one envelope: it is frozen, and its lists (cells, mail)
    must not be changed in place either.
    """
    try:
        return _DECODER.decode(payload)
    except msgspec.DecodeError as exc:  # its ValidationError too: msgspec names the field ("at `$.body.id`")
        raise WireError(f"malformed message: {exc}") from exc
    except UnicodeDecodeError as exc:  # msgspec before 0.23 lets a string that is not UTF-8 through as this
        raise WireError(f"malformed message: not UTF-8: {exc.reason} at byte {exc.start}") from exc


T = TypeVar("T", bound=WireStruct)


def decode_as(payload: bytes, kind: type[T], what: str) -> T:
    """The body of ``payload``, which must be a ``kind`` (``what``, in the error); :class:`WireError`
    naming what is wrong otherwise."""
    body = decode(payload).body
    if not isinstance(body, kind):
        raise WireError(f"expected {what}, got {body.kind}")
    return body


def checked(kind: type[T], /, **fields: Any) -> T:
    """A message built from ``fields`` and validated as if it had come over the wire (building one by
    hand checks nothing); :class:`WireError` naming what is wrong (a mail order typed by an operator)."""
    try:
        return msgspec.convert(fields, kind)
    except msgspec.ValidationError as exc:
        raise WireError(f"{exc}") from exc


def to_json(message: WireStruct) -> dict[str, Any]:
    """``message`` as plain JSON values (a body without its ``kind``)."""
    record: dict[str, Any] = msgspec.to_builtins(message)
    record.pop("kind", None)
    return record
