"""The operator's fleet commands: pause, resume, recall, land and release, each recorded with who asked.

``pause`` and ``resume`` go to the whole fleet, ``recall``, ``land`` and ``resume`` to one drone too;
``release`` goes to every live drone, about one that is gone (its vehicle seen out of the air).
The service stops handing out mail (the fleet paused, or a drone held) before it tells the drones,
and records every command with the drones' answers in the audit trail (table ``command``, made by
api.schema.MIGRATIONS).
What a drone does with each is :meth:`drona_gcs.stack.drone.DroneStack.command`'s: legs under way
are flown, mail on board is delivered, and a landed drone stops only through the protocol.
"""

from __future__ import annotations

import enum
import json
import sqlite3
import time
from dataclasses import dataclass

from pydantic import TypeAdapter

from api.dispatcher import Dispatcher
from api.events import EventBus
from api.gateway import CommandAck, FleetGateway
from api.store import Store


class Action(enum.Enum):
    PAUSE = "pause"
    RESUME = "resume"
    RECALL = "recall"
    LAND = "land"
    RELEASE = "release"


@dataclass(frozen=True)
class CommandRecord:
    """One command as the audit trail keeps it: ``drone`` None for the whole fleet."""

    n: int
    at: float  #: Unix seconds
    by: str
    action: Action
    drone: str | None
    acks: tuple[CommandAck, ...]


_RECORD_JSON = TypeAdapter(CommandRecord)


class FleetCommands:
    def __init__(self, store: Store, dispatcher: Dispatcher, fleet: FleetGateway, bus: EventBus) -> None:
        self.store, self.dispatcher, self.fleet, self.bus = store, dispatcher, fleet, bus

    async def run(self, action: Action, drone: str | None, by: str) -> CommandRecord:
        """Stop handing out mail, tell the drones, then record it all (durably); a resume takes effect
        once the drones heard it, so that mail handed out then is taken up."""
        if action is not Action.RESUME:
            self._apply(action, drone)
        if action is Action.RELEASE:
            acks = tuple(await self.fleet.command(None, action.value, by, about=drone))
            if drone is not None:
                await self.dispatcher.released(drone)
        else:
            acks = tuple(await self.fleet.command(drone, action.value, by))
        if action is Action.RESUME:
            self._apply(action, drone)
        at = time.time()
        n = await self.store.write(lambda conn: _insert(conn, at, by, action, drone, acks))
        record = CommandRecord(n, at, by, action, drone, acks)
        self.bus.publish("command", lambda: _RECORD_JSON.dump_json(record).decode())  # other operators' pages
        return record

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
        return [CommandRecord(n, at, by, Action(action), drone, tuple(CommandAck(**a) for a in json.loads(acks)))
                for n, at, by, action, drone, acks in rows]


def _insert(conn: sqlite3.Connection, at: float, by: str, action: Action, drone: str | None,
            acks: tuple[CommandAck, ...]) -> int:
    answers = json.dumps([{"drone": a.drone, "accepted": a.accepted, "reason": a.reason} for a in acks])
    cur = conn.execute("INSERT INTO command (at, by, action, drone, acks) VALUES (?, ?, ?, ?, ?)",
                       (at, by, action.value, drone, answers))
    assert cur.lastrowid is not None
    return cur.lastrowid
