"""``drona router``: a Zenoh router (a Python session in router mode) for agents in client mode.

Agents configured as Zenoh clients (deploy/zenoh/client.json5) connect to it
and reach each other through it. Stops on SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import sys
from pathlib import Path

from drona_gcs.errors import DronaError
from drona_gcs.workspace_files import load_workspace
from fleet.cli.security import add_security_arguments, tls_dir_from
from fleet.transport.identity import ROUTER, IdentityError
from fleet.transport.keys import FleetKeys, check_name
from fleet.transport.node import ZenohNode
from fleet.transport.settings import DEFAULT_HOST, ROUTER_PORT, ZenohSettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", action="append", metavar="EP",
                        help=f"endpoint to listen on (repeatable; default tcp/{DEFAULT_HOST}:{ROUTER_PORT})")
    parser.add_argument("--connect", action="append", metavar="EP", help="another router to connect to")
    parser.add_argument("--zenoh-config", type=Path, help="Zenoh JSON5 configuration file")
    parser.add_argument("--lease", dest="lease_s", type=float,
                        help="Zenoh lease, s: a cut link is seen after it; keep it the agents' (default 10)")
    parser.add_argument("--workspace", type=Path, default=os.environ.get("DRONA_WORKSPACE"),
                        help="with --tls-dir: the fleet's workspace, whose drones the access control knows "
                             "[DRONA_WORKSPACE]")
    parser.add_argument("--fleet", default=os.environ.get("DRONA_FLEET", "default"),
                        help="fleet name (default 'default') [DRONA_FLEET]")
    add_security_arguments(parser)


def run(args: argparse.Namespace) -> int:
    listen = tuple(args.listen or ()) or (() if args.zenoh_config else (f"tcp/{DEFAULT_HOST}:{ROUTER_PORT}",))
    settings = ZenohSettings(mode="router", listen=listen, connect=tuple(args.connect or ()),
                             config_file=args.zenoh_config, lease_s=args.lease_s)
    try:
        settings = _secured(settings, args)
        asyncio.run(_serve(settings))
    except (DronaError, ValueError) as exc:
        print(f"drona router: {exc}", file=sys.stderr)
        return 2
    return 0


def _secured(settings: ZenohSettings, args: argparse.Namespace) -> ZenohSettings:
    tls_dir = tls_dir_from(args)
    if tls_dir is None:
        return settings
    if args.workspace is None:
        raise IdentityError("--tls-dir needs --workspace: the access control names the fleet's drones")
    drones = list(load_workspace(args.workspace).drones)
    return settings.secured(tls_dir, ROUTER, FleetKeys(check_name("fleet", args.fleet)), drones)


async def _serve(settings: ZenohSettings) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    node = await ZenohNode.open(settings, "router")
    print(f"drona router: listening on {', '.join(settings.listen) or 'the configured endpoints'}",
          file=sys.stderr, flush=True)
    try:
        await stop.wait()
    finally:
        await node.close()
