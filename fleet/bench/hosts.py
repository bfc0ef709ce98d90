"""Hosts made of network namespaces, each a machine of its own: for the fault benches and the tests.

Each host has one cable (a veth pair) to a bridge in the maker's own namespace, which reaches every
host at the bridge's address (``gateway``). Cutting a host's cable partitions it from the rest;
healing it joins it again. Needs root and iproute2 (:func:`can_make_hosts`).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

from fleet.bench import BenchError


@dataclass(frozen=True)
class Hosts:
    """Namespaces on a bridge: ``ip[host]`` is a host's address, ``link[host]`` its cable; ``gateway`` the
    bridge's address, the maker's own on the hosts' network."""

    ns: dict[str, str]
    ip: dict[str, str]
    link: dict[str, str]
    gateway: str

    def cut(self, host: str) -> None:
        _ip("link", "set", self.link[host], "down")

    def heal(self, host: str) -> None:
        _ip("link", "set", self.link[host], "up")

    def run_on(self, host: str, command: list[str]) -> list[str]:
        """``command`` as run on ``host``."""
        return ["ip", "netns", "exec", self.ns[host], *command]


def _ip(*args: str, ns: str | None = None) -> None:
    command = ["ip", *(["netns", "exec", ns, "ip"] if ns else []), *args]
    try:
        subprocess.run(command, check=True, capture_output=True, timeout=10)
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
        said = exc.stderr.decode(errors="replace").strip() if isinstance(exc.stderr, bytes) else ""
        raise BenchError(f"`{' '.join(command)}` failed: {said or exc}") from exc


def _quietly(*command: str) -> None:
    subprocess.run(list(command), check=False, capture_output=True, timeout=10)


CANNOT_MAKE_HOSTS = "network namespaces need root and iproute2 (ip)"


def can_make_hosts() -> bool:
    return os.geteuid() == 0 and shutil.which("ip") is not None


@contextmanager
def network_hosts(names: Sequence[str]) -> Iterator[Hosts]:
    """Hosts ``names`` on a bridge of their own (a fresh /24), removed on exit."""
    if not can_make_hosts():
        raise BenchError(CANNOT_MAKE_HOSTS)
    tag = uuid.uuid4().hex[:5]
    subnet = f"10.{77 + int(tag[0], 16) % 8}.{int(tag[1:3], 16)}"
    bridge = f"br{tag}"
    made = Hosts(ns={h: f"drona-{tag}-{h}" for h in names}, ip={h: f"{subnet}.{i + 1}" for i, h in enumerate(names)},
                 link={h: f"v{tag}{i}" for i, h in enumerate(names)}, gateway=f"{subnet}.254")
    try:
        _ip("link", "add", bridge, "type", "bridge")
        _ip("addr", "add", f"{made.gateway}/24", "dev", bridge)
        _ip("link", "set", bridge, "up")
        for i, host in enumerate(names):
            ns, cable, end = made.ns[host], made.link[host], f"p{tag}{i}"
            _ip("netns", "add", ns)
            _ip("link", "add", cable, "type", "veth", "peer", "name", end)
            _ip("link", "set", end, "netns", ns)
            _ip("link", "set", cable, "master", bridge)
            _ip("link", "set", cable, "up")
            _ip("addr", "add", f"{made.ip[host]}/24", "dev", end, ns=ns)
            _ip("link", "set", end, "up", ns=ns)
            _ip("link", "set", "lo", "up", ns=ns)
        yield made
    finally:
        for host in names:
            _quietly("ip", "netns", "del", made.ns[host])
            _quietly("ip", "link", "del", made.link[host])
        _quietly("ip", "link", "del", bridge)
