"""The operator's fleet commands: pause, resume, recall, land and release, each recorded with who asked.

``pause`` and ``resume`` go to the whole fleet, ``recall``, ``land`` and ``resume`` to one drone too;
``release`` goes to every live drone, about one that is gone (its vehicle seen out of the air).
The service stops handing out mail (the fleet paused, or a drone held) before it tells the drones,
and records every command in the audit trail (table ``command``, made by api.schema.MIGRATIONS) before
it takes effect, then the drones' answers: a command the database refused has done nothing.
What a drone does with each is :meth:`drona_gcs.stack.drone.DroneStack.command`'s: legs under way
are flown, mail on board is delivered, and a landed drone stops only through the protocol.
"""

from __future__ import annotations

import enum
import json
import logging
import sqlite3
import time
from dataclasses import dataclass
from typing import Any

from pydantic import TypeAdapter

from api.dispatcher import Dispatcher
from api.errors import StoreError
from api.events import EventBus
from api.gateway import CommandAck, FleetGateway
from api.store import Store

log = logging.getLogger(__name__)


class Action(enum.Enum):
    PAUSE = "pause"
    RESUME = "resume"
    RECALL = "recall"
    LAND = "land"
    RELEASE = "release"


@dataclass(frozen=True)
class CommandRecord:
    """One command as the audit trail keeps it: ``drone`` None for the whole fleet; ``answered`` False
    when the drones' answers were never stored (the service stopped, or the database failed, after the
    command was recorded)."""

    n: int
    at: float  #: Unix seconds
    by: str
    action: Action
    drone: str | None
    acks: tuple[CommandAck, ...]
    answered: bool = True


_RECORD_JSON = TypeAdapter(CommandRecord)


class FleetCommands:
    def __init__(self, store: Store, dispatcher: Dispatcher, fleet: FleetGateway, bus: EventBus) -> None:
        self.store, self.dispatcher, self.fleet, self.bus = store, dispatcher, fleet, bus

    async def run(self, action: Action, drone: str | None, by: str) -> CommandRecord:
        """Stop handing out mail and record the command (durably), then tell the drones and store their
        answers; a resume takes effect once the drones heard it, so that mail handed out then is taken up.
        A command the database refuses is undone before the drones hear of it."""
        before = (self.dispatcher.paused, frozenset(self.dispatcher.held))
        if action is not Action.RESUME:
            self._apply(action, drone)
        at = time.time()
        try:
            n = await self.store.write(lambda conn: _insert(conn, at, by, action, drone))
        except StoreError:
            self._restore(*before)
            raise
        if action is Action.RELEASE:
            acks = tuple(await self.fleet.command(None, action.value, by, about=drone))
            if drone is not None:
                await self._released(drone)
        else:
            acks = tuple(await self.fleet.command(drone, action.value, by))
        if action is Action.RESUME:
            self._apply(action, drone)
        record = CommandRecord(n, at, by, action, drone, acks, await self._store_answers(n, acks))
        self.bus.publish("command", lambda: _RECORD_JSON.dump_json(record).decode())  # other operators' pages
        return record

    def _restore(self, paused: bool, held: frozenset[str]) -> None:
        self.dispatcher.held.clear()
        self.dispatcher.held.update(held)
        self.dispatcher.hold(paused=paused)

    async def _released(self, drone: str) -> None:
        """The released drone's mail given up; the drones already heard the release, so a database
        failure here is logged, and the mail's deadline gives it up later."""
        try:
            await self.dispatcher.released(drone)
        except StoreError as exc:
            log.error("release of %s took effect, but its mail was not given up yet: %s", drone, exc)

    async def _store_answers(self, n: int, acks: tuple[CommandAck, ...]) -> bool:
        """Whether the answers were stored: the command has taken effect either way, so a failure here
        is logged, not raised, and the record says the answers are missing."""
        try:
            await self.store.write(lambda conn: conn.execute("UPDATE command SET acks = ? WHERE n = ?",
                                                             (_answers_json(acks), n)))
        except StoreError as exc:
            log.error("command %d took effect, but its answers were not stored: %s", n, exc)
            return False
        return True

    def restore(self) -> None:
        """After a restart: the fleet paused, and the drones held, as the recorded commands left them."""
        rows = self.store.read(lambda c: c.execute("SELECT action, drone FROM command ORDER BY n").fetchall())
        for action, drone in rows:
            self._apply(Action(action), drone)

    def _apply(self, action: Action, drone: str | None) -> None:
        """What ``action`` means for handing out mail."""
        if action is Action.RELEASE:
            return  # about a drone gone: it is handed nothing while it is gone anyway
        if action is Action.PAUSE:
            self.dispatcher.hold(paused=True)
        elif action is Action.RESUME and drone is None:
            self.dispatcher.held.clear()
            self.dispatcher.hold(paused=False)
        else:
            self.dispatcher.hold(drone=drone, held=action is not Action.RESUME)

    def history(self, limit: int) -> list[CommandRecord]:
        """The newest ``limit`` commands, newest first."""
        rows = self.store.read(lambda c: c.execute(
            "SELECT n, at, by, action, drone, acks FROM command ORDER BY n DESC LIMIT ?", (limit,)).fetchall())
        return [_record(n, at, by, Action(action), drone, json.loads(acks))
                for n, at, by, action, drone, acks in rows]


def _record(n: int, at: float, by: str, action: Action, drone: str | None,
            answers: list[dict[str, Any]] | None) -> CommandRecord:
    acks = tuple(CommandAck(**a) for a in answers or ())
    return CommandRecord(n, at, by, action, drone, acks, answered=answers is not None)


def _answers_json(acks: tuple[CommandAck, ...]) -> str:
    return json.dumps([{"drone": a.drone, "accepted": a.accepted, "reason": a.reason} for a in acks])


def _insert(conn: sqlite3.Connection, at: float, by: str, action: Action, drone: str | None) -> int:
    """The command, its answers not yet in (``acks`` is JSON null until :meth:`FleetCommands._store_answers`)."""
    cur = conn.execute("INSERT INTO command (at, by, action, drone, acks) VALUES (?, ?, ?, ?, 'null')",
                       (at, by, action.value, drone))
    assert cur.lastrowid is not None
    return cur.lastrowid
