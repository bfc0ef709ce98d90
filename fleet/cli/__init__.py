"""The ``drona`` command: one entry point that ties the core, the fleet and the service together.

Each subcommand lives in its own module and is imported only when used, so
``drona plan`` does not pay for Zenoh or FastAPI. Exit codes: 0 success,
1 the command ran and found a problem (for example a violation), 2 bad
arguments or unusable input.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

# name -> (module, help). Each module has `add_arguments(parser)` and `run(args) -> int`.
COMMANDS: dict[str, tuple[str, str]] = {
    "plan": ("fleet.cli.plan", "plan safe trajectories for JSON Lines problems"),
    "bench": ("fleet.cli.bench", "benchmarks: planner, mavlink, coordination, api, delivery"),
    "verify": ("fleet.cli.verify", "systematic tester: explore schedules of the real stack for bugs"),
    "sim-vehicle": ("fleet.cli.sim_vehicle", "fake ArduCopter/PX4 vehicles speaking MAVLink over UDP or TCP"),
    "serve": ("fleet.cli.serve", "the mail-request service and dashboard (FastAPI)"),
    "agent": ("fleet.cli.agent", "run drones' stacks against their vehicles, coordinating over Zenoh"),
    "mail": ("fleet.cli.mail", "give the fleet a mail over Zenoh, and optionally follow it until delivered"),
    "router": ("fleet.cli.router", "a Zenoh router for agents in client mode"),
    "demo": ("fleet.cli.demo", "a fleet in one command: service and dashboard, agents and fake vehicles"),
    "certs": ("fleet.cli.certs", "the fleet's CA and certificates: mutual TLS and access control on Zenoh"),
    "audit": ("fleet.cli.audit", "judge a recorded run (--record files) for collisions under Delta"),
    "replay": ("fleet.cli.replay", "play a recorded run (--record file) back on a map, with the audit's findings"),
}


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    """The parser; only the ``selected`` command's module is imported (all when None)."""
    parser = argparse.ArgumentParser(prog="drona", description="DRONA ground-control toolkit")
    parser.add_argument("--version", action=_Version, nargs=0,
                        help="print the version and the wire protocol's, and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        cmd = sub.add_parser(name, help=help_text, description=help_text)
        if selected in (None, name):
            importlib.import_module(module).add_arguments(cmd)
        cmd.set_defaults(_module=module)
    return parser


class _Version(argparse.Action):
    """``--version``: the package's version and the wire protocol's (peers must speak the same)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> NoReturn:
        from fleet.transport.wire import VERSION as WIRE_VERSION  # here: other commands do not pay for it

        try:
            version = importlib.metadata.version("drona-gcs")
        except importlib.metadata.PackageNotFoundError:  # run from a source tree that is not installed
            version = "(not installed)"
        print(f"drona {version} (wire protocol {WIRE_VERSION})")
        parser.exit()


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    selected = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(selected if selected in COMMANDS else None)
    if selected is None and (unknown := [a for a in argv if a not in ("-h", "--help", "--version")]):
        parser.error(f"unknown option {unknown[0]}: a COMMAND comes first ({', '.join(COMMANDS)})")
    args = parser.parse_args(argv)
    try:
        code: int = importlib.import_module(args._module).run(args)
    except BrokenPipeError:  # the reader went away (drona ... | head): not our error
        sys.stderr.close()
        return 0
    return code


if __name__ == "__main__":
    sys.exit(main())
