"""``drona bench mavlink``'s fleet on loopback: fake vehicles in a ``drona sim-vehicle`` subprocess over UDP,
and a counting pymavlink link to each in this process."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import IO, Any

from drona_gcs.geo import GeoFrame
from fleet.bench import BenchError
from fleet.bench.processes import cpu_seconds
from fleet.sim.ports import free_udp_base
from fleet.vehicle.mavlink_link import PymavlinkLink

REPO = Path(__file__).resolve().parents[2]
HOST = "127.0.0.1"

CONNECT_TIMEOUT_S = 30.0  #: the subprocess's start-up (imports) plus every link's stream requests
STOP_TIMEOUT_S = 5.0


class CountingLink(PymavlinkLink):
    """A PymavlinkLink that counts the vehicle's messages and records LOCAL_POSITION_NED's delay."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.received = 0
        self.delays: list[tuple[float, float]] = []  #: (link clock, link clock - time_boot_ms) per position

    def _dispatch(self, msg: Any) -> None:
        super()._dispatch(msg)
        if self.sysid is None or msg.get_srcSystem() != self.sysid or msg.get_type() == "BAD_DATA":
            return
        self.received += 1
        if msg.get_type() == "LOCAL_POSITION_NED":
            now = self.clock()
            self.delays.append((now, now - msg.time_boot_ms / 1000))


class SimProcess:
    """``drona sim-vehicle --count N`` over UDP to HOST:base_port + i, stopped on exit."""

    def __init__(self, count: int, base_port: int) -> None:
        self.count, self.base_port = count, base_port
        self.proc: subprocess.Popen[bytes] | None = None
        self._log: IO[bytes] | None = None

    def start(self) -> None:
        cmd = [sys.executable, "-m", "fleet.cli", "sim-vehicle", "--count", str(self.count), "--host", HOST,
               "--base-port", str(self.base_port), "--ready-after", "0.5"]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
        self._log = tempfile.TemporaryFile()  # noqa: SIM115  # open while the process runs
        self.proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=self._log)

    def cpu_seconds(self) -> float | None:
        """User + system CPU seconds of the running vehicles' process (None where /proc is not there)."""
        return None if self.proc is None else cpu_seconds(self.proc.pid)

    def why(self) -> str:
        """The end of what the process wrote to stderr, for an error message."""
        if self._log is None:
            return ""
        self._log.seek(0)
        lines = self._log.read().decode(errors="replace").strip().splitlines()
        code = "" if self.proc is None or self.proc.poll() is None else f" (exit {self.proc.returncode})"
        return f"{code}: " + " | ".join(lines[-5:]) if lines else code

    async def stop(self) -> None:
        proc = self.proc
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            for sig in (signal.SIGKILL, None):
                deadline = time.monotonic() + STOP_TIMEOUT_S
                while proc.poll() is None and time.monotonic() < deadline:
                    await asyncio.sleep(0.05)
                if proc.poll() is not None or sig is None:
                    break
                proc.send_signal(sig)
        if self._log is not None:
            self._log.close()
            self._log = None


@contextlib.asynccontextmanager
async def linked_fleet(count: int, stream_hz: float, frame: GeoFrame | None = None,
                       setpoint_hz: float = 10.0) -> AsyncIterator[tuple[SimProcess, list[CountingLink]]]:
    """``count`` vehicles in a subprocess and a connected link to each (streams requested); each
    link repeats its last setpoint at ``setpoint_hz``."""
    try:
        base = free_udp_base(count, HOST)
    except OSError as exc:
        raise BenchError(str(exc)) from exc
    links = [CountingLink(f"udpin://{HOST}:{base + i}", stream_hz=stream_hz, frame=frame,
                          setpoint_hz=setpoint_hz, heartbeat_timeout=5.0, ack_timeout=2.0) for i in range(count)]
    sim = SimProcess(count, base)
    connecting = [asyncio.create_task(link.connect(timeout=CONNECT_TIMEOUT_S)) for link in links]
    try:
        await asyncio.sleep(0.05)  # every link binds its port before the vehicles send to it
        sim.start()
        done, _ = await asyncio.wait(connecting, timeout=CONNECT_TIMEOUT_S + 10)
        failed = [t for t in connecting if t not in done or t.exception() is not None]
        if failed:
            task = failed[0]
            what = "timed out" if task not in done else str(task.exception())
            raise BenchError(f"{len(failed)} of {count} links did not connect (first: {what}); "
                             f"vehicles{sim.why()}")
        yield sim, links
    finally:
        for task in connecting:
            task.cancel()
        await asyncio.gather(*connecting, return_exceptions=True)
        await asyncio.gather(*(link.close() for link in links), return_exceptions=True)
        await sim.stop()


def udp_queues(ports: set[int]) -> tuple[int, int] | None:
    """(bytes queued unread, datagrams dropped) summed over our UDP sockets on ``ports`` (None off Linux)."""
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    queued = drops = 0
    for line in lines:
        f = line.split()
        if len(f) < 13 or int(f[1].rpartition(":")[2], 16) not in ports:
            continue
        queued += int(f[4].rpartition(":")[2], 16)
        drops += int(f[12])
    return queued, drops
