"""``drona demo``: a working fleet in one command — service, agents and fake vehicles on this machine.

It starts ``drona sim-vehicle --count N`` (fake ArduCopters), ``drona agent
--count N`` (one Zenoh session per drone) and ``drona serve`` (the REST API and
the dashboard, dispatching over Zenoh), each in its own process, on an embedded
workspace unless ``--workspace`` names one. It prints the dashboard's URL and
the operator token, and stops everything cleanly on Ctrl-C: the agents finish
their plans and land, then the vehicles and the service stop. The children die
with the demo however it ends, ``kill -9`` included (:mod:`fleet.cli.lifeline`).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import os
import secrets
import shutil
import signal
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path

import yaml

from drona_gcs.errors import DronaError
from drona_gcs.geo import check_flyable
from drona_gcs.workspace import ARDUCOPTER, Workspace
from drona_gcs.workspace_files import load_workspace
from fleet.cli.lifeline import LEFTOVERS
from fleet.cli.security import add_security_arguments, tls_dir_from
from fleet.transport.identity import SERVICE, make_certs
from fleet.transport.settings import AGENT_BASE_PORT

DEMO_SIDE_X, DEMO_SIDE_Y = 16, 12
STOP_TIMEOUT_S = 90.0  #: the agents may need a plan's length to finish and land
DEMO_READY_AFTER_S = 8.0  #: shorter than a real SITL's 45 s: the dashboard shows the drones waiting, briefly


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add("--drones", type=int, default=8, help="drones (default 8; at most 16 on the embedded workspace)")
    add("--workspace", type=Path, help="workspace file (default: an embedded 16x12 campus)")
    add("--port", type=int, default=8000, help="the service's port (default 8000)")
    add("--host", default="127.0.0.1", help="the service's address (default 127.0.0.1)")
    add("--tau", type=float, help="seconds per step (default: the workspace's; 1.5 s on the embedded one, "
        "which its 3 m cells need at ArduCopter's default gains)")
    add("--speedup", type=float, default=1.0, help="the fake vehicles' simulated seconds per second (default 1)")
    add("--ready-after", type=float, default=DEMO_READY_AFTER_S,
        help="the fake vehicles' boot to their position estimate, simulated seconds (default "
             f"{DEMO_READY_AFTER_S:g}; ArduCopter SITL takes 45: the drones wait for it, taking no mail)")
    add("--db", type=Path, default=Path("drona-demo.db"), help="SQLite database file (default drona-demo.db)")
    add("--record", type=Path, help="write every drone's actual cell at every step here, as JSON Lines")
    add("--token", help="the operator token (default: a new random one, printed)")
    add("--autopilot", choices=["ardupilot", "px4"], default="ardupilot", help="fake vehicles' personality")
    add("--vehicle-port", type=int, default=14540, help="vehicle i talks MAVLink on UDP port (this + i)")
    add("--zenoh-port", type=int, default=AGENT_BASE_PORT, help="drone i's agent listens on TCP port (this + i)")
    add_security_arguments(parser)  # neither given: the demo makes a fleet CA and certificates of its own


#: An ArduCopter at its default gains flies a zigzag of 3 m cells 1.2 s late at this tau (1 s: ever later).
DEMO_TAU_S = 1.5


def demo_workspace(drones: int, tau: float, speedup: float = 1.0) -> dict[str, object]:
    """A small campus: two buildings, two chargers, drones parked along the west and east edges; its
    vehicles ArduCopters at their defaults, at ``speedup`` times real time."""
    if not 1 <= drones <= 16:
        raise ValueError(f"--drones must be within 1..16 on the embedded workspace, got {drones}")
    west = [(0, y) for y in range(1, DEMO_SIDE_Y, 2)]
    east = [(DEMO_SIDE_X - 1, y) for y in range(0, DEMO_SIDE_Y, 2)]
    spots = [cell for pair in zip(west, east, strict=True) for cell in pair] + [(7, 0), (2, 11), (9, 0), (5, 11)]
    homes = spots[:drones]
    return {
        "name": "demo-campus", "size": [DEMO_SIDE_X, DEMO_SIDE_Y, 1], "cell_size_m": 3.0, "tau_s": tau,
        "beta_s": 0.05, "vehicle": asdict(ARDUCOPTER.sped_up(speedup)),
        "geo_origin": {"lat": 47.397742, "lon": 8.545594, "alt_m": 488.0, "layer0_alt_m": 5.0},
        "obstacles": [{"box": [[4, 3, 0], [6, 5, 0]]}, {"box": [[9, 6, 0], [11, 8, 0]]}],
        "charging_stations": [[3, 0, 0], [12, DEMO_SIDE_Y - 1, 0]],
        "parking": [[x, y, 0] for x, y in homes],
        "drones": {f"d{i + 1}": [x, y, 0] for i, (x, y) in enumerate(homes)},
    }


def run(args: argparse.Namespace) -> int:
    try:
        _check(args)
        state = Path(tempfile.mkdtemp(prefix="drona-demo-"))
        workspace_file = _workspace_file(args, state)
        workspace = load_workspace(workspace_file)
        check_flyable(workspace)
        drones = len(workspace.drones) if args.workspace else args.drones
        security = _security(args, workspace, state)
    except (ValueError, DronaError, OSError) as exc:
        print(f"drona demo: {exc}", file=sys.stderr)
        return 2
    token = args.token or secrets.token_urlsafe(18)
    try:
        return asyncio.run(_demo(args, workspace_file, drones, token, state, security))
    except DronaError as exc:
        print(f"drona demo: {exc}", file=sys.stderr)
        return 1


def _check(args: argparse.Namespace) -> None:
    if args.speedup <= 0:
        raise ValueError(f"--speedup must be > 0, got {args.speedup}")
    if not args.ready_after > 0:
        raise ValueError(f"--ready-after must be > 0, got {args.ready_after}")
    if args.tau is not None and args.tau <= 0:
        raise ValueError(f"--tau must be > 0, got {args.tau}")
    if not 0 < args.port < 65536:
        raise ValueError(f"--port must be within 1..65535, got {args.port}")


def _security(args: argparse.Namespace, workspace: Workspace, state: Path) -> list[str]:
    """The children's security flags: the certificates given, or made for this demo; or --insecure."""
    if args.insecure or args.tls_dir is not None:
        tls_dir = tls_dir_from(args)
        return ["--insecure"] if tls_dir is None else ["--tls-dir", str(tls_dir)]
    make_certs(state / "tls", [*workspace.drones, SERVICE])
    return ["--tls-dir", str(state / "tls")]


def _workspace_file(args: argparse.Namespace, state: Path) -> Path:
    """The workspace to fly, as a file the children can read (--tau applied)."""
    if args.workspace is None:
        data = demo_workspace(args.drones, args.tau or DEMO_TAU_S, args.speedup)
    elif args.tau is None:
        given: Path = args.workspace
        return given
    elif args.workspace.suffix.lower() in (".yaml", ".yml", ".json"):
        data = yaml.safe_load(args.workspace.read_text())
        data["tau_s"] = args.tau
    else:
        raise ValueError(f"--tau applies to YAML or JSON workspaces; set tau in {args.workspace} instead")
    path = state / "workspace.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


async def _demo(args: argparse.Namespace, workspace: Path, drones: int, token: str, state: Path,
                security: list[str]) -> int:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    # A watched pipe, not prctl(PR_SET_PDEATHSIG): that signal fires when the *thread* that forked
    # exits, needs a preexec_fn (unsafe with threads), races with a launcher dying before the
    # child's prctl, and is Linux-only. The pipe's EOF comes when this process ends, however and
    # whenever, even before a child starts reading. The write end is not inherited (PEP 446).
    lifeline, held = os.pipe()
    try:
        return await _fly(args, workspace, drones, token, state, lifeline, stop, security)
    finally:
        os.close(lifeline)
        os.close(held)  # children still running (started, then the demo failed) go


async def _fly(args: argparse.Namespace, workspace: Path, drones: int, token: str, state: Path,
               lifeline: int, stop: asyncio.Event, security: list[str]) -> int:
    ws = ["--workspace", str(workspace)]
    start = functools.partial(_start, (lifeline, state))
    vehicles = await start("sim-vehicle", *ws, "--count", str(drones), "--speedup", str(args.speedup),
                            "--autopilot", args.autopilot, "--base-port", str(args.vehicle_port),
                            "--ready-after", str(args.ready_after))
    zenoh = f"tcp/127.0.0.1:{args.zenoh_port}"
    agent_args = [*ws, "--count", str(drones), "--no-adopt-mail", "--vehicle-base-port", str(args.vehicle_port),
                  "--listen", zenoh, "--connect", zenoh, *security]
    if args.record:
        agent_args += ["--record", str(args.record)]
    agents = await start("agent", *agent_args, stderr=asyncio.subprocess.PIPE)
    service = await start("serve", *ws, "--demo", f"--token={token}", "--db", str(args.db),
                           "--host", args.host, "--port", str(args.port), "--connect", zenoh, *security,
                           stdout=asyncio.subprocess.PIPE)
    children = {"service": service, "agents": agents, "vehicles": vehicles}
    try:
        async with asyncio.TaskGroup() as group:
            url = await _wait_for(service.stdout, "listening on ", "the service")
            flying = url and await _wait_for(agents.stderr, " flying (fleet ", "the agents")
            if not url or not flying:
                return 1
            for stream in (service.stdout, agents.stderr):
                group.create_task(_pass_through(stream))  # ends when its process does
            print(f"drona demo: {drones} drones flying; dashboard {url}/  (token {token})\n"
                  f"drona demo: mail: curl -H 'Authorization: Bearer {token}' -H 'Content-Type: application/json' "
                  f"-d '{{\"pickup\": [2, 2, 0], \"dropoff\": [13, 9, 0], \"priority\": 5}}' {url}/v1/mail\n"
                  f"drona demo: Ctrl-C stops everything (the drones land first)", flush=True)
            await _until_stop_or_exit(stop, children)
            await _stop_all(children)
    finally:
        await _stop_all(children)
        shutil.rmtree(state, ignore_errors=True)
    failed = {name: p.returncode for name, p in children.items() if p.returncode not in (0, None)}
    if failed:
        print(f"drona demo: exit codes {failed}", file=sys.stderr)
    return 1 if failed and not stop.is_set() else 0


async def _start(lifeline: tuple[int, Path], command: str, *arguments: str, stdout: int | None = None,
                 stderr: int | None = None) -> asyncio.subprocess.Process:
    """``drona command arguments...``, dying with the demo (``lifeline``: the pipe's read end, and the
    demo's state folder, which the children remove should the demo die without doing so)."""
    fd, state = lifeline
    # Own session: a Ctrl-C in the terminal reaches the demo only, which stops the children in order;
    # and each child leads its own process group, which its lifeline kills whole.
    env = {**os.environ, "PYTHONUNBUFFERED": "1", LEFTOVERS: str(state)}
    return await asyncio.create_subprocess_exec(sys.executable, "-m", "fleet.cli.lifeline", str(fd), command,
                                                *arguments, stdout=stdout, stderr=stderr, start_new_session=True,
                                                pass_fds=(fd,), env=env)


async def _wait_for(stream: asyncio.StreamReader | None, marker: str, who: str) -> str | None:
    """What follows ``marker`` on the first line that has it (earlier lines are passed through)."""
    assert stream is not None
    while line := await stream.readline():
        text = line.decode(errors="replace").rstrip()
        if marker in text:
            return text.rsplit(marker, 1)[1]
        if "token" not in text:  # the demo prints the token itself, once
            print(text, flush=True)
    print(f"drona demo: {who} stopped before starting up", file=sys.stderr)
    return None


async def _pass_through(stream: asyncio.StreamReader | None) -> None:
    assert stream is not None
    while line := await stream.readline():
        sys.stdout.write(line.decode(errors="replace"))


async def _until_stop_or_exit(stop: asyncio.Event, children: dict[str, asyncio.subprocess.Process]) -> None:
    """Until Ctrl-C, or until a child exits on its own (then everything stops)."""
    waiters = {asyncio.ensure_future(p.wait()): name for name, p in children.items()}
    stopper = asyncio.ensure_future(stop.wait())
    try:
        done, _ = await asyncio.wait({*waiters, stopper}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in [*waiters, stopper]:
            task.cancel()
    for task in done:
        if task in waiters:
            print(f"drona demo: the {waiters[task]} stopped (exit {children[waiters[task]].returncode}); "
                  "stopping the rest", file=sys.stderr)


async def _stop_all(children: dict[str, asyncio.subprocess.Process]) -> None:
    """Agents first (they finish their plans and land), then the vehicles and the service."""
    for group in (["agents"], ["vehicles", "service"]):
        for name in group:
            if children[name].returncode is None:
                with contextlib.suppress(ProcessLookupError):
                    children[name].send_signal(signal.SIGINT)
        for name in group:
            try:
                await asyncio.wait_for(children[name].wait(), STOP_TIMEOUT_S)
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    children[name].kill()
                await children[name].wait()
