"""A partition over real processes: agents on two hosts (network namespaces the test makes), cut and healed.

Host ``a`` flies d1 and d2, host ``b`` flies d3, each drone's vehicle on its own host; each host runs a
`drona router`, whose Zenoh clients its agents are, joined to the other's across a bridge in the test's
namespace, where the observer (as the service would) reaches both. The link of host ``b`` goes down while
d3 flies, and comes back. The majority side delivers meanwhile; the cut-off drone plans nothing new; the
flight record audits clean.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx
import pytest

from fleet.transport.wire import MailOrder, MailStatus
from tests.integration.harness import FleetProcesses, Observer
from tests.integration.hosts import Hosts, network_hosts
from tests.integration.runs import check_run_record
from tests.integration.test_service_fleet import HEADERS, TOKEN, Events


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    with network_hosts(["a", "b"]) as made:
        yield made


LEASE_S = 2.0  #: the agents' and routers' Zenoh lease: a cut link is seen within it


def _settled(statuses: list[MailStatus]) -> bool:
    """Delivered, or handed back by the drone that took it over."""
    return MailStatus.DELIVERED in statuses or (MailStatus.REASSIGNED in statuses
                                                and statuses[-1] in (MailStatus.REJECTED, MailStatus.HANDED_BACK))


def _logged_at(line: str) -> float:
    """The time a log line of an agent's was written (its clock is this host's)."""
    return datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()


def test_a_partition_puts_no_two_drones_in_one_cell_and_the_majority_delivers(tmp_path: Path, hosts: Hosts) -> None:
    side = {"d1": "a", "d2": "a", "d3": "b"}
    fleet = FleetProcesses(tmp_path, list(side), agent_options=("--lease", str(LEASE_S)), hosts=hosts, host_of=side,
                           routers=True)
    # d3 parks at (0, 6): its mail keeps to that corner, which it may hold for good while it is gone (it
    # may have stopped anywhere on its way); the others' mail keeps clear of it.
    before = MailOrder(id="before", pickup=[1, 8, 0], dropoff=[3, 9, 0], priority=1)
    during = [MailOrder(id="during1", pickup=[2, 1, 0], dropoff=[8, 2, 0], priority=9),
              MailOrder(id="during2", pickup=[7, 1, 0], dropoff=[8, 8, 0], priority=9)]
    fleet.start()
    try:
        async def scenario() -> tuple[Observer, float, float]:
            async with Observer(fleet, lease_s=LEASE_S) as obs:
                await obs.parked()
                # Given before the cut: a query to a live drone may wait on the cut link until the
                # session's own lease runs out, and time out.
                await obs.give(before, "d3")
                for order, drone in zip(during, ("d1", "d2"), strict=True):
                    await obs.give(order, drone)
                await obs.until(lambda: MailStatus.STARTED in obs.statuses("before"), 30, "d3 under way")
                hosts.cut("b")  # d3 flies on, cut off
                await obs.until(lambda: "d3" not in obs.alive, 15, "d3's liveliness to go")
                apart = time.time() + LEASE_S  # by then d3 has seen its peers go too
                await obs.until(lambda: obs.delivered([o.id for o in during]), 90, "the majority to deliver")
                healed = time.time()
                hosts.heal("b")
                await obs.until(lambda: "d3" in obs.alive, 30, "d3 back")
                await obs.until(lambda: _settled(obs.statuses("before")), 90, "d3's mail settled")
                return obs, apart, healed

        obs, apart, healed = asyncio.run(scenario())
        # One owner: d3, cut off, handed it back before picking it up; d1 took it over (a lease after d3
        # left): delivered once, or handed back again (its pickup on d3's way, held for good). Never both.
        statuses = obs.statuses("before")
        assert statuses.count(MailStatus.DELIVERED) <= 1 and MailStatus.FAILED not in statuses, statuses
        assert [r.drone for r in obs.reports if r.id == "before" and r.status is MailStatus.REASSIGNED] == ["d1"]
        audit = check_run_record(fleet)
        assert audit.safe
        # Cut off from most of the fleet, d3 flew the plan it had, planned nothing and handed its mail back.
        cut_off = (tmp_path / "d3.log").read_text().splitlines()
        planned = [line for line in cut_off if "planned from step" in line and apart < _logged_at(line) < healed]
        noticed = any("no majority" in line or "cut off from most of the fleet" in line for line in cut_off)
        assert not planned and noticed, "\n".join(cut_off[-40:])
    finally:
        fleet.kill_all()


def test_under_drona_serve_a_partition_leaves_every_mail_one_owner_and_nothing_failed_then_delivered(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The service on a host of its own with d3, the majority (d1, d2) cut off from both. d1 carries a
    mail, d2 flies to another's pickup (started: cleared for pickup), a third waits behind one of them.
    The service holds the first two as their drones' through the cut; the third, not cleared, it
    requeues, and the drone hands it back when it sees the service go. Healed: what the drones did
    meanwhile reaches the service, and every mail is picked up by one drone, once."""
    with network_hosts(["a", "b", "s"]) as hosts:
        side = {"d1": "a", "d2": "a", "d3": "b"}
        fleet = FleetProcesses(tmp_path, list(side), agent_options=("--lease", str(LEASE_S), "--no-adopt-mail"),
                               hosts=hosts, host_of=side, routers=True)
        fleet.start()
        try:
            fleet.add_router("s")
            monkeypatch.setenv("DRONA_API_SSE_PING_S", "1")  # the test's event stream reads every second
            url = _serve(fleet, hosts, tmp_path / "mail.db")
            events = Events(url)
            events.until(lambda: {"d1", "d2", "d3"} <= set(events.drones), 60, "every drone", fleet.logs)
            _post(url, "/v1/fleet/drones/d3/recall")  # held: the mail goes to the side that is cut off
            orders = [([0, 3, 0], [9, 3, 0], 9), ([8, 8, 0], [8, 1, 0], 5), ([8, 7, 0], [2, 8, 0], 1)]
            carried, far, third = (_post(url, "/v1/mail", {"pickup": p, "dropoff": d, "priority": n})["id"]
                                   for p, d, n in orders)
            events.until(lambda: events.status(carried) == "picked_up", 60, "the first mail on board", fleet.logs)
            holders = [_get(url, f"/v1/mail/{mail}")["drone"] for mail in (carried, far, third)]
            assert holders[:2] == ["d1", "d2"] and holders[2] in ("d1", "d2"), holders
            hosts.cut("a")
            events.until(lambda: events.status(third) == "queued", 30, "the mail not cleared requeued", fleet.logs)
            time.sleep(15)  # the partition's length: d1 and d2, a majority, fly on
            hosts.heal("a")
            _post(url, "/v1/fleet/drones/d3/resume")
            mails = (carried, far, third)
            events.until(lambda: all(events.status(m) == "delivered" for m in mails), 150, "every mail delivered",
                         fleet.logs)
            for mail in mails:
                history = _get(url, f"/v1/mail/{mail}")["history"]
                assert "failed" not in [h["status"] for h in history], history
                logs = [(tmp_path / f"{d}.log").read_text() for d in side]
                assert sum(log.count(f"mail {mail} picked_up") for log in logs) == 1, mail
            requeued = [h for h in _get(url, f"/v1/mail/{third}")["history"] if h["status"] == "queued"][1]
            assert f"drone {holders[2]} was lost before the pickup" in requeued["reason"], requeued
            handed = f"mail {third} rejected (out of touch with the service)"
            assert handed in (tmp_path / f"{holders[2]}.log").read_text()
            assert check_run_record(fleet).safe
        finally:
            fleet.kill_all()


def _serve(fleet: FleetProcesses, hosts: Hosts, db: Path) -> str:
    """`drona serve` on host ``s``, a client of its router; its URL once it answers."""
    ip, port = hosts.ip["s"], 8000
    fleet.spawn("serve", ["serve", "--workspace", str(fleet.workspace), "--db", str(db), "--host", ip,
                          "--port", str(port), "--demo", "--token", TOKEN, "--fleet", fleet.fleet,
                          "--log-level", "info", "--zenoh-config", str(fleet.client_config),
                          "--connect", f"tcp/{ip}:{fleet.router_port}"], host="s")
    url = f"http://{ip}:{port}"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:  # the port answers once uvicorn is up: nothing to wait on but it
        with contextlib.suppress(httpx.TransportError):
            if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                return url
        time.sleep(0.2)
    raise AssertionError(f"the service did not come up\n{fleet.logs()}")


def _post(url: str, path: str, body: dict[str, object] | None = None) -> dict[str, Any]:
    res = httpx.post(f"{url}{path}", headers=HEADERS, json=body, timeout=30)
    assert res.status_code in (200, 201, 202), res.text
    result: dict[str, Any] = res.json()
    return result


def _get(url: str, path: str) -> Any:
    res = httpx.get(f"{url}{path}", headers=HEADERS, timeout=10)
    assert res.status_code == 200, res.text
    return res.json()
