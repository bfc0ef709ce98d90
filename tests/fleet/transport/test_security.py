"""Who may say what on the fleet's Zenoh network: real sessions on 127.0.0.1, mutual TLS and access control.

Each test opens d1's session as an agent opens it (``ZenohSettings.secured``), and others as a
rogue would: without a certificate, with one of another CA, or with a fleet certificate used to
write another's keys. A forgery is known not to have arrived when a message the same session sent
after it on the same link has (Zenoh keeps a link's order); every wait is bounded.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh

from api.gateway import MailStatusReport
from drona_gcs.geo import GeoFrame
from drona_gcs.motion import Trajectory
from drona_gcs.planner import SafePlanner
from drona_gcs.stack.drone import DroneStack, StackConfig
from drona_gcs.stack.messages import TaskId
from drona_gcs.workspace import Workspace
from fleet.agent.drone import DroneAgent
from fleet.sim.ports import free_port
from fleet.transport.gateway import ZenohGateway
from fleet.transport.identity import SERVICE, IdentityError, Speakers, access_control, identity_for, make_certs
from fleet.transport.keys import FleetKeys
from fleet.transport.node import ZenohNode
from fleet.transport.settings import ZenohSettings
from fleet.transport.wire import MailStatus, answers, encode
from fleet.transport.wire import MailStatusReport as WireReport
from tests.conftest import fleet_tls_dir
from tests.fakes.node import FakeNode
from tests.fakes.vehicle import FakeVehicle

KEYS = FleetKeys("sec")
DRONES = ["d1", "d2", "d3"]
WAIT_S = 10.0
REFUSED_S = 3.0  #: a fleet's sessions link and route within a second here


class Inbox:
    """What a subscriber got, by key, with a bounded wait for a key."""

    def __init__(self) -> None:
        self.keys: list[str] = []
        self.changed = threading.Condition()

    def add(self, key: str) -> None:
        with self.changed:
            self.keys.append(key)
            self.changed.notify_all()

    def wait_for(self, key: str, timeout: float = WAIT_S) -> bool:
        with self.changed:
            return self.changed.wait_for(lambda: key in self.keys, timeout)


@contextmanager
def session(name: str, *, listen: str | None = None, connect: str | None = None,
            tls_dir: Path | None = None, secure: bool = True) -> Iterator[_Tracked]:
    plain = ZenohSettings(listen=(listen,) if listen else (), connect=(connect,) if connect else ())
    settings = plain.secured(tls_dir or fleet_tls_dir(), name, KEYS, DRONES) if secure else plain
    opened = zenoh.open(settings.config())
    declared: list[Any] = []
    try:
        yield _Tracked(opened, declared)
    finally:
        for declaration in reversed(declared):
            declaration.undeclare()
        opened.close()  # type: ignore[no-untyped-call]


class _Tracked:
    """A session whose declarations are undeclared before it closes (a live one hangs the interpreter)."""

    def __init__(self, session: zenoh.Session, declared: list[Any]) -> None:
        self.session, self.declared = session, declared

    def __getattr__(self, name: str) -> Any:
        return getattr(self.session, name)

    def subscribe(self, key: str, inbox: Inbox) -> None:
        self.declared.append(self.session.declare_subscriber(key, lambda s: inbox.add(str(s.key_expr))))

    def watch_tokens(self, key: str, inbox: Inbox) -> None:
        self.declared.append(self.session.liveliness().declare_subscriber(key, lambda s: inbox.add(str(s.key_expr))))

    def token(self, key: str) -> None:
        self.declared.append(self.session.liveliness().declare_token(key))

    def serve(self, key: str, reply: Callable[[zenoh.Query], None]) -> None:
        self.declared.append(self.session.declare_queryable(key, reply))


def _until(put: Callable[[], None], inbox: Inbox, key: str, timeout: float = WAIT_S) -> bool:
    """Put until ``key`` arrives (the link is up and routes are known): bounded."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        put()
        if inbox.wait_for(key, 0.2):
            return True
    return False


def _endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"


@pytest.fixture
def d1() -> Iterator[tuple[_Tracked, Inbox, str]]:
    """Drone d1's session, listening, with every fleet key subscribed."""
    endpoint, inbox = _endpoint(), Inbox()
    with session("d1", listen=endpoint) as node:
        node.subscribe(f"{KEYS.root}/**", inbox)
        yield node, inbox, endpoint


def test_the_fleet_links_over_mutual_tls_with_access_control(d1: tuple[_Tracked, Inbox, str]) -> None:
    _, inbox, endpoint = d1
    with session("d2", connect=endpoint) as d2:
        assert _until(lambda: d2.put(KEYS.plan("d2"), b"mine"), inbox, KEYS.plan("d2"))


@pytest.mark.parametrize("who", ["no certificate", "another CA's certificate"])
def test_a_stranger_gets_no_link(d1: tuple[_Tracked, Inbox, str], tmp_path: Path, who: str) -> None:
    _, inbox, endpoint = d1
    foreign = tmp_path / "foreign"
    make_certs(foreign, ["d2"])
    with session("d2", connect=endpoint, tls_dir=foreign, secure=who != "no certificate") as rogue:
        forge = lambda: rogue.put(KEYS.proto("d1", "d2"), b"forged")  # noqa: E731
        assert not _until(forge, inbox, KEYS.proto("d1", "d2"), REFUSED_S)
    assert inbox.keys == []


def test_a_fleet_member_writes_only_its_own_keys(d1: tuple[_Tracked, Inbox, str]) -> None:
    """d3 holds a fleet certificate: what it says as d2 is refused by d1's session itself."""
    node, inbox, endpoint = d1
    tokens = Inbox()
    node.watch_tokens(KEYS.alive(), tokens)
    forged = [KEYS.proto("d1", "d2"), KEYS.proto("all", "d2"), KEYS.answers("d2"), KEYS.plan("d2"), KEYS.state("d2"),
              KEYS.held("d2"), KEYS.status("d2", "m1"), f"{KEYS.root}/mail/status/m1"]
    with session("d3", connect=endpoint) as d3:
        assert _until(lambda: d3.put(KEYS.plan("d3"), b"mine"), inbox, KEYS.plan("d3"))
        d3.token(KEYS.alive("d2"))
        for key in forged:
            d3.put(key, b"forged")
        d3.token(KEYS.alive("d3"))
        d3.put(KEYS.state("d3"), b"after the forgeries")
        assert inbox.wait_for(KEYS.state("d3")) and tokens.wait_for(KEYS.alive("d3"))
    assert set(inbox.keys) == {KEYS.plan("d3"), KEYS.state("d3")}
    assert KEYS.alive("d2") not in tokens.keys


def test_only_the_service_gives_mail(d1: tuple[_Tracked, Inbox, str]) -> None:
    node, _, endpoint = d1
    asked: list[str] = []

    def answer(query: zenoh.Query) -> None:
        asked.append(str(query.key_expr))
        query.reply(KEYS.assign("d1"), b"ack")

    node.serve(KEYS.assign("d1"), answer)

    def replies(name: str) -> int:
        with session(name, connect=endpoint) as asker:
            deadline = time.monotonic() + WAIT_S
            while time.monotonic() < deadline:
                got = [r for r in asker.get(KEYS.assign("d1"), payload=b"order", timeout=0.5) if r.ok is not None]
                if got or name != SERVICE:
                    return len(got)
            return 0

    assert replies("d3") == 0 and asked == []
    assert replies(SERVICE) == 1 and len(asked) == 1


def test_the_access_control_names_each_drone_only_on_its_own_keys() -> None:
    acl = access_control(KEYS, DRONES)
    for drone in DRONES:
        own = [r for r in acl["rules"] if r["id"].startswith(f"{drone}-")]
        assert own and all(KEYS.writer(key) == drone for rule in own for key in rule["key_exprs"])
    assert acl["default_permission"] == "deny"


# ------------------------------------------------------------------ bounds on what a peer may say
WS = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0), "d2": (7, 0, 0)})


def _agent() -> tuple[DroneAgent, DroneStack]:
    stack = DroneStack("d1", StackConfig(WS, SafePlanner(WS)), dict(WS.drones))
    agent = DroneAgent(stack, FakeNode(), KEYS, FakeVehicle(GeoFrame(WS), (0, 0, 0)), GeoFrame(WS), lambda: 1000.0)
    agent.tick(0)
    return agent, stack


OUTSIDE = {"a cell outside": (8, 0, 0), "a cell beyond y": (7, 8, 0), "a cell below": (7, 0, -1),
           "a cell above": (7, 0, 1)}


@pytest.mark.parametrize("what", ["200,000 cells", *OUTSIDE, "a stamp far ahead"])
def test_a_peer_message_out_of_bounds_is_refused_with_one_log_line(what: str, caplog: pytest.LogCaptureFixture) -> None:
    agent, stack = _agent()
    cells = [(7, 0, 0), OUTSIDE.get(what, (6, 0, 0))]
    if what == "200,000 cells":
        cells = [(x % 8, 0, 0) for x in range(200_000)]
    if what == "a stamp far ahead":
        cells = [(7, 0, 0)]
    stamp = 1_800_000_000_000 if what == "a stamp far ahead" else 5
    forged = answers(Trajectory(3, tuple(cells)), {"d1": TaskId(stamp, "d1", 1)})
    before = stack.protocol.known["d2"]
    payload = encode("d2", 1000.0, forged)  # once: 1000 encodings could outlast the 10 s throttle window
    with caplog.at_level(logging.WARNING):
        for _ in range(1000):
            agent._on_protocol(KEYS.answers("d2"), payload)
    assert stack.protocol.known["d2"] == before
    assert stack.clock.stamp < 1000  # the task-id clock was not dragged ahead
    refused = [r for r in caplog.records if "dropped a message" in r.getMessage()]
    assert len(refused) == 1, [r.getMessage() for r in refused]
    fine = answers(Trajectory(3, ((7, 0, 0), (6, 0, 0))), {"d1": TaskId(5, "d1", 1)})
    agent._on_protocol(KEYS.answers("d2"), encode("d2", 1000.0, fine))
    assert stack.protocol.known["d2"].cells == ((7, 0, 0), (6, 0, 0))


def test_a_sample_with_more_messages_than_drones_is_refused_whole(caplog: pytest.LogCaptureFixture) -> None:
    endpoint = _endpoint()
    got: list[bytes] = []

    async def scenario() -> None:
        host = await ZenohNode.open(ZenohSettings(listen=(endpoint,), max_frames=3), "host")
        other = await ZenohNode.open(ZenohSettings(connect=(endpoint,)), "other")
        try:
            host.subscribe(KEYS.plan(), lambda key, payload: got.append(payload))
            for _ in range(100):  # until linked: bounded
                other.put(KEYS.plan("d2"), b"hello")
                await asyncio.sleep(0.05)
                if got:
                    break
            got.clear()
            for _ in range(5):
                other.session.put(KEYS.plan("d2"), b"\n".join([b"x"] * 1000))  # as a peer's gathered puts
            other.session.put(KEYS.plan("d2"), b"a\nb")
            for _ in range(100):
                await asyncio.sleep(0.05)
                if got:
                    break
        finally:
            await other.close()
            await host.close()

    with caplog.at_level(logging.WARNING):
        asyncio.run(scenario())
    assert got == [b"a", b"b"]
    assert len([r for r in caplog.records if "refused a sample of 1000" in r.getMessage()]) == 1


# ------------------------------------------------------------------ the service believes only the holder
def test_the_service_takes_a_mail_status_only_from_the_drone_on_whose_key_it_came() -> None:
    heard: list[MailStatusReport] = []

    class Listener:
        def on_mail_status(self, report: MailStatusReport) -> None:
            heard.append(report)

    gateway = ZenohGateway(WS, argparse.Namespace(fleet="sec", connect=["tcp/127.0.0.1:1"], zenoh_config=None))
    gateway.listen(Listener())  # type: ignore[arg-type]
    report = WireReport(id="m1", drone="d1", status=MailStatus.DELIVERED, step=4)
    gateway._on_report(KEYS.status("d2", "m1"), encode("d1", 1.0, report))  # d2's key, d1's name
    gateway._on_report(KEYS.status("d1", "m1"), encode("d2", 1.0, report))  # d1's key, another sender
    assert heard == []
    gateway._on_report(KEYS.status("d1", "m1"), encode("d1", 1.0, report))
    assert [(r.mail_id, r.drone, r.status) for r in heard] == [("m1", "d1", "delivered")]


# ------------------------------------------------------------------ hosts: several drones in one session
def test_a_host_speaks_for_its_drones_and_no_other(tmp_path: Path) -> None:
    """A process flying d2 and d3 in one session (--shared-session) presents its host's certificate: it
    may write both drones' keys, and still not d1's."""
    tls = tmp_path / "tls"
    make_certs(tls, DRONES, hosts={"pair": ["d2", "d3"]})
    assert identity_for(tls, ["d2", "d3"]) == "pair" and identity_for(tls, ["d2"]) == "d2"
    with pytest.raises(IdentityError, match="no host certificate"):
        identity_for(tls, ["d1", "d2"])
    endpoint, inbox = _endpoint(), Inbox()
    with session("d1", listen=endpoint, tls_dir=tls) as d1, session("pair", connect=endpoint, tls_dir=tls) as pair:
        d1.subscribe(f"{KEYS.root}/**", inbox)
        assert _until(lambda: pair.put(KEYS.plan("d2"), b"mine"), inbox, KEYS.plan("d2"))
        pair.put(KEYS.plan("d1"), b"forged")
        pair.put(KEYS.plan("d3"), b"mine too")
        assert inbox.wait_for(KEYS.plan("d3")) and KEYS.plan("d1") not in inbox.keys
        pair.put(KEYS.proto("d1", "pair"), b"its drones' acks, joined")
        assert inbox.wait_for(KEYS.proto("d1", "pair"))


def test_only_a_host_writes_its_drones_joined_messages(tmp_path: Path) -> None:
    """``proto/<host>/<to>`` carries messages of the host's drones, and each says which: a drone's own
    session may not write there, or it could speak for the host's other drones."""
    tls = tmp_path / "tls"
    make_certs(tls, DRONES, hosts={"pair": ["d2", "d3"]})
    endpoint, inbox = _endpoint(), Inbox()
    with session("d1", listen=endpoint, tls_dir=tls) as d1, session("d2", connect=endpoint, tls_dir=tls) as d2:
        d1.subscribe(f"{KEYS.root}/**", inbox)
        assert _until(lambda: d2.put(KEYS.plan("d2"), b"mine"), inbox, KEYS.plan("d2"))
        d2.put(KEYS.proto("d1", "pair"), b"as d3, forged")
        d2.put(KEYS.proto("d1", "d2"), b"mine")
        assert inbox.wait_for(KEYS.proto("d1", "d2")) and KEYS.proto("d1", "pair") not in inbox.keys


def test_a_drone_takes_a_hosts_message_only_from_a_drone_it_flies() -> None:
    """A forged message that reached a receiver all the same (a host that speaks for others than
    hosts.json says) changes nothing: d3 is not pair's."""
    ws = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0,
                         drones={"d1": (0, 0, 0), "d2": (7, 0, 0), "d3": (7, 7, 0)})

    def believed(sender: str, key: str = KEYS.proto("d1", "pair")) -> bool:
        stack = DroneStack("d1", StackConfig(ws, SafePlanner(ws)), dict(ws.drones))
        agent = DroneAgent(stack, FakeNode(), KEYS, FakeVehicle(GeoFrame(ws), (0, 0, 0)), GeoFrame(ws),
                           lambda: 1000.0, speakers=Speakers({"pair": frozenset({"d2"})}))
        agent.tick(0)
        x, y, z = ws.drones[sender]
        lie = Trajectory(5, ((x, y, z), (x - 1, y, z)))
        agent._on_protocol(key, encode(sender, 1000.0, answers(lie, {"d9": TaskId(9, "d9", 1)})))
        return stack.protocol.known.get(sender) == lie

    assert believed("d2")
    assert not believed("d3")
    assert not believed("d2", KEYS.answers("pair"))  # a host writes its drones' protocol messages only


def test_hosts_named_as_a_drone_the_service_or_a_router_speak_for_nobody(tmp_path: Path) -> None:
    (tmp_path / "hosts.json").write_text('{"pair": ["d2"], "d1": ["d2"], "service": ["d2"], "router": ["d2"]}')
    assert Speakers.of(tmp_path, DRONES).hosts == {"pair": frozenset({"d2"})}
    assert Speakers.of(None, DRONES).hosts == {}
