"""How a process joins the fleet's Zenoh network: the session's configuration, where agents listen by
default, and mutual TLS with the fleet's access control (:mod:`fleet.transport.identity`).

The configuration is refused with a :class:`~fleet.transport.node.TransportError` naming what is wrong,
Zenoh's own errors mapped by :func:`~fleet.transport.node.zenoh_errors`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import zenoh

from fleet.transport.identity import Identity, access_control, read_hosts
from fleet.transport.keys import FleetKeys
from fleet.transport.node import TransportError, zenoh_errors

#: Where the agent of drone i listens by default on one machine (and where the others look for it).
AGENT_BASE_PORT = 7448
ROUTER_PORT = 7447
DEFAULT_HOST = "127.0.0.1"
RETRY = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}


@dataclass(frozen=True)
class ZenohSettings:
    """How to join the fleet's Zenoh network (plain values; the CLI's settings build it)."""

    mode: str = "peer"  #: peer, client or router
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config_file: Path | None = None  #: a Zenoh JSON5 file; listen/connect above are added to it
    lease_s: float | None = None  #: how long a silent link lives (Zenoh's default is 10 s)
    multicast: bool = False  #: multicast scouting (off: on this kind of host it picks the wrong interface)
    extra: tuple[tuple[str, str], ...] = field(default=())  #: more (key, JSON5 value) pairs
    identity: Identity | None = None  #: mutual TLS with this certificate (None: plain TCP, --insecure)
    access: dict[str, Any] | None = None  #: Zenoh's access_control (see fleet.transport.identity)
    #: the most messages (lines) one sample may carry; a host's gathered puts to one key go in samples of
    #: at most this many
    max_frames: int | None = None

    def config(self) -> zenoh.Config:
        """The Zenoh configuration; :class:`TransportError` naming what is wrong."""
        source = f" in {self.config_file}" if self.config_file else ""
        try:
            with zenoh_errors(f"Zenoh configuration{source}"):
                return self._config()
        except (OSError, ValueError) as exc:
            raise TransportError(f"Zenoh configuration{source}: {exc}") from exc

    def _config(self) -> zenoh.Config:
        cfg = zenoh.Config.from_file(str(self.config_file)) if self.config_file else zenoh.Config()
        if self.config_file is None or self.mode != "peer":
            cfg.insert_json5("mode", json.dumps(self.mode))
        if self.listen:
            cfg.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.connect:
            cfg.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        if self.identity is not None:
            _mutual_tls(cfg, self.identity)
        if self.access is not None:
            cfg.insert_json5("access_control", json.dumps(self.access))
        if self.config_file is None:
            cfg.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast))
            # Endpoints not up yet are retried in the background; retry often, so a fleet
            # started in any order meshes within a second (Zenoh's default backs off to 4 s).
            cfg.insert_json5("connect/retry", json.dumps(RETRY))
        if self.lease_s is not None:
            lease_ms = round(self.lease_s * 1000)
            cfg.insert_json5("transport/link/tx/lease", json.dumps(lease_ms))
            # Keep-alives must come several times per lease, or a busy link looks dead.
            cfg.insert_json5("transport/link/tx/keep_alive", json.dumps(4))
        for key, value in self.extra:
            cfg.insert_json5(key, value)
        return cfg

    def secured(self, tls_dir: Path | None, name: str, keys: FleetKeys,
                drones: Sequence[str] | None) -> ZenohSettings:
        """These settings as ``name`` of the fleet: mutual TLS, and the fleet's access control over what the
        ``drones`` say (None: none, for a tool that only asks and checks its answers' writers itself).
        Unchanged without ``tls_dir`` (a plain-TCP fleet, ``--insecure``)."""
        if tls_dir is None:
            return self
        access = access_control(keys, drones, read_hosts(tls_dir)) if drones is not None else None
        return replace(self, identity=Identity.of(tls_dir, name), access=access)


def _mutual_tls(cfg: zenoh.Config, identity: Identity) -> None:
    """TLS links only, with ``identity``'s files; every ``tcp/`` endpoint (given, in the file or Zenoh's
    default) is taken as ``tls/`` on the same address."""
    for section in ("listen/endpoints", "connect/endpoints"):
        cfg.insert_json5(section, json.dumps(_as_tls(json.loads(cfg.get_json(section)))))
    cfg.insert_json5("transport/link/protocols", json.dumps(["tls"]))
    cfg.insert_json5("transport/link/tls", json.dumps(identity.tls_config()))


def _as_tls(endpoints: Any) -> Any:
    """Endpoints as Zenoh's config holds them (a list, or a list per mode), ``tcp/`` ones made ``tls/``."""
    if isinstance(endpoints, dict):
        return {mode: _as_tls(listed) for mode, listed in endpoints.items()}
    return [f"tls/{ep.removeprefix('tcp/')}" if ep.startswith("tcp/") else ep for ep in endpoints]


def agent_endpoint(index: int, host: str = DEFAULT_HOST) -> str:
    """Where drone number ``index`` of the workspace listens by default."""
    return f"tcp/{host}:{AGENT_BASE_PORT + index}"
