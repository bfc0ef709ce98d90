"""Contract tests of the vehicle link against the fake vehicle (as test_link.py): refusals with their
reasons, a lost stream that comes back, a vehicle that goes silent, and nothing to connect to.
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from drona_gcs.errors import VehicleCommandRejected, VehicleError
from drona_gcs.geo import Ned
from fleet.sim.mav import mavlink2
from fleet.sim.model import VehicleModel
from fleet.sim.ports import free_port
from fleet.sim.transport import PtyLink
from fleet.vehicle.link import Readiness, Telemetry, VehicleLink, readiness
from tests.fakes.autopilot import BACKENDS, SERIAL_BAUD, FakeAutopilot, connected, fake_vehicle, run
from tests.fleet.vehicle.link_helpers import backends, personalities, transports

#: What a backend cannot show, as (backend, test, transport) -> why the test is skipped for it.
CANNOT: dict[tuple[str, str, str], str] = {
    ("mavsdk", "connecting_to_nothing", "tcp"):
        "MAVSDK's tcpout connects in the background and retries a refused connection, which it only logs: "
        "add_any_connection succeeds, so the link cannot say 'cannot open', only that no HEARTBEAT came",
}
#: How each backend reports a vehicle gone silent, by transport: MAVSDK hides a closed TCP connection
#: (its tcpout reconnects), so it sees the same missing HEARTBEATs as over UDP.
#: The silence is measured when noticed, so its figure varies with scheduling; the timeout is named as set.
NO_HEARTBEAT = r"no HEARTBEAT for \d+\.\d s \(timeout 0\.5 s\)"
SILENT_WHY = {("pymavlink", "tcp"): "connection closed by the vehicle", ("mavsdk", "tcp"): NO_HEARTBEAT,
              # The fake's end of the pseudo-terminal closes: a USB serial adapter pulled out.
              ("pymavlink", "serial"): "connection lost: device reports readiness to read but returned no data"}


def skip_if_cannot(backend: str, test: str, transport: str) -> None:
    if (reason := CANNOT.get((backend, test, transport))) is not None:
        print(f"skipped: {reason}")
        pytest.skip(reason)


# ------------------------------------------------------------------ contract: refusals
@backends
@personalities
def test_arming_before_the_position_estimate_is_refused_with_the_reason(backend: str, personality: str) -> None:
    async def scenario() -> None:
        async with fake_vehicle(personality, "udp", ready_after_s=1000.0) as fake, connected(backend, fake) as link:
            with pytest.raises(VehicleError, match="position"):  # no estimate yet
                await link.wait_ready(timeout=0.3)
            with pytest.raises(VehicleCommandRejected) as refused:
                await link.arm()
            assert refused.value.result == fake.personality.rejected
            assert "position estimate" in refused.value.reason.lower()
            assert not link.telemetry().armed

    run(scenario)


@backends
def test_before_its_position_estimate_arducopter_takes_guided_but_the_vehicle_waits_for_its_position(
        backend: str) -> None:
    """As ArduCopter SITL V4.7 does, disarmed: GUIDED is taken at once (the next HEARTBEAT says so), yet
    arming is refused; the link says the vehicle waits for its position, not that it is broken."""
    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "tcp", ready_after_s=1000.0) as fake, connected(backend, fake) as link:
            await link.set_mode("GUIDED")
            assert link.telemetry().mode == "GUIDED"
            with pytest.raises(VehicleCommandRejected, match="Need Position Estimate"):
                await link.arm()
            await link.wait_until(lambda t: t.gps_fix > 0 or t.position_ok is not None, 5, "the EKF's word")
            assert readiness(link.telemetry()) is Readiness.WAITING_FOR_POSITION

    run(scenario)


@backends
def test_a_mode_change_acked_but_not_taken_is_a_rejection(backend: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """An autopilot that ACKs a mode change and stays where it was (older ArduCopter did so before its
    position estimate): the next HEARTBEATs decide, not the ACK."""
    monkeypatch.setattr(VehicleModel, "change_mode", lambda self, base, custom, now: mavlink2.MAV_RESULT_ACCEPTED)

    async def scenario() -> None:
        async with fake_vehicle("ardupilot", "tcp") as fake, connected(backend, fake) as link:
            with pytest.raises(VehicleCommandRejected, match="stayed in STABILIZE") as refused:
                await link.set_mode("GUIDED")
            assert refused.value.result == mavlink2.MAV_RESULT_ACCEPTED
            assert link.telemetry().mode == "STABILIZE"

    run(scenario)


@backends
@personalities
def test_takeoff_while_disarmed_is_rejected_with_the_mav_result(backend: str, personality: str) -> None:
    async def scenario() -> None:
        async with fake_vehicle(personality, "tcp") as fake, connected(backend, fake) as link:
            await link.wait_ready(timeout=5)
            started = time.monotonic()
            with pytest.raises(VehicleCommandRejected, match="TAKEOFF") as refused:
                await link.takeoff(5.0)
            assert refused.value.result == fake.personality.rejected
            assert time.monotonic() - started < 2.0
            with pytest.raises(VehicleError, match="unknown mode"):
                await link.set_mode("SPORT")

    run(scenario)


# ------------------------------------------------------------------ a lost stream comes back
async def telemetry_again(link: VehicleLink, fresh: Callable[[Telemetry], bool], timeout: float) -> Telemetry:
    """Wait for ``fresh`` telemetry as the agent's supervisor does: a lost link fails at once, so
    try again after a pause (the link opens the stream again every second) until ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return await link.wait_until(fresh, max(0.1, deadline - time.monotonic()), "fresh telemetry")
        except VehicleError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)


@backends
@transports
def test_a_vehicle_lost_or_silent_comes_back_with_its_telemetry_asked_for_again(backend: str, transport: str,
                                                                               tmp_path: Path) -> None:
    """SITL restarted, a USB adapter pulled out and plugged back in, a vehicle rebooted behind UDP:
    the link fails commands while the vehicle is gone, opens a lost stream again by its name (TCP: the
    same port; serial: a by-id style link that now points at the new device; UDP loses no stream, the
    vehicle only goes silent) and asks the new vehicle, which streams nothing yet, for the telemetry
    again, however late its first HEARTBEAT. ArduCopter, as it streams nothing unasked. (MAVSDK
    reconnects TCP itself, but neither opens a serial device again nor asks for the streams again.)"""
    personality, heartbeat_timeout = "ardupilot", 1.2

    async def scenario() -> None:
        port = free_port(socket.SOCK_DGRAM if transport == "udp" else socket.SOCK_STREAM)
        by_id = tmp_path / "usb-fake-if00"
        url = {"tcp": f"tcp://127.0.0.1:{port}", "udp": f"udpin://127.0.0.1:{port}",
               "serial": f"serial://{by_id}:{SERIAL_BAUD}"}[transport]

        def point_at(fake: FakeAutopilot) -> None:
            if transport == "serial":
                assert isinstance(fake.nodes[0].link, PtyLink)
                by_id.unlink(missing_ok=True)
                by_id.symlink_to(fake.nodes[0].link.device)

        async with fake_vehicle(personality, transport, port=port) as first:
            point_at(first)
            link = BACKENDS[backend](url, heartbeat_timeout=heartbeat_timeout)
            await link.connect(timeout=5)
            try:
                await link.wait_ready(timeout=5)
                await first.silence()
                with pytest.raises(VehicleError):
                    await link.arm()
                await asyncio.sleep(heartbeat_timeout * 1.25)  # away for longer than the heartbeat timeout
                # At real speed: its first HEARTBEAT comes up to a second after the link is back, well
                # past the link's heartbeat timeout.
                async with fake_vehicle(personality, transport, port=port, speedup=1.0, ready_after_s=0.5) as second:
                    point_at(second)
                    back = time.monotonic()
                    # It streams no position until asked: a fresh one shows the streams asked for again.
                    await telemetry_again(link, lambda t: t.position is not None and t.position.at > back, 10)
                    await link.wait_ready(timeout=5)
                    await link.arm()
                    assert link.telemetry().armed
            finally:
                await link.close()

    run(scenario)


# ------------------------------------------------------------------ contract: a vehicle that goes silent
@backends
@personalities
@transports
def test_a_silent_vehicle_fails_commands_and_waits_within_the_timeout(backend: str, personality: str,
                                                                       transport: str) -> None:
    async def scenario() -> None:
        async with fake_vehicle(personality, transport) as fake, \
                connected(backend, fake, heartbeat_timeout=0.5) as link:
            await link.wait_ready(timeout=5)
            await fake.silence()
            started = time.monotonic()
            why = SILENT_WHY.get((backend, transport), NO_HEARTBEAT)
            with pytest.raises(VehicleError, match=why):
                await link.wait_until(lambda t: False, 5, "something that never comes")
            with pytest.raises(VehicleError, match=why):
                await link.arm()
            assert time.monotonic() - started < 1.5
            with pytest.raises(VehicleError):
                await link.send_position_target(Ned(0, 0, -1))

    run(scenario)


@backends
@transports
def test_connecting_to_nothing_fails_cleanly(backend: str, transport: str) -> None:
    skip_if_cannot(backend, "connecting_to_nothing", transport)

    async def scenario() -> None:
        url = {"tcp": f"tcp://127.0.0.1:{free_port(socket.SOCK_STREAM)}",
               "udp": f"udpin://127.0.0.1:{free_port(socket.SOCK_DGRAM)}",
               "serial": "serial:///dev/drona-test-no-such-port:57600"}[transport]
        link = BACKENDS[backend](url)
        why = "waited 0.3 s for a HEARTBEAT" if transport == "udp" else "cannot open"
        with pytest.raises(VehicleError, match=why):
            await link.connect(timeout=0.3)
        await link.close()

    run(scenario)
