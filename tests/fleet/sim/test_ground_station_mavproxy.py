"""The fake vehicle towards a real ground station: MAVProxy.

MAVProxy (from PyPI, a subprocess) connects to ``drona sim-vehicle`` (another subprocess) in each
personality and downloads the parameters and the mission lists, as a pilot's ``param show`` and
``wp list`` do. Against a fake that ignored PARAM_REQUEST_LIST and MISSION_REQUEST_LIST it printed
nothing, timed out on MAVLink FTP and reported a fence breach.
"""

from __future__ import annotations

import contextlib
import os
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from fleet.sim.fleet import placements
from fleet.sim.params import TABLES
from fleet.sim.personality import ARDUPILOT, Personality
from fleet.sim.ports import free_port
from tests.fleet.sim.ground_station_helpers import BOTH
from tests.fleet.sim.vehicle_helpers import REPO, stderr_lines


# ------------------------------------------------------------------ MAVProxy
class MAVProxy:
    """``mavproxy.py`` in a subprocess: its output collected by a thread, commands written to its stdin."""

    def __init__(self, master: str, workdir: Path) -> None:
        script = Path(sys.executable).with_name("mavproxy.py")
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "HOME": str(workdir)}  # no user's .mavinit.scr
        self.proc = subprocess.Popen([sys.executable, str(script), "--master", master], cwd=workdir, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, *texts: str, timeout: float) -> None:
        self.wait_until(lambda out: all(t in out for t in texts), f"{list(texts)}", timeout)

    def wait_until(self, printed: Callable[[str], bool], what: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not printed(self.output):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                pytest.fail(f"MAVProxy did not print {what} within {timeout} s:\n{self.output}")
            time.sleep(0.05)

    def send(self, *commands: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("".join(f"{c}\n" for c in commands))
        self.proc.stdin.flush()

    def stop(self) -> None:
        """End of input: MAVProxy exits (killed after 10 s)."""
        with contextlib.suppress(BrokenPipeError, OSError):
            assert self.proc.stdin is not None
            self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(5)
        assert self.proc.stdout is not None
        self.proc.stdout.close()


@contextlib.contextmanager
def sim_vehicle(personality: Personality) -> Iterator[str]:
    """``drona sim-vehicle`` on its SITL's link (ArduPilot: a TCP server, PX4: UDP to the ground station);
    yields MAVProxy's --master."""
    tcp = personality is ARDUPILOT
    port = free_port(socket.SOCK_STREAM if tcp else socket.SOCK_DGRAM)
    flags = ["--autopilot", personality.name, "--base-port", str(port), "--ready-after", "0.2", *(["--tcp"] * tcp)]
    proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "sim-vehicle", *flags], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        assert "sim-vehicle: system 1" in stderr_lines(proc, 1, 10)[0]
        yield f"tcp:127.0.0.1:{port}" if tcp else f"udpin:127.0.0.1:{port}"
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def shown_values(out: str) -> dict[str, str]:
    """``param show``'s lines (``NAME  value``, after any prompts) as name -> value."""
    return dict(re.findall(r"^(?:\S+> )*([A-Z][A-Z0-9_]+)\s+(-?[\d.]+)$", out, re.MULTILINE))


@BOTH
def test_mavproxy_downloads_the_parameters_and_the_mission(personality: Personality, tmp_path: Path) -> None:
    pytest.importorskip("MAVProxy", reason="MAVProxy (the dev extra) is not installed")
    ardupilot = personality is ARDUPILOT
    count = len(TABLES[personality.name])
    with sim_vehicle(personality) as master:
        mavproxy = MAVProxy(master, tmp_path)
        try:
            mavproxy.wait_for("online system 1", timeout=20)
            # Its stream rates asked again at once (MAVProxy asks every 15 s): SYS_STATUS for the fence module.
            mavproxy.send("set streamrate 5", "wp list", "fence list", "rally list")
            mission = ["Requesting 1 waypoints", "16 0 ", "Saved 1 waypoints"] if ardupilot else \
                ["Requesting 0 waypoints"]
            fence = ["fence present"] if ardupilot else []  # MAVProxy saw ArduCopter's SYS_STATUS
            mavproxy.wait_for(f"Received {count} parameters", *mission, "Requesting 0 fence items",
                              "Requesting 0 rally items", *fence, timeout=20)
            shown = ("WPNAV_SPEED", "SYSID_THISMAV") if ardupilot else ("MPC_XY_VEL_MAX", "MAV_SYS_ID")
            mavproxy.send(*(f"param show {name}" for name in shown))
            mavproxy.wait_until(lambda out: set(shown) <= set(shown_values(out)), f"{shown}'s values", timeout=5)
            time.sleep(1.0)  # whatever MAVProxy has still to say about what it received
        finally:
            mavproxy.stop()
    out = mavproxy.output
    values = shown_values(out)
    if ardupilot:
        assert (values["WPNAV_SPEED"], values["SYSID_THISMAV"]) == ("1000.0", "1.0")
        # Not anchored: under load MAVProxy's prompt may come first on the line.
        (item,) = re.findall(r"(?<!\S)16 0 (\S+) (\S+) (\S+) p1=", out)
        home = placements(None, 1)[0]
        want = home.frame.ned_to_global(home.home)
        assert [float(v) for v in item] == [pytest.approx(want.lat, abs=1e-7), pytest.approx(want.lon, abs=1e-7),
                                            pytest.approx(want.alt_m, abs=1e-3)]
        assert "fence breach" not in out
    else:  # an INT32 sent bytewise, read back as PX4's
        assert (values["MPC_XY_VEL_MAX"], values["MAV_SYS_ID"]) == ("12.0", "1")
        # (Real PX4's SYS_STATUS has no geofence bit, which MAVProxy's fence module reports as a breach.)
    assert not re.search(r"time(d)? ?out", out, re.IGNORECASE), out
    assert "Traceback" not in out
