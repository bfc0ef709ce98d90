"""The packages form layers, each importing only those below it: fleet -> api -> drona_gcs.

``fleet`` holds the ``drona`` command, the composition root, and owns Zenoh, MAVLink and the clock;
``api`` is the service (HTTP, the database, dispatching), which reaches the fleet through the port it
defines (:class:`api.gateway.FleetGateway`, implemented over Zenoh in :mod:`fleet.transport.gateway`);
``drona_gcs`` is the sans-I/O core under both. Every import counts, at the top of a module or inside a
function.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("drona_gcs", "api", "fleet")  #: lowest first
#: what the core never imports: it takes events and ``now``, and returns actions
IO_MODULES = {"asyncio", "socket", "selectors", "select", "threading", "subprocess", "multiprocessing", "time",
              "sqlite3", "zenoh", "pymavlink", "mavsdk", "fastapi", "uvicorn", "httpx"}


def imports_of(path: Path) -> set[str]:
    """The top-level names of the absolute imports in ``path``."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found


def modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", LAYERS)
def test_a_package_imports_no_layer_above_it(package: str) -> None:
    above = set(LAYERS[LAYERS.index(package) + 1:])
    upward = {str(path.relative_to(ROOT)): sorted(imports_of(path) & above) for path in modules(package)}
    assert {path: names for path, names in upward.items() if names} == {}


def test_the_core_does_no_io() -> None:
    found = {str(path.relative_to(ROOT)): sorted(imports_of(path) & IO_MODULES) for path in modules("drona_gcs")}
    assert {path: names for path, names in found.items() if names} == {}


def test_every_package_is_a_layer() -> None:
    """A new top-level package must be placed in the order (or this test tells where to)."""
    packages = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file() and p.name != "tests"}
    assert packages == set(LAYERS)
