"""A fleet of agents in separate processes, with the defaults (mutual TLS, access control), while rogue
Zenoh clients on the same network try every forgery of issue 26: answers and plans claiming to be a
drone, liveliness tokens, mail orders and mail statuses. Judged as every fleet run is: the flight
record audits clean and every mail is delivered, in priority order; and nothing forged reached anyone.
"""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import pytest
import zenoh

from drona_gcs.motion import Trajectory
from drona_gcs.stack.messages import TaskId
from fleet.transport.identity import make_certs
from fleet.transport.keys import FleetKeys
from fleet.transport.settings import ZenohSettings
from fleet.transport.wire import MailOrder, MailStatus, MailStatusReport, PlanAnnounce, WireTrajectory, answers, encode
from tests.conftest import fleet_tls_dir
from tests.integration.harness import FleetProcesses
from tests.integration.runs import check_run, deliver_all, random_orders

pytestmark = pytest.mark.slow

ROGUES = {  # who tries, and with what identity
    "no certificate": None,
    "another CA's certificate of d2": "foreign",
    "a fleet CA certificate of a drone not in the fleet": "fleet",
}
PERIOD_S = 0.1
FORGED_STEP = 1  #: the step the rogues' reports carry: no agent's step is that small


class Rogue(threading.Thread):
    """One Zenoh session that forges, every PERIOD_S, until stopped; it counts what it hears."""

    def __init__(self, fleet: FleetProcesses, tls_dir: Path | None, name: str) -> None:
        super().__init__(daemon=True)
        self.keys = FleetKeys(fleet.fleet)
        connect = tuple(fleet.endpoint(d) for d in fleet.drones)
        plain = ZenohSettings(connect=connect)
        settings = plain.secured(tls_dir, name, self.keys, None) if tls_dir else plain
        self.config = settings.config()
        self.stop = threading.Event()
        self.heard = 0
        self.sent = 0
        self.errors: list[str] = []

    def run(self) -> None:
        try:
            session = zenoh.open(self.config)
        except zenoh.ZError as exc:  # a client refused at the handshake may not even open
            self.errors.append(str(exc))
            return
        # Only what comes from elsewhere: a session hears its own puts too.
        subscriber = session.declare_subscriber(f"{self.keys.root}/**", self._heard,
                                                allowed_origin=zenoh.Locality.REMOTE)
        token = session.liveliness().declare_token(self.keys.alive("d2"))
        try:
            while not self.stop.wait(PERIOD_S):
                self._forge(session)
        finally:
            token.undeclare()  # type: ignore[no-untyped-call]
            subscriber.undeclare()  # type: ignore[no-untyped-call]
            session.close()  # type: ignore[no-untyped-call]

    def _heard(self, sample: zenoh.Sample) -> None:
        self.heard += 1

    def _forge(self, session: zenoh.Session) -> None:
        keys, parked = self.keys, Trajectory(0, ((9, 9, 0),))
        lie = answers(parked, {d: TaskId(1, d, s) for d in ("d1", "d3", "d4") for s in (1,)})
        session.put(keys.answers("d2"), encode("d2", 0.0, lie))
        session.put(keys.plan("d2"), encode("d2", 0.0, PlanAnnounce(trajectory=WireTrajectory.of(parked))))
        for mail in ("m0", "ghost"):
            report = MailStatusReport(id=mail, drone="d2", status=MailStatus.DELIVERED, step=FORGED_STEP)
            session.put(keys.status("d2", mail), encode("d2", 0.0, report))
        order = MailOrder(id="forged", pickup=[1, 1, 0], dropoff=[8, 8, 0], priority=9)
        replies = list(session.get(keys.assign("d1"), payload=encode("service", 0.0, order), timeout=0.05))
        self.heard += sum(1 for r in replies if r.ok is not None)
        self.sent += 1


def test_rogue_clients_steer_nothing_and_the_flight_audits_clean(tmp_path: Path) -> None:
    fleet = FleetProcesses(tmp_path, ["d1", "d2", "d3", "d4"])
    orders = random_orders(8, seed=26, fleet=fleet)
    make_certs(tmp_path / "foreign", ["d2"])
    rogues = {who: Rogue(fleet, {None: None, "foreign": tmp_path / "foreign", "fleet": fleet_tls_dir()}[kind],
                         "d2" if kind == "foreign" else "d99")
              for who, kind in ROGUES.items()}
    fleet.start()
    try:
        for rogue in rogues.values():
            rogue.start()
        obs = asyncio.run(deliver_all(fleet, orders, timeout=150))
        for rogue in rogues.values():
            rogue.stop.set()
            rogue.join(30)
        check_run(fleet, obs, orders)
        for who, rogue in rogues.items():
            assert rogue.heard == 0, f"{who}: heard {rogue.heard} samples or replies from the fleet"
            assert rogue.sent > 10 or rogue.errors, f"{who}: tried only {rogue.sent} times"
        assert "forged" not in {r.id for r in obs.reports} and "ghost" not in {r.id for r in obs.reports}
        # d2 may deliver mail it took over from a late drone: what it delivers, it picked up first.
        assert all(r.step != FORGED_STEP for r in obs.reports)
        picked: set[str] = set()
        for report in (r for r in obs.reports if r.drone == "d2"):
            if report.status is MailStatus.PICKED_UP:
                picked.add(report.id)
            assert report.status is not MailStatus.DELIVERED or report.id in picked, report
        logs = fleet.logs()
        assert "forged" not in logs
    finally:
        for rogue in rogues.values():
            rogue.stop.set()
        fleet.kill_all()
