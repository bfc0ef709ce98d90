"""The deployment files under ``deploy/``: they load, they parse, and the Zenoh ones work.

* every JSON5 file under ``deploy/`` is a valid Zenoh config (``zenoh.Config.from_file``);
* the configs work: their endpoints rewritten to free ports on 127.0.0.1, a sample put on
  one session reaches a subscriber on the other (peer mesh, client and router, TLS);
* TLS with mutual authentication (``deploy/zenoh/tls-mutual``, certificates made by its
  ``make-certs.sh`` in a temporary folder): a client and a peer signed by the fleet CA get
  through; a client or peer whose certificate another CA signed is refused and gets nothing;
* the env examples for systemd name exactly the agent's settings between them, and their
  values are well formed (the vehicle URL through the real parser);
* the systemd units and the compose file say what the README promises, and the commands in
  them parse with the real ``drona`` parser (commands not written yet are skipped).

Every wait is bounded; every subscriber is undeclared before its session closes.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import re
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import yaml

from drona_gcs.geo import check_flyable, check_speed
from drona_gcs.workspace_files import load_workspace
from fleet.cli import COMMANDS, build_parser, main
from fleet.cli.sim_vehicle import max_speed
from fleet.sim.ports import free_port
from fleet.vehicle.urls import parse_link_url

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"
ZENOH_DIR = DEPLOY / "zenoh"
TLS_DIR = ZENOH_DIR / "tls-mutual"
SYSTEMD_DIR = DEPLOY / "systemd"
CONTAINER_DIR = DEPLOY / "container"

#: The agent's settings from the environment (pydantic-settings, prefix DRONA_).
SETTINGS = frozenset({
    "DRONA_WORKSPACE", "DRONA_DRONE", "DRONA_VEHICLE", "DRONA_FLEET", "DRONA_ZENOH_CONFIG",
    "DRONA_LISTEN", "DRONA_CONNECT", "DRONA_LEASE_S", "DRONA_EPOCH", "DRONA_RECORD", "DRONA_TLS_DIR",
    "DRONA_INSECURE", "DRONA_ADOPT_MAIL",
})
KEY = "drona/deploy-test/put"
ARRIVAL_S = 5.0  #: how long a sample may take to arrive over loopback
REFUSAL_S = 1.0  #: how long a refused node is watched for samples after the others got theirs


# ------------------------------------------------------------------ zenoh helpers
@pytest.fixture(scope="module")
def zenoh() -> ModuleType:
    module: ModuleType = pytest.importorskip("zenoh")
    return module


def _endpoint(proto: str = "tcp") -> str:
    return f"{proto}/127.0.0.1:{free_port(socket.SOCK_STREAM)}"


def _config(zenoh: ModuleType, path: Path, listen: list[str], connect: list[str],
            **overrides: Any) -> Any:
    """``path`` loaded, its endpoints replaced; ``overrides`` maps a/b/c keys (as a__b__c) to values."""
    config = zenoh.Config.from_file(str(path))
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("connect/endpoints", json.dumps(connect))
    for key, value in overrides.items():
        config.insert_json5(key.replace("__", "/"), json.dumps(value))
    return config


class Inbox:
    """A callback subscriber's samples; the callback only records (it runs on zenoh's thread)."""

    def __init__(self) -> None:
        self.payloads: list[str] = []
        self.got = threading.Event()

    def __call__(self, sample: Any) -> None:
        self.payloads.append(sample.payload.to_string())
        self.got.set()


@pytest.fixture
def sessions(zenoh: ModuleType) -> Iterator[tuple[Any, Any]]:
    """``(open, subscribe)``: everything opened is closed at the end, subscribers first."""
    with contextlib.ExitStack() as stack:

        def open_session(config: Any) -> Any:
            session = zenoh.open(config)
            stack.callback(session.close)
            return session

        def subscribe(session: Any) -> Inbox:
            inbox = Inbox()
            subscriber = session.declare_subscriber(KEY, inbox)
            stack.callback(subscriber.undeclare)  # LIFO: before its session closes
            return inbox

        yield open_session, subscribe


def _put_until(publisher: Any, inboxes: list[Inbox], timeout: float = ARRIVAL_S) -> bool:
    """Put every 50 ms (declarations travel asynchronously) until every inbox has a sample."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        publisher.put(KEY, "hello")
        if all(inbox.got.wait(0.05) for inbox in inboxes):
            return True
    return False


# ------------------------------------------------------------------ every config loads
ALL_JSON5 = sorted(DEPLOY.rglob("*.json5"))


def test_the_deploy_folder_has_the_zenoh_configs() -> None:
    names = {p.relative_to(ZENOH_DIR).as_posix() for p in ALL_JSON5 if p.is_relative_to(ZENOH_DIR)}
    assert names >= {"peer-mesh.json5", "client.json5", "router.json5",
                     "tls-mutual/router.json5", "tls-mutual/client.json5", "tls-mutual/peer.json5"}


@pytest.mark.parametrize("path", ALL_JSON5, ids=[p.relative_to(DEPLOY).as_posix() for p in ALL_JSON5])
def test_config_loads(zenoh: ModuleType, path: Path) -> None:
    config = zenoh.Config.from_file(str(path))  # unknown keys and bad values raise here
    assert json.loads(config.get_json("mode")) in {"peer", "client", "router"}
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False, "multicast scouting must be off"
    tls = json.loads(config.get_json("transport/link/tls"))
    if path.is_relative_to(TLS_DIR):
        assert tls["enable_mtls"] is True and tls["root_ca_certificate"]
        assert json.loads(config.get_json("transport/link/protocols")) == ["tls"]


# ------------------------------------------------------------------ plain configs work
def test_peer_mesh_config_links_peers_through_gossip(zenoh: ModuleType, sessions: tuple[Any, Any]) -> None:
    """a and c connect only to b, which relays nothing: a's samples reach c over a link gossip made."""
    open_session, subscribe = sessions
    ends = {name: _endpoint() for name in "abc"}
    a = open_session(_config(zenoh, ZENOH_DIR / "peer-mesh.json5", [ends["a"]], [ends["b"]]))
    b = open_session(_config(zenoh, ZENOH_DIR / "peer-mesh.json5", [ends["b"]], []))
    c = open_session(_config(zenoh, ZENOH_DIR / "peer-mesh.json5", [ends["c"]], [ends["b"]]))
    inboxes = [subscribe(b), subscribe(c)]
    assert _put_until(a, inboxes), "a put on one peer did not reach both others"


def test_client_and_router_configs_connect(zenoh: ModuleType, sessions: tuple[Any, Any]) -> None:
    open_session, subscribe = sessions
    endpoint = _endpoint()
    router = open_session(_config(zenoh, ZENOH_DIR / "router.json5", [endpoint], []))
    clients = [open_session(_config(zenoh, ZENOH_DIR / "client.json5", [], [endpoint],
                                    connect__timeout_ms=int(ARRIVAL_S * 1000))) for _ in range(2)]
    inboxes = [subscribe(router), subscribe(clients[1])]
    assert _put_until(clients[0], inboxes), "a client's put did not reach the router and the other client"


# ------------------------------------------------------------------ TLS, mutual authentication


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """`drona certs` run twice: the fleet CA (a router, a node) and a stranger CA (a node)."""
    base = tmp_path_factory.mktemp("tls")
    for folder, names in (("fleet", ("router", "node")), ("stranger", ("node",))):
        assert main(["certs", str(base / folder), *(f"--name={n}" for n in names)]) == 0
    found = {"ca": base / "fleet/ca.pem", "router": base / "fleet/router", "node": base / "fleet/node",
             "stranger": base / "stranger/node"}
    for name, path in found.items():
        assert path.exists(), f"drona certs made no {name}: {path}"
    return found


def _tls(certs: dict[str, Path], own: str, *, listen: bool, connect: bool) -> dict[str, Any]:
    """TLS overrides: the fleet CA, and ``own``'s certificate for the listening and connecting sides."""
    keys: dict[str, Any] = {"transport__link__tls__root_ca_certificate": str(certs["ca"])}
    for side, wanted in (("listen", listen), ("connect", connect)):
        if wanted:
            keys[f"transport__link__tls__{side}_certificate"] = str(certs[own] / "cert.pem")
            keys[f"transport__link__tls__{side}_private_key"] = str(certs[own] / "key.pem")
    return keys


def test_mutual_tls_admits_the_fleet_and_refuses_strangers(
        zenoh: ModuleType, sessions: tuple[Any, Any], certs: dict[str, Path]) -> None:
    open_session, subscribe = sessions
    endpoint = _endpoint("tls")
    router = open_session(_config(zenoh, TLS_DIR / "router.json5", [endpoint], [],
                                  **_tls(certs, "router", listen=True, connect=True)))
    client_overrides = {"connect__timeout_ms": int(ARRIVAL_S * 1000)}
    client = open_session(_config(zenoh, TLS_DIR / "client.json5", [], [endpoint], **client_overrides,
                                  **_tls(certs, "node", listen=False, connect=True)))
    # The stranger differs from the fleet's peer only in its certificate, from another CA; it
    # trusts the fleet CA (so it accepts the router): only client authentication keeps it out.
    fleet_peer, stranger_peer = (
        open_session(_config(zenoh, TLS_DIR / "peer.json5", [], [endpoint], **_tls(certs, own, listen=False,
                                                                                    connect=True)))
        for own in ("node", "stranger"))
    stranger_client_config = _config(zenoh, TLS_DIR / "client.json5", [], [endpoint], connect__timeout_ms=500,
                                     **_tls(certs, "stranger", listen=False, connect=True))
    with pytest.raises(zenoh.ZError):
        open_session(stranger_client_config)  # a client without a router refuses to open

    to_router, to_fleet_peer, to_stranger = subscribe(router), subscribe(fleet_peer), subscribe(stranger_peer)
    assert _put_until(client, [to_router, to_fleet_peer]), \
        "the fleet's client and peer could not reach each other through the router over mutual TLS"
    deadline = time.monotonic() + REFUSAL_S
    while time.monotonic() < deadline:  # keep publishing: a late link would show up here
        client.put(KEY, "not for strangers")
        router.put(KEY, "not for strangers")
        time.sleep(0.05)
    assert to_stranger.payloads == [], "a peer signed by another CA received samples"


def test_mutual_tls_peers_link_directly(zenoh: ModuleType, sessions: tuple[Any, Any],
                                        certs: dict[str, Path]) -> None:
    open_session, subscribe = sessions
    first, second = _endpoint("tls"), _endpoint("tls")
    tls = _tls(certs, "node", listen=True, connect=True)
    a = open_session(_config(zenoh, TLS_DIR / "peer.json5", [first], [], **tls))
    b = open_session(_config(zenoh, TLS_DIR / "peer.json5", [second], [first], **tls))
    inbox = subscribe(a)
    assert _put_until(b, [inbox]), "two peers with fleet certificates did not link over mutual TLS"


# ------------------------------------------------------------------ env examples
ASSIGNMENT = re.compile(r"^(#\s*)?([A-Z][A-Z0-9_]*)=(.*)$")
ENDPOINT = re.compile(r"^(tcp|udp|tls|quic)/(\[[0-9a-fA-F:]+\]|[A-Za-z0-9.-]+):\d{1,5}$")


def _env_names(path: Path) -> dict[str, str | None]:
    """Setting name -> its active value (None when only shown commented out)."""
    found: dict[str, str | None] = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        match = ASSIGNMENT.match(line.strip())
        if match is None:
            continue
        commented, name, value = match.groups()
        assert name in SETTINGS, f"{path.name}:{number}: {name} is not one of the agent's settings"
        assert name not in found, f"{path.name}:{number}: {name} appears twice"
        assert value == value.strip() and not value.startswith(("'", '"')), \
            f"{path.name}:{number}: write NAME=value without quotes or spaces"
        found[name] = None if commented else value
    return found


def _check_value(name: str, value: str) -> None:
    if name == "DRONA_VEHICLE":
        parse_link_url(value)
    elif name in ("DRONA_LISTEN", "DRONA_CONNECT"):
        for endpoint in value.split(","):
            assert ENDPOINT.match(endpoint), f"{name}: {endpoint!r} is not a Zenoh endpoint like tcp/10.0.0.5:7448"
    elif name == "DRONA_LEASE_S":
        assert float(value) > 0
    elif name == "DRONA_EPOCH":
        assert float(value) >= 0
    elif name in ("DRONA_WORKSPACE", "DRONA_ZENOH_CONFIG", "DRONA_RECORD", "DRONA_TLS_DIR"):
        assert value.startswith("/"), f"{name}: use an absolute path, got {value!r}"
    else:
        assert re.fullmatch(r"[A-Za-z0-9_.-]+", value), f"{name}: {value!r}"


def test_env_examples_name_exactly_the_agents_settings() -> None:
    fleet = _env_names(SYSTEMD_DIR / "fleet.env.example")
    agent = _env_names(SYSTEMD_DIR / "agent.env.example")
    assert not fleet.keys() & agent.keys(), f"in both examples: {sorted(fleet.keys() & agent.keys())}"
    assert fleet.keys() | agent.keys() == SETTINGS, f"missing: {sorted(SETTINGS - fleet.keys() - agent.keys())}"
    assert {"DRONA_WORKSPACE", "DRONA_FLEET", "DRONA_EPOCH", "DRONA_LEASE_S", "DRONA_TLS_DIR"} <= fleet.keys()
    assert fleet["DRONA_TLS_DIR"] is not None and fleet.get("DRONA_INSECURE") is None  # secure by default
    for name, value in (fleet | agent).items():
        if value is not None:
            _check_value(name, value)


def test_the_settings_named_are_the_agents() -> None:
    if importlib.util.find_spec("fleet.agent.settings") is None:
        pytest.skip("fleet.agent.settings is not written yet")
    from fleet.agent.settings import AgentSettings

    prefix = AgentSettings.model_config.get("env_prefix", "")
    real = {f"{prefix}{name}".upper() for name in AgentSettings.model_fields}
    assert real >= SETTINGS, f"not settings of the agent: {sorted(SETTINGS - real)}"


def test_commented_alternatives_in_the_agent_example_are_valid_vehicle_urls() -> None:
    urls = re.findall(r"^#\s+((?:serial|udpin|udpout|tcp)://\S+)", (SYSTEMD_DIR / "agent.env.example").read_text(),
                      flags=re.MULTILINE)
    assert len(urls) >= 4
    for url in urls:
        parse_link_url(url)


# ------------------------------------------------------------------ systemd units
def _unit(path: Path) -> dict[str, list[str]]:
    settings: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, _, value = line.partition("=")
            settings.setdefault(key, []).append(value)
    return settings


def _written(command: str) -> bool:
    return command in COMMANDS and importlib.util.find_spec(COMMANDS[command][0]) is not None


def _parses(command: str) -> None:
    """``command`` (``drona ...``) parses with the real parser, if its subcommand is written yet."""
    argv = command.split()[1:]
    if not _written(argv[0]):
        return  # nothing to check against yet
    try:
        build_parser(argv[0]).parse_args(argv)
    except SystemExit:
        pytest.fail(f"{command!r} does not parse with the drona command's parser")


def test_agent_unit_reads_the_fleet_then_the_drone_settings() -> None:
    unit = _unit(SYSTEMD_DIR / "drona-agent@.service")
    assert unit["EnvironmentFile"] == ["/etc/drona/fleet.env", "/etc/drona/agent-%i.env"]  # the later wins
    assert unit["Environment"] == ["DRONA_DRONE=%i"]
    assert unit["KillSignal"][0] in {"SIGINT", "SIGTERM"}
    assert int(unit["TimeoutStopSec"][0]) >= 60, "stopping must leave time to land"
    assert unit["Restart"] == ["on-failure"] and "StartLimitBurst" in unit
    assert "dialout" in unit["SupplementaryGroups"][0].split()
    assert unit["NoNewPrivileges"] == ["yes"] and unit["ProtectSystem"] == ["strict"]
    assert unit["ExecStart"][0].endswith("/drona agent")
    _parses("drona agent")


def test_router_unit_runs_drona_router() -> None:
    unit = _unit(SYSTEMD_DIR / "drona-router.service")
    command = unit["ExecStart"][0]
    assert command.split()[1] == "router"
    _parses("drona " + command.split(maxsplit=1)[1])


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
def test_units_pass_systemd_analyze_verify(tmp_path: Path) -> None:
    for unit in SYSTEMD_DIR.glob("*.service"):  # the real binary is not installed here
        text = re.sub(r"^ExecStart=\S+", "ExecStart=/bin/true", unit.read_text(), flags=re.MULTILINE)
        (tmp_path / unit.name).write_text(text)
    targets = [str(tmp_path / "drona-agent@d1.service"), str(tmp_path / "drona-router.service")]
    result = subprocess.run(["systemd-analyze", "verify", "--man=no", *targets],
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stdout + result.stderr


# ------------------------------------------------------------------ containers
def test_compose_makes_certificates_and_runs_a_router_four_vehicles_and_four_agents() -> None:
    compose = yaml.safe_load((CONTAINER_DIR / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"certs", "router", "vehicles", "agents"}
    for name, service in services.items():
        assert service["network_mode"] == "host", name
        for volume in service["volumes"]:
            source = volume.split(":")[0]
            assert source in compose["volumes"] or (CONTAINER_DIR / source).exists(), f"{name}: {volume}"
        _parses("drona " + " ".join(service["command"]))
    assert services["agents"]["stop_signal"] == "SIGINT"
    assert services["agents"]["environment"]["DRONA_ZENOH_CONFIG"] == "/etc/drona/zenoh.json5"
    # Secure by default: the agents and the router run with the certificates the first service makes.
    assert services["agents"]["environment"]["DRONA_TLS_DIR"] == "/etc/drona/tls"
    assert "--tls-dir" in services["router"]["command"] and services["certs"]["command"][0] == "certs"
    vehicles = build_parser("sim-vehicle").parse_args(services["vehicles"]["command"])
    workspace = load_workspace(CONTAINER_DIR / "workspace.yaml")
    assert len(workspace.drones) >= vehicles.count == 4
    check_speed(workspace, max_speed(vehicles, workspace))  # sim-vehicle would refuse it otherwise
    check_flyable(workspace)  # and the agents
    containerfile = (CONTAINER_DIR / "Containerfile").read_text()
    assert "FROM docker.io/library/python:3.11-slim" in containerfile
    assert 'ENTRYPOINT ["drona"]' in containerfile
    # The image compiles the planner (setup.py) and never takes a host's compiled modules.
    assert "COPY pyproject.toml setup.py" in containerfile and "DRONA_NATIVE_REQUIRED=1 pip install" in containerfile
    ignored = (CONTAINER_DIR / "Containerfile.dockerignore").read_text().splitlines()
    assert {"!setup.py", "**/*.so", "**/_native_sources.*.sha256"} <= set(ignored)
