"""``drona certs``: the fleet's CA and a certificate per drone, the service and a router.

    drona certs /etc/drona/tls --workspace ws.yaml                  # d1 ... dN, service, router
    drona certs /etc/drona/tls --name d9 --san IP:10.0.0.19        # one more, signed by the same CA

The CA is made on the first run and reused after. Copy ``ca.pem`` and a node's own folder
to its host; keep ``ca-key.pem`` on the machine that signs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from drona_gcs.errors import DronaError
from drona_gcs.workspace_files import load_workspace
from fleet.transport.identity import ROUTER, SERVICE, make_certs


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", type=Path, help="folder for ca.pem and one folder per node")
    parser.add_argument("--workspace", type=Path, help="a certificate for each of its drones, the service and a router")
    parser.add_argument("--name", action="append", default=[], help="a certificate for this node too (repeatable)")
    parser.add_argument("--san", action="append", default=[], metavar="DNS:NAME|IP:ADDR",
                        help="another name or address in every certificate made (beside localhost and 127.0.0.1)")
    parser.add_argument("--host", action="append", default=[], metavar="NAME=D1,D2,...",
                        help="a certificate for a process that flies these drones in one session (drona agent "
                             "--count --shared-session), recorded in hosts.json (repeatable)")
    parser.add_argument("--days", type=int, default=825, help="how long the certificates are good for (default 825)")


def run(args: argparse.Namespace) -> int:
    try:
        names = [*load_workspace(args.workspace).drones, SERVICE, ROUTER] if args.workspace else []
        names += [n for n in args.name if n not in names]
        if not names and not args.host:
            raise ValueError("nothing to make: give --workspace, --name or --host")
        if args.days < 1:
            raise ValueError(f"--days must be at least 1, got {args.days}")
        hosts = dict(_host(spec) for spec in args.host)
        made = make_certs(args.out, names, args.san, args.days, hosts)
    except (DronaError, ValueError, OSError) as exc:
        print(f"drona certs: {exc}", file=sys.stderr)
        return 2
    print(f"drona certs: CA {args.out / 'ca.pem'}; {len(made)} certificates: "
          f"{', '.join(p.parent.name for p in made)}")
    return 0


def _host(spec: str) -> tuple[str, list[str]]:
    name, _, drones = spec.partition("=")
    flown = [d.strip() for d in drones.split(",") if d.strip()]
    if not name or not flown:
        raise ValueError(f"--host {spec!r}: write NAME=D1,D2,...")
    return name, flown
