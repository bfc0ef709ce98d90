"""How an agent process spreads its drones over Zenoh sessions, and where each session listens."""

from __future__ import annotations

from pathlib import Path

import pytest

from drona_gcs.workspace_files import load_workspace
from fleet.agent.host import session_groups, zenoh_settings
from fleet.agent.settings import AgentSettings
from fleet.transport.node import agent_endpoint
from tests.integration.harness import workspace_yaml


@pytest.fixture()
def ws_file(tmp_path: Path) -> Path:
    path = tmp_path / "ws.yaml"
    path.write_text(workspace_yaml(4))
    return path


def sessions(ws_file: Path, **flags: object) -> list[tuple[list[str], tuple[str, ...], tuple[str, ...]]]:
    """(drones, listen, connect) of every session the process would open for drones d2 and d3."""
    settings = AgentSettings(workspace=ws_file, drone="d2", count=2, **flags)  # type: ignore[arg-type]
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
