"""``drona router``: a Zenoh router (a Python session in router mode) for agents in client mode.

Agents configured as Zenoh clients (deploy/zenoh/client.json5) connect to it
and reach each other through it. Stops on SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
from pathlib import Path

from drona_gcs.errors import DronaError
from fleet.transport.node import DEFAULT_HOST, ROUTER_PORT, ZenohNode, ZenohSettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--listen", action="append", metavar="EP",
                        help=f"endpoint to listen on (repeatable; default tcp/{DEFAULT_HOST}:{ROUTER_PORT})")
    parser.add_argument("--connect", action="append", metavar="EP", help="another router to connect to")
    parser.add_argument("--zenoh-config", type=Path, help="Zenoh JSON5 configuration file")


def run(args: argparse.Namespace) -> int:
    listen = tuple(args.listen or ()) or (() if args.zenoh_config else (f"tcp/{DEFAULT_HOST}:{ROUTER_PORT}",))
    settings = ZenohSettings(mode="router", listen=listen, connect=tuple(args.connect or ()),
                             config_file=args.zenoh_config)
    try:
        asyncio.run(_serve(settings))
    except DronaError as exc:
        print(f"drona router: {exc}", file=sys.stderr)
        return 2
    return 0


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
