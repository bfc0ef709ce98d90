"""``drona mail``: give the fleet one mail over Zenoh, and with ``--wait`` follow it until delivered.

Without ``--drone`` the mail goes to the drone that can take it soonest (see
:mod:`drona_gcs.dispatch`). Progress lines go to stderr; stdout gets one JSON
line per status report (``{"id", "drone", "status", "step", "reason"}``), so
scripts can follow along. Exit codes: 0 accepted (with ``--wait``: delivered);
1 refused, rejected, failed or timed out; 2 bad arguments or no fleet.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
import uuid
from pathlib import Path

from drona_gcs.errors import DronaError
from fleet.cli.security import add_security_arguments, tls_dir_from
from fleet.transport.fleet_client import FleetClient
from fleet.transport.identity import SERVICE
from fleet.transport.keys import FleetKeys, check_name
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings, agent_endpoint
from fleet.transport.wire import MailOrder, MailStatus, MailStatusReport, WireError, checked, decode, to_json

#: With no endpoints given, look for the agents where `drona agent` listens by default on this machine.
DEFAULT_AGENTS = 16
FINAL = {MailStatus.DELIVERED: 0, MailStatus.REJECTED: 1, MailStatus.FAILED: 1, MailStatus.CANCELLED: 1}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add("--pickup", required=True, type=_cell, help="pickup cell X,Y,Z")
    add("--dropoff", required=True, type=_cell, help="drop-off cell X,Y,Z")
    add("--priority", required=True, type=_priority, help="0 (least urgent) to 9 (most)")
    add("--drone", help="give it to this drone (default: the one that can take it soonest)")
    add("--id", help="mail id (default: a random one); giving the same id again is not a second mail")
    add("--note", help="free text kept with the mail")
    add("--wait", action="store_true", help="follow the mail; exit 0 once it is delivered")
    add("--timeout", type=float, default=600.0, help="with --wait: give up after S seconds (default 600)")
    add("--fleet", default="default", help="fleet name (default 'default')")
    add("--connect", action="append", metavar="EP",
        help=f"Zenoh endpoint of an agent or router (default: tcp/127.0.0.1:7448..{7447 + DEFAULT_AGENTS})")
    add("--zenoh-config", type=Path, help="Zenoh JSON5 configuration file")
    add_security_arguments(parser)
    add("--discover-timeout", type=float, default=10.0, help="how long to wait for a drone to answer (default 10)")


def _cell(text: str) -> list[int]:
    parts = text.split(",")
    if len(parts) != 3 or not all(p.strip().lstrip("-").isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"a cell is X,Y,Z with three integers, got {text!r}")
    return [int(p) for p in parts]


def _priority(text: str) -> int:
    if not text.isdigit() or not 0 <= int(text) <= 9:
        raise argparse.ArgumentTypeError(f"priority must be an integer within 0..9, got {text!r}")
    return int(text)


def run(args: argparse.Namespace) -> int:
    try:
        check_name("fleet", args.fleet)
        if args.drone:
            check_name("drone", args.drone)
        mail_id = check_name("mail id", args.id) if args.id else f"m-{uuid.uuid4().hex[:12]}"
        order = checked(MailOrder, id=mail_id, pickup=args.pickup, dropoff=args.dropoff, priority=args.priority,
                        note=args.note)
        if args.pickup == args.dropoff:
            raise ValueError(f"pickup and drop-off are the same cell {args.pickup}")
        if not args.timeout > 0:
            raise ValueError(f"--timeout must be > 0, got {args.timeout}")
    except (ValueError, WireError) as exc:
        print(f"drona mail: {exc}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_mail(args, order))
    except DronaError as exc:  # no fleet answered, or the network could not be joined
        print(f"drona mail: {exc}", file=sys.stderr)
        return 2


async def _mail(args: argparse.Namespace, order: MailOrder) -> int:
    connect = tuple(args.connect or ()) or (
        () if args.zenoh_config else tuple(agent_endpoint(i) for i in range(DEFAULT_AGENTS)))
    keys = FleetKeys(args.fleet)
    settings = ZenohSettings(connect=connect, config_file=args.zenoh_config).secured(tls_dir_from(args), SERVICE,
                                                                                     keys, None)
    node = await ZenohNode.open(settings, "drona-mail")
    reports: asyncio.Queue[MailStatusReport] = asyncio.Queue()
    try:
        if args.wait:  # subscribe first: no report can slip by between the order and the subscription
            node.subscribe(keys.status(mail=order.id), lambda key, payload: _queue_report(reports, key, payload))
        client = FleetClient(node, keys, f"mail-{order.id}")
        ack = await client.dispatch(order, args.drone, args.discover_timeout)
        _emit({"id": order.id, "drone": ack.drone, "status": "accepted" if ack.accepted else "refused",
               "reason": ack.reason})
        if not ack.accepted:
            print(f"drona mail: drone {ack.drone} refused mail {order.id}: {ack.reason}", file=sys.stderr)
            return 1
        print(f"drona mail: {order.id} accepted by {ack.drone}", file=sys.stderr)
        if not args.wait:
            return 0
        return await _follow(order.id, reports, args.timeout)
    finally:
        await node.close()


def _queue_report(reports: asyncio.Queue[MailStatusReport], key: str, payload: bytes) -> None:
    try:
        envelope = decode(payload)
    except WireError:
        return
    body = envelope.body
    if isinstance(body, MailStatusReport) and body.drone == envelope.sender == FleetKeys.writer(key):
        reports.put_nowait(body)


async def _follow(mail_id: str, reports: asyncio.Queue[MailStatusReport], timeout: float) -> int:
    deadline = time.monotonic() + timeout
    while True:
        try:
            report = await asyncio.wait_for(reports.get(), max(0.0, deadline - time.monotonic()))
        except TimeoutError:
            print(f"drona mail: {mail_id} not delivered within {timeout:g} s", file=sys.stderr)
            return 1
        _emit(to_json(report))
        print(f"drona mail: {mail_id} {report.status.value} ({report.drone}, step {report.step})"
              f"{': ' + report.reason if report.reason else ''}", file=sys.stderr)
        if report.status in FINAL:
            return FINAL[report.status]


def _emit(record: dict[str, object]) -> None:
    print(json.dumps(record), flush=True)
