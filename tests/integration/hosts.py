"""Hosts for the integration tests (:mod:`fleet.bench.hosts`); a test that cannot make them skips."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import pytest

from fleet.bench.hosts import CANNOT_MAKE_HOSTS, Hosts, can_make_hosts
from fleet.bench.hosts import network_hosts as make_hosts

__all__ = ["Hosts", "network_hosts"]


@contextmanager
def network_hosts(names: Sequence[str]) -> Iterator[Hosts]:
    if not can_make_hosts():
        pytest.skip(CANNOT_MAKE_HOSTS)
    with make_hosts(names) as made:
        yield made
