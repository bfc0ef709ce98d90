"""Puts gathered while a sample is handed round, sent as one message per key.

A subscription may *gather* (``ZenohNode.subscribe(..., gather=True)``): what the
session's nodes put while its sample is handed round goes out at the end, one
message per key (in runs of at most ``max_frames``, and split where joining would send a node's
put before one it made earlier). A request to everyone reaches every drone of a host at once;
their answers to the requester then cross the network, and its event loop, as
one message instead of one per drone (a put ``now`` goes at once: a key only one
node puts to gathers nothing). Payloads are framed with newlines (a
payload never contains one: :func:`~fleet.transport.wire.encode` writes
compact JSON), and every subscription hands each frame to its handlers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

FRAME_END = b"\n"  #: between the payloads of one Zenoh message


@dataclass
class Gathered:
    """Puts held while a sample is handed round: runs of puts to one key, sent in order. A put joins its
    key's newest run unless its node has put to a later run since (it would go out before that put)."""

    runs: list[tuple[str, list[bytes]]] = field(default_factory=list)
    newest: dict[str, int] = field(default_factory=dict)  #: key -> its newest run
    last: dict[str, int] = field(default_factory=dict)  #: node -> the run of its newest put
    sent: int = 0  #: the runs before this one are sent

    def add(self, node: str, key: str, payload: bytes) -> None:
        run = self.newest.get(key)
        if run is None or run < self.sent or self.last.get(node, -1) > run:
            run = self.newest[key] = len(self.runs)
            self.runs.append((key, []))
        self.runs[run][1].append(payload)
        self.last[node] = run

    def due(self, node: str | None = None) -> list[tuple[str, list[bytes]]]:
        """The runs not sent yet, in order: all, or (before ``node`` puts at once) up to its newest put's."""
        end = len(self.runs) if node is None else self.last.get(node, -1) + 1
        due, self.sent = self.runs[self.sent:end], max(self.sent, end)
        return due


def in_runs(parts: list[bytes], most: int | None) -> list[list[bytes]]:
    """``parts`` in runs of at most ``most`` (None: one run)."""
    step = most or len(parts)
    return [parts[first:first + step] for first in range(0, len(parts), step)]
