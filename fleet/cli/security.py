"""The flags every command on the fleet's Zenoh network shares: its certificates, or ``--insecure``."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from fleet.transport.identity import check_security


def add_security_arguments(parser: argparse.ArgumentParser) -> None:
    tls_dir = os.environ.get("DRONA_TLS_DIR")
    parser.add_argument("--tls-dir", type=Path, default=Path(tls_dir) if tls_dir else None,
                        help="the fleet's certificates, made by `drona certs`: mutual TLS and the fleet's access "
                             "control [DRONA_TLS_DIR]")
    parser.add_argument("--insecure", action="store_true", default=os.environ.get("DRONA_INSECURE") == "1",
                        help="plain TCP without identities: anyone on the network may speak for any drone "
                             "[DRONA_INSECURE=1]")


def tls_dir_from(args: argparse.Namespace) -> Path | None:
    """The certificates' folder, or None when ``--insecure``; IdentityError when neither or both are given."""
    return check_security(args.tls_dir, args.insecure)
