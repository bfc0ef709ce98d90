"""``drona sim-vehicle``: fake MAVLink quadrotors that behave like ArduCopter or PX4 SITL.

Vehicle ``i`` (system id ``i + 1``; ArduPilot: 1, as every SITL instance) starts under drone ``i``'s
start cell of ``--workspace``; ``--instance N`` starts from vehicle ``N`` (SITL's ``-I``), so that
each vehicle may run in its own process and die alone.
Over UDP (the default, as PX4 SITL) it sends to a ground station listening on
``--host``:(14540 + i); with ``--tcp`` (as ArduPilot SITL) it listens on (5760 + 10 i).
``--base-port`` moves either range. With ``--serial`` each vehicle is on a serial line
instead, a pseudo-terminal that behaves like a UART at ``--baud`` (as a flight controller
wired to a companion computer, or behind a telemetry radio): it prints the device to open,
for example ``drona agent --vehicle serial:///dev/pts/3:57600``, and on exit how much of the
telemetry the line had no room for, if any. Stops cleanly on SIGINT or SIGTERM (exit 0).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import signal
import sys
from dataclasses import replace
from pathlib import Path
from typing import TextIO

from drona_gcs.errors import DronaError
from drona_gcs.geo import GeoFrame, check_speed
from drona_gcs.workspace import Workspace
from drona_gcs.workspace_files import load_workspace
from fleet import runtime
from fleet.sim.config import VehicleConfig
from fleet.sim.fleet import FleetConfig, SimNode, run_fleet
from fleet.sim.params import ParamStore, limit_params, starting_limits
from fleet.sim.personality import PERSONALITIES
from fleet.sim.transport import PtyLink
from fleet.sim.truth import TruthRecord
from fleet.vehicle.signing import parse_key
from fleet.vehicle.urls import DEFAULT_BAUD


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--workspace",
                        help="workspace file: vehicle i starts at drone i's start cell, set to its vehicle limits")
    parser.add_argument("--count", type=int, default=1, help="number of vehicles (default 1)")
    parser.add_argument("--instance", type=int, default=0,
                        help="the first vehicle's instance, as SITL's -I: vehicle i of this process is the "
                             "workspace's drone (instance + i), on that one's port (default 0)")
    parser.add_argument("--autopilot", choices=sorted(PERSONALITIES), default="ardupilot",
                        help="personality: modes, results and streams of ArduCopter or PX4 (default ardupilot)")
    link = parser.add_mutually_exclusive_group()
    link.add_argument("--tcp", action="store_true", help="TCP servers as ArduPilot SITL (default: UDP as PX4 SITL)")
    link.add_argument("--serial", action="store_true",
                      help="each vehicle on a serial line, a pseudo-terminal whose device it prints (Linux)")
    parser.add_argument("--baud", type=int,
                        help="with --serial: the line's baud rate, 10 bits a byte (default 57600, a telemetry radio)")
    parser.add_argument("--host", default="127.0.0.1", help="address to use (default 127.0.0.1)")
    parser.add_argument("--base-port", type=int, help="first port (default 14540 for UDP, 5760 for TCP)")
    parser.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per wall-clock second")
    parser.add_argument("--ready-after", type=float,
                        help="simulated seconds from boot to a position estimate, arming refused before (default: "
                             "as the autopilot's SITL, ArduCopter 41.5, PX4 15; may be shortened, not switched off)")
    parser.add_argument("--spool-up", type=float,
                        help="simulated seconds from an accepted take-off to leaving the ground (default: ArduCopter "
                             "3.5, PX4 1)")
    parser.add_argument("--auto-disarm", type=float,
                        help="seconds armed on the ground without takeoff before disarming itself: the starting "
                             "DISARM_DELAY or COM_DISARM_PRFLT/COM_DISARM_LAND (default: the autopilot's, 10; PX4 "
                             "2 after a landing)")
    parser.add_argument("--max-speed", type=float,
                        help="horizontal speed limit, m/s of simulated time: the starting WPNAV_SPEED or "
                             "MPC_XY_VEL_MAX, which a ground station may change (default: the workspace's, else "
                             "the autopilot's, ArduCopter 10, PX4 12)")
    parser.add_argument("--battery", type=float, default=100.0, help="initial battery charge, percent")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="a parameter's starting value, as set by hand on a real vehicle (repeat for more), "
                             "e.g. PSC_JERK_XY=10: ArduCopter closes in on a setpoint at jerk / (2 WPNAV_ACCEL)")
    parser.add_argument("--signing-key", help="MAVLink 2 signing key, 64 hex digits: unsigned commands are ignored")
    parser.add_argument("--record", type=Path,
                        help="with --workspace: write where each vehicle really was at each step here (JSON Lines, "
                             "for drona audit; the agents' own records show what their telemetry said)")
    parser.add_argument("--epoch", type=float, default=0.0,
                        help="the fleet epoch for --record, Unix seconds: step k starts at epoch + k tau (default 0)")


def run(args: argparse.Namespace) -> int:
    try:
        workspace: Workspace | None = load_workspace(args.workspace) if args.workspace else None
        config = _config(args, workspace)
        if workspace is not None:  # a cell per tau must be within what the vehicles can fly
            check_speed(workspace, starting_limits(config.vehicle).max_speed * args.speedup)  # simulated s run faster
    except (ValueError, DronaError) as exc:
        print(f"drona sim-vehicle: {exc}", file=sys.stderr)
        return 2
    if args.record is not None and workspace is None:
        print("drona sim-vehicle: --record needs --workspace (its cells and tau)", file=sys.stderr)
        return 2
    try:
        runtime.run(_serve(config, workspace, args.record, args.epoch))
    except DronaError as exc:
        print(f"drona sim-vehicle: {exc}", file=sys.stderr)
        return 2
    return 0


def max_speed(args: argparse.Namespace, workspace: Workspace | None = None) -> float:
    """The horizontal speed limit the vehicles start with, in their simulated seconds: ``--max-speed``, else
    the workspace's slowed by ``--speedup`` (or their autopilot's default)."""
    return starting_limits(_config(args, workspace).vehicle).max_speed


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not name or not math.isfinite(number):
        raise ValueError(f"--param must be NAME=VALUE with a finite number, got {text!r}")
    return name, number


def _config(args: argparse.Namespace, workspace: Workspace | None = None) -> FleetConfig:
    if args.count < 1:
        raise ValueError(f"--count must be >= 1, got {args.count}")
    if args.instance < 0:
        raise ValueError(f"--instance must be >= 0, got {args.instance}")
    for name in ("speedup", "max_speed"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise ValueError(f"--{name.replace('_', '-')} must be > 0, got {value}")
    if args.baud is not None and not args.serial:
        raise ValueError("--baud is the rate of a serial line: it needs --serial")
    if args.serial and args.base_port is not None:
        raise ValueError("--base-port: a serial line has no port (each vehicle prints its device)")
    baud = DEFAULT_BAUD if args.baud is None else args.baud
    if baud <= 0:
        raise ValueError(f"--baud must be > 0, got {baud}")
    if not 0 <= args.battery <= 100:
        raise ValueError(f"--battery must be within 0..100, got {args.battery}")
    personality = PERSONALITIES[args.autopilot]
    limits = None  # the personality's parameter defaults
    if args.max_speed is not None:
        limits = replace(starting_limits(VehicleConfig(personality=personality)), max_speed=args.max_speed)
    # The workspace's vehicle limits are set on the vehicles as an operator would, before any by hand; they
    # are in the fleet's seconds, which a sped-up vehicle makes shorter.
    tuned: tuple[tuple[str, float], ...] = ()
    if workspace is not None:
        wanted = workspace.vehicle.sped_up(1 / args.speedup)
        tuned = limit_params(wanted if args.max_speed is None else replace(wanted, speed_m_s=args.max_speed),
                             personality)
    vehicle = VehicleConfig(personality=personality, limits=limits, ready_after_s=args.ready_after,
                            spool_up_s=args.spool_up, auto_disarm_s=args.auto_disarm, battery_pct=args.battery,
                            params=(*tuned, *(_param(text) for text in args.param)))
    ParamStore(vehicle)  # refuses a parameter its autopilot does not have, before any vehicle starts
    key = parse_key(args.signing_key, "--signing-key") if args.signing_key else None
    return FleetConfig(count=args.count, vehicle=vehicle, tcp=args.tcp, host=args.host, base_port=args.base_port,
                       speedup=args.speedup, signing_key=key, serial_baud=baud if args.serial else None,
                       first=args.instance)


async def _serve(config: FleetConfig, workspace: Workspace | None, record: Path | None = None,
                 epoch: float = 0.0) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)

    serving: list[SimNode] = []

    def announce(nodes: list[SimNode]) -> None:
        serving.extend(nodes)
        kind = "tcp server" if config.tcp else "udp to"
        for i, node in zip(config.instances, nodes, strict=True):
            if isinstance(node.link, PtyLink):
                where = f"serial {node.link.device} at {config.serial_baud} baud"
            else:
                where = f"{kind} {config.host}:{config.port(i)}"
            print(f"drona sim-vehicle: system {node.system_id} ({config.vehicle.personality.name}) {where}",
                  file=sys.stderr, flush=True)

    with contextlib.ExitStack() as files:
        truth = None
        if record is not None and workspace is not None:
            out = files.enter_context(_open_record(record))
            names = list(workspace.drones)[config.instances.start:config.instances.stop]
            truth = TruthRecord(GeoFrame(workspace), names, epoch, out)
        await run_fleet(config, workspace, stop, on_ready=announce, truth=truth)
    for node in serving:  # whether the telemetry asked for fits the line (a radio's 57600 baud, say)
        if isinstance(node.link, PtyLink) and node.link.unsent:
            line = node.link
            print(f"drona sim-vehicle: system {node.system_id}: the serial line had no room for {line.unsent} of "
                  f"{line.sent + line.unsent} bytes ({100 * line.unsent / (line.sent + line.unsent):.1f}%): "
                  "ask for less telemetry, or a higher baud rate", file=sys.stderr, flush=True)


def _open_record(path: Path) -> TextIO:
    try:
        return path.open("w", encoding="utf-8")
    except OSError as exc:
        raise DronaError(f"--record {path}: {exc.strerror}") from exc
