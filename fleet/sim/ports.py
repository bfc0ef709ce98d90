"""Free loopback ports for fake vehicles, benchmarks and tests."""

from __future__ import annotations

import contextlib
import random
import socket
from pathlib import Path

#: Ports this process handed out: free when handed, so two calls in a row could hand the same one.
_HANDED: set[int] = set()


def free_port(kind: int = socket.SOCK_DGRAM, host: str = "127.0.0.1") -> int:
    """A port free for ``kind`` (SOCK_DGRAM or SOCK_STREAM) on ``host``, below the ephemeral range.

    A port the OS hands out may be handed out again before it is bound: to a socket that connects to
    it, even, which then holds it (a TCP connection to oneself)."""
    return free_port_block(1, kind, host)


def free_udp_base(count: int, host: str = "127.0.0.1") -> int:
    """A port p with p .. p + count - 1 all free for UDP on ``host``."""
    return free_port_block(count, socket.SOCK_DGRAM, host)


def free_port_block(count: int, kind: int, host: str = "127.0.0.1") -> int:
    """A port p with p .. p + count - 1 all free for ``kind`` (SOCK_DGRAM or SOCK_STREAM) on ``host``.

    Searched below the ephemeral range where possible, so that ports the OS hands
    out to other sockets meanwhile do not land in the block.
    """
    low = 32768
    with contextlib.suppress(OSError, ValueError, IndexError):
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    first, last = (10000, low - count) if low - count > 12000 else (low, 65535 - count)
    rng = random.Random()
    for _ in range(100):
        base = rng.randrange(first, last)
        block = range(base, base + count)
        if not _HANDED.isdisjoint(block):
            continue
        socks: list[socket.socket] = []
        try:
            for port in block:
                sock = socket.socket(socket.AF_INET, kind)
                socks.append(sock)
                sock.bind((host, port))
            _HANDED.update(block)
            return base
        except OSError:
            continue
        finally:
            for sock in socks:
                sock.close()
    raise OSError(f"found no {count} consecutive free ports on {host}")
