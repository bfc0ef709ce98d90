"""Key expressions: everything a fleet says lives under ``drona/<fleet>/``.

=============================  =============================================
``alive/<drone>``              liveliness token: the drone is a member
``proto/<sender>/<drone>``     Protocol 1 messages to the drone (``proto/<sender>/all``: to every drone;
                               ``proto/<host>/<drone>``: from the drones of a host, joined)
``answers/<sender>``           one trajectory answering several drones' requests (each takes its own)
``state/<drone>``              the drone's state (published each step; queryable)
``plan/<drone>``               the drone's new plan, once made
``held/<drone>``               the mail the drone holds (published on change; queryable)
``mail/assign/<drone>``        query: give the drone a mail (reply: mail_ack)
``mail/cancel/<drone>``        query: drop a mail still waiting (reply: mail_ack)
``mail/status/<drone>/<mail>`` the drone's reports on a mail it holds
``clock/<drone>``              query: the drone's clock (offset estimation)
``command/<drone>``            query: an operator's command (pause, resume, recall, land)
=============================  =============================================

Whoever writes a key is named in it (``<sender>``, or the drone the key is of): the fleet's access
control (:mod:`fleet.transport.identity`) lets only that identity write there, and a receiver
checks that a message's sender is the key's (:meth:`FleetKeys.writer`), or a drone of the host that is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_NAME = re.compile(r"[A-Za-z0-9_.-]+\Z")  # \Z: "$" would let a final newline through


def check_name(what: str, name: str) -> str:
    """A fleet, drone or mail name usable as one chunk of a key expression."""
    if not _NAME.match(name):
        raise ValueError(f"{what} {name!r} must be letters, digits, '_', '.' or '-' (it is a Zenoh key chunk)")
    return name


@dataclass(frozen=True)
class FleetKeys:
    fleet: str = "default"

    def __post_init__(self) -> None:
        check_name("fleet", self.fleet)

    @property
    def root(self) -> str:
        return f"drona/{self.fleet}"

    def alive(self, drone: str = "*") -> str:
        return f"{self.root}/alive/{drone}"

    def service(self) -> str:
        """The service's liveliness token: drones it dispatches to hold its mail only while it is there."""
        return f"{self.root}/service"

    def proto(self, drone: str, sender: str = "*") -> str:
        return f"{self.root}/proto/{sender}/{drone}"

    def answers(self, sender: str = "*") -> str:
        return f"{self.root}/answers/{sender}"

    def state(self, drone: str = "*") -> str:
        return f"{self.root}/state/{drone}"

    def plan(self, drone: str = "*") -> str:
        return f"{self.root}/plan/{drone}"

    def held(self, drone: str = "*") -> str:
        return f"{self.root}/held/{drone}"

    def assign(self, drone: str) -> str:
        return f"{self.root}/mail/assign/{drone}"

    def cancel(self, drone: str) -> str:
        return f"{self.root}/mail/cancel/{drone}"

    def clear(self, drone: str) -> str:
        return f"{self.root}/mail/clear/{drone}"

    def status(self, drone: str = "*", mail: str = "*") -> str:
        return f"{self.root}/mail/status/{drone}/{mail}"

    def clock(self, drone: str = "*") -> str:
        return f"{self.root}/clock/{drone}"

    def command(self, drone: str = "*") -> str:
        return f"{self.root}/command/{drone}"

    def last_chunk(self, key: str) -> str:
        return key.rsplit("/", 1)[-1]

    @staticmethod
    def is_proto(key: str) -> bool:
        """Whether ``key`` carries Protocol 1 messages (``proto/<sender>/<to>``)."""
        return key.split("/")[2:3] == ["proto"]

    @staticmethod
    def writer(key: str) -> str:
        """Who may write ``key`` (of any fleet): its sender chunk, or the drone the key is of."""
        chunks = key.split("/")[2:]  # after drona/<fleet>/
        if chunks[:2] == ["mail", "status"] and len(chunks) == 4:
            return chunks[2]
        return chunks[1] if chunks[0] == "proto" and len(chunks) == 3 else chunks[-1]
