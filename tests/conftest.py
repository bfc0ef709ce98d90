"""Shared test fixtures: where the test data lives, and a file writer.

The original DRONA workspaces and the MovingAI maps are in ``tests/data`` (its README says
where they come from). Tests that take one of the arguments named in :data:`DATA_FILES` run
once per matching file (one test id each).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import pytest

from fleet.transport.identity import ROUTER, SERVICE, make_certs

DATA_DIR = Path(__file__).resolve().parent / "data"

#: Test argument -> glob patterns under DATA_DIR of the files it runs over.
DATA_FILES: dict[str, tuple[str, ...]] = {
    "drona_xml": ("drona-workspaces/*/Workspace.xml",),
    "movingai_map": ("movingai/*.map", "movingai/*.grid"),
}


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    for arg, patterns in DATA_FILES.items():
        if arg in metafunc.fixturenames:
            files = sorted(f for pattern in patterns for f in DATA_DIR.glob(pattern))
            assert files, f"no test data for {arg}: {patterns} under {DATA_DIR}"
            metafunc.parametrize(arg, [pytest.param(f, id=f.relative_to(DATA_DIR).as_posix()) for f in files])


#: Every test's fleet runs as `drona demo` and deploy/ do: mutual TLS and the fleet's access control, with
#: certificates for these names, made once per test session (a test of --insecure says so itself).
CERT_NAMES = [*(f"d{i}" for i in range(257)), SERVICE, ROUTER]
SIM_HOST = "sim-host"  #: a host certificate that flies every drone above in one session (--shared-session)


@pytest.fixture(scope="session", autouse=True)
def fleet_certificates(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The fleet's CA and certificates, in ``DRONA_TLS_DIR`` for every process the tests start."""
    tls_dir = tmp_path_factory.mktemp("fleet-tls")
    make_certs(tls_dir, CERT_NAMES, hosts={SIM_HOST: CERT_NAMES[:-2]})
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("DRONA_TLS_DIR", str(tls_dir))
        patch.delenv("DRONA_INSECURE", raising=False)
        yield tls_dir


def fleet_tls_dir() -> Path:
    """The test session's certificates (see :func:`fleet_certificates`)."""
    return Path(os.environ["DRONA_TLS_DIR"])


CORE_TESTS = Path(__file__).resolve().parent / "drona_gcs"  #: the sans-I/O core's tests: they only compute
YIELDING_NICE = 10  #: their niceness: a process at 0 gets about nine times their share of a busy CPU
CAP_SYS_NICE = 23  #: the capability to raise a priority back (root's, unless a container drops it)


@functools.cache
def may_raise_priority() -> bool:
    """Whether this process holds CAP_SYS_NICE (the Makefile asks the same of its shell)."""
    try:
        status = Path("/proc/self/status").read_text(encoding="ascii")
    except OSError:
        return False
    effective = next((line.split()[1] for line in status.splitlines() if line.startswith("CapEff:")), "0")
    return bool(int(effective, 16) >> CAP_SYS_NICE & 1)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Generator[None, None, None]:
    """A test that only computes yields the CPU to the fleets' tests (make test runs them beside it):
    starved on a busy machine, their vehicles run late and their flights fail the audit. Without
    CAP_SYS_NICE a priority cannot be raised back, so every test then runs as it is."""
    if not item.path.is_relative_to(CORE_TESTS) or not may_raise_priority():
        return (yield)
    before = os.getpriority(os.PRIO_PROCESS, 0)
    os.setpriority(os.PRIO_PROCESS, 0, YIELDING_NICE)
    try:
        return (yield)
    finally:
        os.setpriority(os.PRIO_PROCESS, 0, before)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The test data folder (``tests/data``)."""
    return DATA_DIR


@pytest.fixture
def write_file(tmp_path: Path) -> Callable[[str, str | bytes], Path]:
    """``write_file(name, content)`` writes text or bytes into ``tmp_path`` and returns the path."""

    def write(name: str, content: str | bytes) -> Path:
        path = tmp_path / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content, encoding="utf-8")
        return path

    return write

