"""``drona serve``: the mail-request service and dashboard (FastAPI under uvicorn).

    drona serve --workspace ws.yaml --db drona.db --port 8000
    drona serve --workspace ws.yaml --demo                         # makes a token and prints it
    drona serve --workspace ws.yaml --demo --gateway simulated     # dev/test: an in-memory fake fleet

Settings not given as options come from ``DRONA_API_*`` (see :mod:`api.settings`).
Once the service is up it prints ``drona serve: listening on http://HOST:PORT`` on
stdout (``--port 0`` picks a free port). SIGINT or SIGTERM stop it cleanly (exit 0).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib
import logging
import socket
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import Any

import uvicorn

from drona_gcs.errors import DronaError
from drona_gcs.workspace import Workspace
from fleet import runtime
from fleet.cli.security import add_security_arguments, tls_dir_from

#: --gateway name -> "module:factory"; factory(workspace, args) -> FleetGateway. The first is the default.
GATEWAYS: dict[str, str] = {
    "zenoh": "fleet.transport.gateway:ZenohGateway",  # the agents over Zenoh
    "simulated": "tests.api.simulated:SimulatedGateway",  # dev/test only: a test double from the source checkout
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--workspace", help="workspace file (default: DRONA_API_WORKSPACE)")
    parser.add_argument("--db", help="SQLite database file (default: DRONA_API_DB or drona.db)")
    parser.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="port to listen on (default 8000; 0: any free port)")
    parser.add_argument("--demo", action="store_true", help="demo/dev mode: without a token, make one and print it")
    parser.add_argument("--token", help="in demo mode: the operator token to use (default: a random one), "
                        "besides those of DRONA_API_TOKENS and DRONA_API_TOKEN_FILE")
    parser.add_argument("--gateway", choices=sorted(GATEWAYS), default=next(iter(GATEWAYS)),
                        help="how to reach the drones; 'simulated' is an in-memory fake fleet for dev and tests")
    parser.add_argument("--sim-drones", type=int, help="simulated gateway: number of drones "
                        "(default: the workspace's drones, or 4)")
    parser.add_argument("--sim-step", type=float, default=0.2, help="simulated gateway: seconds per step (default 0.2)")
    parser.add_argument("--fleet", default="default", help="zenoh gateway: fleet name (default 'default')")
    parser.add_argument("--connect", action="append", metavar="EP", help="zenoh gateway: endpoint of an agent or "
                        "router (repeatable; default: where `drona agent` listens on this machine)")
    parser.add_argument("--zenoh-config", type=Path, help="zenoh gateway: Zenoh JSON5 configuration file")
    add_security_arguments(parser)
    parser.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        settings, token = _settings(args)
        workspace = _workspace(settings)
        gateway = _gateway(args, workspace)
    except (DronaError, ValueError) as exc:
        print(f"drona serve: {exc}", file=sys.stderr)
        return 2
    if token is not None:
        print(f"drona serve: demo operator token: {token}", flush=True)
    from api.main import create_app

    app = create_app(settings, gateway, workspace)
    runtime.settle_gc()  # FastAPI's routes, pydantic's validators and the workspace are built by now
    return runtime.run(_serve(app, settings.host, settings.port, args.log_level))


def _settings(args: argparse.Namespace) -> tuple[Any, str | None]:
    """The settings (options over environment) and, in demo mode without a token, the token made up."""
    from pydantic import ValidationError

    from api.auth import make_token
    from api.settings import ApiSettings

    given = {k: v for k, v in {"workspace": args.workspace, "db": args.db, "host": args.host,
                               "port": args.port}.items() if v is not None}
    if args.demo:
        given["demo"] = True
    made = None
    try:
        settings = ApiSettings(**given)
        if settings.demo and (args.token or not settings.token_table()):
            made = args.token or make_token()
            settings = _with_demo_token(settings, made)
        elif args.token:
            raise ValueError("--token is for demo mode (--demo); otherwise set DRONA_API_TOKENS")
    except ValidationError as exc:
        raise ValueError("; ".join(_setting_error(e) for e in exc.errors())) from None
    return settings, made


def _with_demo_token(settings: Any, token: str) -> Any:
    """The demo's operator token joins the configured ones (``DRONA_API_TOKENS``, ``DRONA_API_TOKEN_FILE``).

    Listed there already as an operator's, that entry stands, its name too (``drona demo --token T``
    in an environment that lists ``operator:T``); listed as a submitter's, it is a conflict.
    """
    known = settings.token_table().lookup(token)
    if known is None:
        return settings.model_copy(update={"tokens": f"{settings.tokens} operator:{token}:demo".strip()})
    if not known.is_operator:
        raise ValueError(f"--token is {known.name}'s submitter token in DRONA_API_TOKENS or DRONA_API_TOKEN_FILE; "
                         "the demo's token is an operator's: pass another one")
    return settings


def _setting_error(error: Any) -> str:
    where = ".".join(str(p) for p in error.get("loc", ())) or "settings"
    return f"{where}: {error.get('msg', 'invalid')}"


def _workspace(settings: Any) -> Workspace:
    from drona_gcs.workspace_files import load_workspace

    if settings.workspace is None:
        raise ValueError("no workspace: pass --workspace or set DRONA_API_WORKSPACE")
    return load_workspace(settings.workspace)


def _gateway(args: argparse.Namespace, workspace: Workspace) -> Any:
    module_name, factory = GATEWAYS[args.gateway].split(":")
    if args.gateway == "simulated":
        _source_checkout_on_path()
        drones = args.sim_drones if args.sim_drones is not None else (None if workspace.drones else 4)
        if args.sim_step <= 0:
            raise ValueError(f"--sim-step must be > 0, got {args.sim_step}")
        return getattr(importlib.import_module(module_name), factory)(workspace, drones, args.sim_step)
    args.tls_dir = tls_dir_from(args)
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ValueError(f"--gateway {args.gateway} is not available: {exc}") from exc
    return getattr(module, factory)(workspace, args)


def _source_checkout_on_path() -> None:
    """The simulated gateway is a test double living in tests/api/ of the source checkout."""
    root = Path(__file__).resolve().parents[2]
    if not (root / "tests" / "api" / "simulated.py").is_file():
        raise ValueError(f"--gateway simulated needs a source checkout: no tests/api/simulated.py under {root}")
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))


async def _serve(app: Any, host: str, port: int, log_level: str) -> int:
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        print(f"drona serve: cannot listen on {host}:{port}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    bound = sock.getsockname()[1]
    from api.main import MAX_HEAD_BYTES

    # h11, not httptools: httptools buffers a request head of any length; h11 closes once an incomplete head
    # outgrows the limit (a head that came whole: api.headlimit).
    config = uvicorn.Config(app, http="h11", h11_max_incomplete_event_size=MAX_HEAD_BYTES, log_level=log_level,
                            timeout_graceful_shutdown=1, access_log=False)
    server = _AnnouncingServer(config, f"http://{host}:{bound}", lambda: _end_streams(app))
    await server.serve(sockets=[sock])
    return 0


def _end_streams(app: Any) -> None:
    """Stopping: end the /v1/events streams, which would otherwise hold the shutdown up."""
    service = getattr(app.state, "service", None)
    if service is not None:
        service.bus.close()


class _AnnouncingServer(uvicorn.Server):
    """A uvicorn server that prints where it listens once it is up (tests wait for that line),
    ends the event streams when told to stop, and then exits 0."""

    def __init__(self, config: uvicorn.Config, url: str, on_exit: Callable[[], None]) -> None:
        super().__init__(config)
        self.url = url
        self.on_exit = on_exit

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        super().handle_exit(sig, frame)
        with contextlib.suppress(RuntimeError):  # no loop running: nothing to end
            asyncio.get_running_loop().call_soon_threadsafe(self.on_exit)

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        with super().capture_signals():
            yield
            self._captured_signals.clear()  # stopped cleanly on SIGINT/SIGTERM: exit 0, not by the signal

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        if not self.should_exit:
            print(f"drona serve: listening on {self.url}", flush=True)
