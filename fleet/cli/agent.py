"""``drona agent``: run one drone's stack (or ``--count N`` of them) against its vehicle, over Zenoh.

Every flag can also come from the environment (``DRONA_<FLAG>``, see
deploy/systemd/agent.env.example); a flag wins over its variable. With no
Zenoh flags, drone i of the workspace listens on tcp/127.0.0.1:(7448 + i) and
connects to the others, and its vehicle is expected where ``drona sim-vehicle``
sends it (udpin://127.0.0.1:(14540 + i)): on one machine the defaults find each
other. Exit codes: 0 after a clean shutdown, 2 for bad settings or a vehicle
or network that cannot be reached at start-up.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from pathlib import Path
from typing import TextIO

from pydantic import ValidationError

from drona_gcs.errors import DronaError
from drona_gcs.geo import check_flyable
from drona_gcs.workspace_files import load_workspace
from fleet import runtime
from fleet.agent.host import Host, ignore_signals, install_signals, run_host, select_drones
from fleet.agent.settings import AgentSettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add("--workspace", help="workspace file (YAML, JSON or DRONA XML) [DRONA_WORKSPACE]")
    add("--drone", help="drone id; with --count, the first of consecutive drones (default: the first) [DRONA_DRONE]")
    add("--count", type=int, help="drones hosted by this process, each with its own Zenoh session (default 1)")
    add("--shared-session", action="store_const", const=True,
        help="simulation: the --count drones share one Zenoh session (each keeps its own declarations and "
             "liveliness token); a broadcast then crosses into Python once per process [DRONA_SHARED_SESSION]")
    add("--vehicle", help="MAVLink URL of the vehicle: udpin://HOST:PORT, udpout://..., tcp://HOST:PORT, "
                          "serial://DEV:BAUD (default udpin://127.0.0.1:(14540 + i)) [DRONA_VEHICLE]")
    add("--vehicle-base-port", type=int, help="default vehicle URLs: udpin://127.0.0.1:(this + i) (default 14540, "
                                              "as `drona sim-vehicle`)")
    add("--fleet", help="fleet name: keys live under drona/<fleet>/ (default 'default') [DRONA_FLEET]")
    add("--zenoh-config", type=Path, help="Zenoh JSON5 configuration file [DRONA_ZENOH_CONFIG]")
    add("--listen", action="append", metavar="EP", help="Zenoh endpoint to listen on (repeatable) [DRONA_LISTEN]")
    add("--connect", action="append", metavar="EP", help="Zenoh endpoint to connect to (repeatable) [DRONA_CONNECT]")
    add("--lease", dest="lease_s", type=float, help="Zenoh lease, s: a cut link is seen after it (default 10)")
    add("--epoch", type=float, help="fleet epoch, Unix seconds: step k starts at epoch + k tau (default 0)")
    add("--record", type=Path, help="write every drone's actual cell at every step here, as JSON Lines")
    add("--lead-steps", type=int, help="steps from planning to a plan's start (default: Delta + 1 + climb)")
    add("--hover-lead-steps", type=int,
        help="the same for a drone in the air, at most --lead-steps (default: Delta + 1 + a second's round)")
    add("--clock-offset", dest="clock_offset_s", type=float,
        help="simulation only: shift this process's clock by S seconds (tests the skew check)")
    add("--clock-step-on-signal", action="store_const", const=True,
        help="simulation only: shift the clock by --clock-offset once the process gets SIGUSR1, not from the start "
             "(a clock stepped in flight)")
    add("--telemetry-hz", type=float, help="rate asked of the vehicle's position streams; the landed state comes at "
                                           "half of it, battery and status at a quarter (default 10)")
    add("--rate-hz", type=float, help="the link streams the setpoint at this rate, over 2 (PX4 leaves OFFBOARD "
                                      "at 2 Hz or less) (default 20) [DRONA_RATE_HZ]")
    add("--drain-per-step", type=float,
        help="battery points one step of flight costs, for planning (default 0.33 a second of flight, times tau)")
    add("--backend", choices=["pymavlink", "mavsdk"],
        help="the vehicle link's MAVLink library (default pymavlink; mavsdk needs the mavsdk extra) [DRONA_BACKEND]")
    add("--ready-timeout", dest="ready_timeout_s", type=float,
        help="at start-up, seconds a vehicle may take to be ready before its drone joins anyway, waiting for its "
             "position (default 5)")
    add("--takeoff-timeout", dest="takeoff_timeout_s", type=float,
        help="seconds from an accepted take-off to leaving the ground (default 10; ArduCopter spools up ~3.5 s)")
    add("--command-timeout", dest="command_timeout_s", type=float,
        help="seconds a whole take-off or landing may take (default 30)")
    add("--signing-key-file", type=Path, metavar="PATH",
        help="MAVLink 2 signing: a file holding the vehicle's key (64 hex digits), or a line 'DRONE KEY' per "
             "drone (one file may serve every process of the fleet: each takes its own drones' keys). The link "
             "then signs what it sends and hears only what is signed with the key. For one drone the key may "
             "instead come from DRONA_SIGNING_KEY (not a flag: ps shows flags) [DRONA_SIGNING_KEY_FILE]")
    add("--no-adopt-mail", dest="adopt_mail", action="store_const", const=False,
        help="`drona serve` dispatches the mail: take over no departed drone's mail (the service reassigns it), "
             "take mail on board only once the service cleared it, and hand back what is not cleared when the "
             "service is out of touch")
    add("--tls-dir", type=Path, help="the fleet's certificates, made by `drona certs`: Zenoh runs with mutual TLS and "
                                     "the fleet's access control, each drone its own identity [DRONA_TLS_DIR]")
    add("--insecure", action="store_const", const=True,
        help="plain TCP without identities: anyone on the network may speak for any drone [DRONA_INSECURE]")
    add("--log-level", help="DEBUG, INFO (default), WARNING")


def settings_from(args: argparse.Namespace) -> AgentSettings:
    given = {k: v for k, v in vars(args).items() if v is not None and not k.startswith("_") and k != "command"}
    return AgentSettings(**given)


def run(args: argparse.Namespace) -> int:
    try:
        settings = settings_from(args)
        workspace = load_workspace(settings.workspace)
        check_flyable(workspace)
        names = select_drones(settings, workspace)
    except ValidationError as exc:
        print(f"drona agent: {_first_problem(exc)}", file=sys.stderr)
        return 2
    except (ValueError, DronaError, OSError) as exc:
        print(f"drona agent: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(level=settings.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    host = Host(settings, workspace, names)
    try:
        runtime.run(_main(host))
    except (DronaError, OSError, ExceptionGroup) as exc:
        problems = _leaves(exc)
        if not all(isinstance(p, (DronaError, OSError)) for p in problems):
            raise
        for problem in problems:
            print(f"drona agent: {problem}", file=sys.stderr)
        return 2
    return 0


def _leaves(exc: BaseException) -> list[BaseException]:
    if isinstance(exc, BaseExceptionGroup):
        return [leaf for inner in exc.exceptions for leaf in _leaves(inner)]
    return [exc]


async def _main(host: Host) -> None:
    install_signals(host)
    try:
        with contextlib.ExitStack() as files:
            record: TextIO | None = None
            if host.settings.record is not None:
                record = files.enter_context(host.settings.record.open("a", encoding="utf-8"))
            await run_host(host, record, on_ready=_announce)
    finally:
        ignore_signals()


def _announce(host: Host) -> None:
    print(f"drona agent: {', '.join(host.names)} flying (fleet {host.settings.fleet})", file=sys.stderr, flush=True)


def _first_problem(exc: ValidationError) -> str:
    error = exc.errors()[0]
    where = ".".join(str(part) for part in error["loc"]) or "settings"
    return f"{where}: {error['msg']}"
