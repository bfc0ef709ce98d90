"""The benches' child processes: ``drona`` commands run as subprocesses, waited for, checked, and the CPU
they use."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, cast

from fleet.bench import BenchError


def spawn(arguments: list[str], nice: int = 0, on: list[str] | None = None) -> subprocess.Popen[bytes]:
    """``drona`` with ``arguments``, at ``nice`` (added to this process's niceness: lower priority), run
    by the command ``on`` (``ip netns exec NS``: on another host; it execs the process)."""
    child = subprocess.Popen([*(on or []), sys.executable, "-m", "fleet.cli", *arguments], stdout=subprocess.DEVNULL)
    if nice:  # at once: it is still importing, long before it serves a drone
        os.setpriority(os.PRIO_PROCESS, child.pid, os.getpriority(os.PRIO_PROCESS, 0) + nice)
    return child


async def up_or_gone(all_up: asyncio.Event, children: list[subprocess.Popen[bytes]], timeout_s: float,
                      what: str) -> None:
    """Until ``all_up`` (every agent ``what``); :class:`BenchError` at once if a child process exits first
    (a bad setting, a port taken: its own error is on stderr above), or after ``timeout_s``."""
    loop = asyncio.get_running_loop()
    gone: asyncio.Future[None] = loop.create_future()
    fds = [os.pidfd_open(child.pid) for child in children]

    def one_gone() -> None:
        if not gone.done():
            gone.set_result(None)

    for fd in fds:
        loop.add_reader(fd, one_gone)
    up: asyncio.Future[Any] = asyncio.create_task(all_up.wait())
    try:
        await asyncio.wait([up, gone], timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED)
    finally:
        up.cancel()
        for fd in fds:
            loop.remove_reader(fd)
            os.close(fd)
    check_alive(children)
    if not all_up.is_set():
        raise BenchError(f"the agents were not all {what} after {timeout_s:g} s")


def check_alive(children: list[subprocess.Popen[bytes]]) -> None:
    for child in children:
        if (code := child.poll()) is not None:
            args = cast(list[str], child.args)  # [..., python, -m, fleet.cli, command, ...] (see spawn)
            command = args[args.index("fleet.cli") + 1]
            raise BenchError(f"`drona {command}` (pid {child.pid}) exited with code {code}; its error is above")


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds used so far by process ``pid`` (None where /proc is not there)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


REFERENCE_LOOP = 1_000_000  #: additions in the reference loop


def reference_loop_ms() -> float:
    """Wall milliseconds of a fixed pure-Python loop: how fast this host runs Python now. A virtual
    machine's speed follows its neighbours' load, and CPU-bound figures with it; read beside them, it
    says how far two runs can be compared."""
    started = time.perf_counter()
    total = 0
    for i in range(REFERENCE_LOOP):
        total += i & 7
    return (time.perf_counter() - started) * 1000
