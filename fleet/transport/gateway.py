"""The service's way to the fleet over Zenoh: :class:`api.gateway.FleetGateway` for real agents.

It is one outside session on the fleet (like ``drona mail``): it follows every
drone's state, the mail status reports and the liveliness tokens, hands them
to the service's listener on the event loop, and gives or cancels mail with the
agents' queries. Reports are translated to the service's vocabulary: a
mail ``reassigned`` to a drone's heir is ``accepted`` by that drone.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from api.errors import AssignRefused
from api.gateway import CommandAck as GatewayAck
from api.gateway import DroneView, FleetListener, Health, MailOrder, MailStatusReport, Position, TaskView, VehicleInfo
from api.gateway import TrajectoryView as View
from drona_gcs.geo import GeoFrame
from drona_gcs.workspace import Cell, Workspace
from fleet.transport.fleet_client import QUERY_TIMEOUT_S, FleetClient, FleetUnavailable
from fleet.transport.identity import SERVICE
from fleet.transport.keys import FleetKeys
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings, agent_endpoint
from fleet.transport.wire import (
    CommandAck,
    CommandAction,
    DroneState,
    FleetCommand,
    MailCancel,
    MailClear,
    MailStatus,
    VehicleView,
    WireError,
    decode,
    encode,
)
from fleet.transport.wire import MailOrder as WireOrder
from fleet.transport.wire import MailStatusReport as WireReport

log = logging.getLogger(__name__)

#: Agent report -> the service's status (None: not the service's business).
STATUS: dict[MailStatus, str | None] = {
    MailStatus.ACCEPTED: "accepted", MailStatus.STARTED: "started", MailStatus.PICKED_UP: "picked_up",
    MailStatus.DELIVERED: "delivered", MailStatus.REJECTED: "rejected", MailStatus.FAILED: "failed",
    MailStatus.REASSIGNED: "accepted", MailStatus.CANCELLED: None,
    MailStatus.HANDED_BACK: "rejected",  #: sent only with no service; here, the service reassigns it
}


class ZenohGateway:
    def __init__(self, workspace: Workspace, args: argparse.Namespace) -> None:
        self.workspace, self.frame = workspace, GeoFrame(workspace)
        self.keys = FleetKeys(getattr(args, "fleet", None) or "default")
        connect = tuple(getattr(args, "connect", None) or ())
        config: Path | None = getattr(args, "zenoh_config", None)
        if not connect and config is None:  # on one machine: where `drona agent` listens by default
            connect = tuple(agent_endpoint(i) for i in range(len(workspace.drones)))
        tls_dir: Path | None = getattr(args, "tls_dir", None)
        self.settings = ZenohSettings(connect=connect, config_file=config).secured(
            tls_dir, SERVICE, self.keys, list(workspace.drones))
        self.listener: FleetListener | None = None
        self.views: dict[str, DroneView] = {}
        self.node: ZenohNode | None = None
        self.ready = asyncio.Event()

    def listen(self, listener: FleetListener) -> None:
        self.listener = listener

    async def run(self) -> None:
        node = self.node = await ZenohNode.open(self.settings, "drona-serve")
        try:
            node.subscribe(self.keys.state(), self._on_state)
            node.subscribe(self.keys.status(), self._on_report)
            node.watch_liveliness(self.keys.alive(), self._on_liveliness)
            node.token(self.keys.service())  # drones hold the mail it gave only while they see it
            self.ready.set()
            await asyncio.Event().wait()  # until cancelled: everything else comes through the callbacks
        finally:
            self.ready.clear()
            self.node = None
            await node.close()

    def is_open(self) -> bool:
        return self.ready.is_set() and self.node is not None and self.node.linked()

    async def assign(self, drone: str, mail: MailOrder) -> None:
        client = await self._client()
        order = WireOrder(id=mail.id, pickup=list(mail.pickup), dropoff=list(mail.dropoff), priority=mail.priority,
                          note=mail.note or None)
        try:
            ack = await client.assign(drone, order)
        except FleetUnavailable as exc:
            raise AssignRefused(drone, mail.id, str(exc)) from exc
        if not ack.accepted:
            raise AssignRefused(drone, mail.id, ack.reason)

    async def cancel(self, drone: str, mail_id: str) -> None:
        with contextlib.suppress(Exception):  # best effort: the drone may be gone
            node = (await self._client()).node
            await node.get(self.keys.cancel(drone), encode("drona-serve", 0.0, MailCancel(id=mail_id)),
                           QUERY_TIMEOUT_S)

    async def clear(self, drone: str, mail_id: str) -> None:
        with contextlib.suppress(Exception):  # best effort: the drone may be gone
            node = (await self._client()).node
            await node.get(self.keys.clear(drone), encode("drona-serve", 0.0, MailClear(id=mail_id)),
                           QUERY_TIMEOUT_S)

    async def command(self, drone: str | None, action: str, by: str, about: str | None = None) -> list[GatewayAck]:
        node = (await self._client()).node
        order = encode(SERVICE, time.time(), FleetCommand(action=CommandAction(action), by=by, about=about))
        replies = await node.get(self.keys.command(drone or "*"), order, QUERY_TIMEOUT_S, block=True)
        acks: list[GatewayAck] = []
        for reply in replies:
            try:
                envelope = decode(reply.payload)
            except WireError as exc:
                log.warning("dropped a command answer on %s: %s", reply.key, exc)
                continue
            body = envelope.body
            if isinstance(body, CommandAck) and body.drone == envelope.sender == self.keys.writer(reply.key):
                acks.append(GatewayAck(body.drone, body.accepted, body.reason))
        return sorted(acks, key=lambda a: a.drone)

    def drones(self) -> Mapping[str, DroneView]:
        return dict(self.views)

    async def _client(self) -> FleetClient:
        await self.ready.wait()
        if self.node is None:
            raise AssignRefused("?", "?", "the gateway is closed")
        return FleetClient(self.node, self.keys, "drona-serve")

    # ------------------------------------------------------------ inbound
    def _on_state(self, key: str, payload: bytes) -> None:
        try:
            body = decode(payload).body
        except WireError as exc:
            log.warning("dropped a state on %s: %s", key, exc)
            return
        if not isinstance(body, DroneState) or body.drone not in self.workspace.drones:
            return
        if body.drone != self.keys.writer(key):
            log.warning("dropped %s's state on %s: not its key", body.drone, key)
            return
        view = self._view(body)
        self.views[view.id] = view
        if self.listener is not None:
            self.listener.on_drone_state(view)

    def _on_report(self, key: str, payload: bytes) -> None:
        try:
            envelope = decode(payload)
        except WireError as exc:
            log.warning("dropped a mail report on %s: %s", key, exc)
            return
        body = envelope.body
        if not isinstance(body, WireReport):
            return
        if not body.drone == envelope.sender == self.keys.writer(key):
            log.warning("dropped a report on %s from %r about %s's mail: only a drone reports its own", key,
                        envelope.sender, body.drone)
            return
        status = STATUS[body.status]
        if status is not None and self.listener is not None:
            self.listener.on_mail_status(MailStatusReport(body.id, body.drone, status, body.reason,  # type: ignore[arg-type]
                                                          body.step, envelope.sent_at))

    def _on_liveliness(self, key: str, alive: bool) -> None:
        drone = self.keys.last_chunk(key)
        if not alive and drone in self.views:
            del self.views[drone]
            if self.listener is not None:
                self.listener.on_drone_lost(drone)

    def _view(self, state: DroneState) -> DroneView:
        cell = _cell(state.cell)
        if state.position is not None:
            lat, lon, alt = state.position
        else:  # no fix yet: the centre of the cell the drone holds
            centre = self.frame.cell_to_global(cell)
            lat, lon, alt = centre.lat, centre.lon, centre.alt_m
        task = (TaskView(_cell(state.task.goal), state.task.purpose, state.task.mail_id)
                if state.task is not None else None)
        trajectory = (View(state.trajectory.start_step, tuple(_cell(c) for c in state.trajectory.cells))
                      if state.trajectory is not None else None)
        return DroneView(
            id=state.drone, cell=cell, position=Position(lat, lon, alt),
            battery_pct=state.battery_pct if state.battery_pct is not None else 100.0, mode=state.mode,
            phase=state.phase, task=task, trajectory=trajectory,
            queue=tuple(m.id for m in state.mail if m.stage != "carrying"),
            carrying=next((m.id for m in state.mail if m.stage == "carrying"), None),
            health=Health(state.health.ok, tuple(state.health.alarms)), step=state.step,
            vehicle=_vehicle(state.vehicle), coordination_ms=state.coordination_ms)


def _vehicle(v: VehicleView | None) -> VehicleInfo | None:
    if v is None:
        return None
    return VehicleInfo(status=v.status, reason=v.reason, mode=v.mode, armed=v.armed, landed=v.landed,
                       height_m=v.height_m, gps_fix=v.gps_fix, satellites=v.satellites, battery_v=v.battery_v)


def _cell(values: Sequence[int]) -> Cell:
    return (values[0], values[1], values[2])
