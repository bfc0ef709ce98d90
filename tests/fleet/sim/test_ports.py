"""Free ports for tests and benchmarks: never one the OS may hand a connecting socket meanwhile."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from fleet.sim.ports import free_port

EPHEMERAL = Path("/proc/sys/net/ipv4/ip_local_port_range")


@pytest.mark.parametrize("kind", [socket.SOCK_STREAM, socket.SOCK_DGRAM], ids=["tcp", "udp"])
def test_free_ports_lie_below_the_ephemeral_range_and_none_is_handed_twice(kind: int) -> None:
    """A port from the ephemeral range may be taken before it is bound: a gateway connecting to it
    got it as its own local port (a TCP connection to itself), and the peer to listen there could not.
    A port is free until bound: handed twice (1000 random picks of some 22000 surely repeat one),
    two callers would share it."""
    if not EPHEMERAL.exists():
        pytest.skip(f"{EPHEMERAL} is missing: no ephemeral range to keep out of")
    low = int(EPHEMERAL.read_text().split()[0])
    if low <= 12000:
        pytest.skip(f"the ephemeral range starts at {low}: too low to search below it")
    handed = [free_port(kind) for _ in range(1000)]
    assert all(port < low for port in handed), f"ports in the ephemeral range (from {low}): {handed}"
    assert len(set(handed)) == len(handed), "a port handed out twice: free until bound, so two callers share it"
    for port in handed[:20]:
        with socket.socket(socket.AF_INET, kind) as sock:
            sock.bind(("127.0.0.1", port))
