"""How an agent process spreads its drones over Zenoh sessions, where each session listens, and whose
MAVLink 2 signing key each of its vehicles gets."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest
from pydantic import ValidationError

from drona_gcs.geo import GeoFrame
from drona_gcs.workspace_files import load_workspace
from fleet.agent.host import Host, install_signals, open_link, session_groups, zenoh_settings
from fleet.agent.settings import AgentSettings
from fleet.cli import main
from fleet.sim.ports import free_port, free_udp_base
from fleet.transport.settings import agent_endpoint
from fleet.vehicle.signing import SigningKeyError
from tests.integration.harness import DRONA, workspace_yaml


@pytest.fixture()
def ws_file(tmp_path: Path) -> Path:
    path = tmp_path / "ws.yaml"
    path.write_text(workspace_yaml(4))
    return path


def sessions(ws_file: Path, **flags: object) -> list[tuple[list[str], tuple[str, ...], tuple[str, ...]]]:
    """(drones, listen, connect) of every session the process would open for drones d2 and d3."""
    # Plain TCP: a shared session has no one drone's identity (the endpoints are what is tested here).
    settings = AgentSettings.model_validate({"workspace": ws_file, "drone": "d2", "count": 2, "tls_dir": None,
                                             "insecure": True, **flags})
    ws, names = load_workspace(ws_file), ["d2", "d3"]
    out = []
    for group in session_groups(settings, names):
        zs = zenoh_settings(settings, ws, group, names.index(group[0]))
        out.append((group, zs.listen, zs.connect))
    return out


def test_each_hosted_drone_has_its_own_session_by_default(ws_file: Path) -> None:
    """As on a real fleet: d2 and d3 each listen on their own endpoint and connect to every other drone's,
    each other's included."""
    assert sessions(ws_file) == [
        (["d2"], (agent_endpoint(1),), tuple(agent_endpoint(i) for i in (0, 2, 3))),
        (["d3"], (agent_endpoint(2),), tuple(agent_endpoint(i) for i in (0, 1, 3))),
    ]


def test_a_shared_session_listens_for_every_hosted_drone_and_connects_only_outside(ws_file: Path) -> None:
    assert sessions(ws_file, shared_session=True) == [
        (["d2", "d3"], (agent_endpoint(1), agent_endpoint(2)), (agent_endpoint(0), agent_endpoint(3))),
    ]


@pytest.mark.parametrize("shared", [False, True])
def test_explicit_endpoints_give_the_ith_hosted_drone_the_port_i_up(ws_file: Path, shared: bool) -> None:
    found = sessions(ws_file, shared_session=shared, listen=["tcp/127.0.0.1:9000"], connect=["tcp/127.0.0.1:9000"])
    listening = [ep for _, listen, _ in found for ep in listen]
    assert listening == ["tcp/127.0.0.1:9000", "tcp/127.0.0.1:9001"]
    # Nobody connects to its own endpoint; the second drone's session reaches the first's.
    for _, listen, connect in found:
        assert not set(listen) & set(connect)
    if not shared:
        assert found[1][2] == ("tcp/127.0.0.1:9000",)


# ------------------------------------------------------------------ MAVLink 2 signing keys
KEY, OTHER = bytes(range(32)).hex(), bytes(range(1, 33)).hex()


def test_a_key_file_with_one_key_signs_the_one_drone(ws_file: Path, tmp_path: Path) -> None:
    keys = tmp_path / "key"
    keys.write_text(f"# d1's radio\n{KEY}\n")
    settings = AgentSettings(workspace=ws_file, signing_key_file=keys)
    assert settings.signing_keys(["d1"]) == {"d1": bytes.fromhex(KEY)}
    with pytest.raises(SigningKeyError, match="one key, for one drone"):
        settings.signing_keys(["d1", "d2"])


def test_a_fleet_key_file_gives_each_hosted_drone_its_own_line(ws_file: Path, tmp_path: Path) -> None:
    keys = tmp_path / "fleet.keys"
    keys.write_text(f"d1 {OTHER}\nd2 {KEY}\n\nd3 {OTHER}\n")
    settings = AgentSettings(workspace=ws_file, drone="d2", count=2, signing_key_file=keys)
    assert settings.signing_keys(["d2", "d3"]) == {"d2": bytes.fromhex(KEY), "d3": bytes.fromhex(OTHER)}
    with pytest.raises(SigningKeyError, match="no key for d4"):
        settings.signing_keys(["d3", "d4"])


def test_a_bad_key_is_refused_without_being_quoted(ws_file: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    secret = KEY[:-2]  # a byte short
    keys = tmp_path / "fleet.keys"
    keys.write_text(f"d1 {secret}\n")
    with pytest.raises(SigningKeyError, match="32 bytes") as found:
        AgentSettings(workspace=ws_file, signing_key_file=keys).signing_keys(["d1"])
    monkeypatch.setenv("DRONA_SIGNING_KEY", secret)
    with pytest.raises(ValidationError, match="DRONA_SIGNING_KEY: a signing key is 32 bytes") as invalid:
        AgentSettings(workspace=ws_file)
    assert secret not in str(found.value) and secret not in str(invalid.value)


def test_the_environments_key_is_one_vehicles(ws_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DRONA_SIGNING_KEY", KEY)
    assert AgentSettings(workspace=ws_file, drone="d3").signing_keys(["d3"]) == {"d3": bytes.fromhex(KEY)}
    with pytest.raises(ValidationError, match="with --count > 1 give each drone its own"):
        AgentSettings(workspace=ws_file, count=2)
    keys = tmp_path / "key"
    keys.write_text(KEY)
    with pytest.raises(ValidationError, match="not both"):
        AgentSettings(workspace=ws_file, signing_key_file=keys)


def test_without_a_key_nothing_is_signed(ws_file: Path) -> None:
    assert AgentSettings(workspace=ws_file, count=2).signing_keys(["d1", "d2"]) == {}


def test_the_mavsdk_backend_refuses_a_signing_key_rather_than_fly_unsigned(ws_file: Path) -> None:
    settings = AgentSettings(workspace=ws_file, backend="mavsdk")
    frame = GeoFrame(load_workspace(ws_file))
    try:
        import fleet.vehicle.mavsdk_link  # noqa: F401
    except Exception as exc:  # no package, or its native library does not load here
        pytest.skip(f"MAVSDK cannot run here: {type(exc).__name__}: {exc}")
    with pytest.raises(SigningKeyError, match="mavsdk backend cannot sign"):
        open_link(settings, "udpin://127.0.0.1:14540", frame, bytes.fromhex(KEY))


def test_an_agent_with_its_key_file_flies_a_signed_sim_vehicle(ws_file: Path, tmp_path: Path) -> None:
    """`drona agent --signing-key-file` against `drona sim-vehicle --signing-key`: it connects (its
    telemetry requests signed and acknowledged), joins and says so, and leaves cleanly."""
    keys, log = tmp_path / "key", tmp_path / "agent.log"
    keys.write_text(f"{KEY}\n")
    base, listen = free_udp_base(1), free_port(socket.SOCK_STREAM)
    sim = subprocess.Popen([*DRONA, "sim-vehicle", "--workspace", str(ws_file), "--base-port", str(base),
                            "--speedup", "6", "--ready-after", "0.5", "--signing-key", KEY],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with log.open("wb") as out:
        agent = subprocess.Popen([*DRONA, "agent", "--workspace", str(ws_file), "--drone", "d1",
                                  "--vehicle", f"udpin://127.0.0.1:{base}", "--signing-key-file", str(keys),
                                  "--fleet", f"sign-{listen}", "--listen", f"tcp/127.0.0.1:{listen}"],
                                 stdout=subprocess.DEVNULL, stderr=out)
    try:
        deadline = time.monotonic() + 30
        while b"d1 flying" not in log.read_bytes() and agent.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert b"d1 flying" in log.read_bytes(), log.read_text(errors="replace")
    finally:
        for process in (agent, sim):
            process.send_signal(signal.SIGINT)
        time.sleep(0.2)
        agent.send_signal(signal.SIGINT)  # a second one: leave now, no landing to wait for
        codes = [_wait(process) for process in (agent, sim)]
    assert codes == [0, 0], log.read_text(errors="replace")


def test_an_agent_refuses_a_vehicle_set_slower_than_the_workspace_naming_the_parameter(ws_file: Path) -> None:
    """The workspace's ArduCopters at 6 times real time accelerate at 90 m/s² on the wall clock: its
    lambda counts on it. A vehicle whose WPNAV_ACCEL was set by hand to 1 m/s² (36 at that speedup) is
    refused once connected, its agent exiting with the parameter named."""
    base, listen = free_udp_base(1), free_port(socket.SOCK_STREAM)
    sim = subprocess.Popen([*DRONA, "sim-vehicle", "--workspace", str(ws_file), "--base-port", str(base),
                            "--speedup", "6", "--ready-after", "0.5", "--param", "WPNAV_ACCEL=100"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        agent = subprocess.run([*DRONA, "agent", "--workspace", str(ws_file), "--drone", "d1",
                                "--vehicle", f"udpin://127.0.0.1:{base}", "--fleet", f"slow-{listen}",
                                "--listen", f"tcp/127.0.0.1:{listen}"], capture_output=True, text=True, timeout=60,
                               check=False)
    finally:
        sim.send_signal(signal.SIGINT)
        _wait(sim)
    assert agent.returncode == 2, agent.stderr[-2000:]
    assert ("drone d1: its vehicle flies less than the workspace's vehicle limits, which lambda is derived from: "
            "WPNAV_ACCEL 100 gives 36, under the workspace's vehicle.accel_m_s2 90") in agent.stderr, agent.stderr


def _wait(process: subprocess.Popen[bytes]) -> int | None:
    try:
        return process.wait(15)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(5)
        return None


def test_an_agent_started_before_its_vehicle_waits_for_it(ws_file: Path, tmp_path: Path) -> None:
    """A vehicle not up yet (ArduCopter SITL started after the agent, or resetting the connection while
    it boots) is waited for: the agent joins once it answers, instead of exiting."""
    log, port, listen = tmp_path / "agent.log", free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    with log.open("wb") as out:
        agent = subprocess.Popen([*DRONA, "agent", "--workspace", str(ws_file), "--drone", "d1",
                                  "--vehicle", f"tcp://127.0.0.1:{port}", "--fleet", f"late-{listen}",
                                  "--listen", f"tcp/127.0.0.1:{listen}"], stdout=subprocess.DEVNULL, stderr=out)
    sim: subprocess.Popen[bytes] | None = None
    try:
        assert _log_says(log, agent, b"no vehicle yet", 20), log.read_text(errors="replace")
        sim = subprocess.Popen([*DRONA, "sim-vehicle", "--workspace", str(ws_file), "--tcp", "--base-port", str(port),
                                "--speedup", "6", "--ready-after", "0.5"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        assert _log_says(log, agent, b"d1 flying", 30), log.read_text(errors="replace")
    finally:
        processes = [agent] if sim is None else [agent, sim]
        for process in processes:
            process.send_signal(signal.SIGINT)
        time.sleep(0.2)
        agent.send_signal(signal.SIGINT)
        codes = [_wait(process) for process in processes]
    assert codes == [0, 0], log.read_text(errors="replace")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_agent_waiting_for_its_vehicle_leaves_on_a_signal(ws_file: Path, tmp_path: Path, sig: int) -> None:
    """Found flying SITL: agents waiting for a vehicle that never came ignored Ctrl-C and SIGTERM (the signal
    only asked them to land what flies). Nothing flies yet: they leave at once, and cleanly, however often
    the signal comes (one after the fleet had left killed the process: exit -2, found in the suite)."""
    log, port, listen = tmp_path / "agent.log", free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    with log.open("wb") as out:
        agent = subprocess.Popen([*DRONA, "agent", "--workspace", str(ws_file), "--drone", "d1",
                                  "--vehicle", f"tcp://127.0.0.1:{port}", "--fleet", f"gone-{listen}",
                                  "--listen", f"tcp/127.0.0.1:{listen}"], stdout=subprocess.DEVNULL, stderr=out)
    try:
        assert _log_says(log, agent, b"no vehicle yet", 20), log.read_text(errors="replace")
        for _ in range(500):  # until it has exited
            if agent.poll() is not None:
                break
            agent.send_signal(sig)
            time.sleep(0.01)
        assert _wait(agent) == 0, log.read_text(errors="replace")
    finally:
        agent.kill()


def _log_says(log: Path, process: subprocess.Popen[bytes], text: bytes, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while text not in log.read_bytes() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    return text in log.read_bytes()


def test_a_system_clock_stepped_on_signal_is_shifted_from_the_signal_on_and_the_fleet_clock_takes_it_up(
        ws_file: Path) -> None:
    """`--clock-step-on-signal`: the system clock is true until SIGUSR1, then off by `--clock-offset` (the
    fault bench steps a drone's clock in flight so); the drones' schedule clock does not step with it.
    Without the flag the offset is there from the start, in both."""
    settings = AgentSettings.model_validate({"workspace": ws_file, "drone": "d1", "tls_dir": None, "insecure": True,
                                             "clock_offset_s": 7.0, "clock_step_on_signal": True})
    host = Host(settings, load_workspace(ws_file), ["d1"])

    async def offsets() -> list[tuple[float, float]]:
        install_signals(host)
        before = (host._system_clock() - time.time(), host.clock() - time.time())
        os.kill(os.getpid(), signal.SIGUSR1)
        await asyncio.sleep(0.05)  # the loop runs the handler on its next turn
        return [before, (host._system_clock() - time.time(), host.clock() - time.time())]

    (system_before, fleet_before), (system_after, fleet_after) = asyncio.run(offsets())
    assert abs(system_before) < 0.01 and abs(system_after - 7.0) < 0.01, (system_before, system_after)
    assert abs(fleet_before) < 0.01 and abs(fleet_after) < 0.01, (fleet_before, fleet_after)
    without = Host(settings.model_copy(update={"clock_step_on_signal": False}), host.workspace, ["d1"])
    assert abs(without.clock() - time.time() - 7.0) < 0.01


def test_an_agent_refuses_a_workspace_its_vehicles_cannot_fly_naming_the_limit(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """1 m cells every 0.5 s need 4 m/s² to cross half a cell from rest in a tau; ArduCopter's default
    WPNAV_ACCEL is 2.5 m/s². Refused before any vehicle or session is touched."""
    slow = tmp_path / "slow.yaml"
    slow.write_text("size: [4, 4, 1]\ncell_size_m: 1.0\ntau_s: 0.5\ndrones: {d1: [1, 1, 0]}\n")
    assert main(["agent", "--workspace", str(slow)]) == 2
    assert ("drona agent: " in (err := capsys.readouterr().err) and "vehicle.accel_m_s2: 2.5 m/s² cannot fly 1 m a "
            "tau (0.5 s), which needs 4.00 m/s²" in err), err
