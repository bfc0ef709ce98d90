"""Fixtures of the runs over real processes."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest

from tests.integration.harness import FleetProcesses
from tests.integration.hosts import network_hosts


@pytest.fixture
def hosted_apart(tmp_path: Path) -> Iterator[Callable[..., FleetProcesses]]:
    """``hosted_apart(drones, **options)``: a fleet with each drone on a host of its own, through routers."""
    with ExitStack() as stack:
        def fleet(drones: list[str], **options: object) -> FleetProcesses:
            hosts = stack.enter_context(network_hosts(drones))
            return FleetProcesses(tmp_path, drones, hosts=hosts, host_of={d: d for d in drones}, routers=True,
                                  **options)  # type: ignore[arg-type]
        yield fleet
