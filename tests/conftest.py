"""Shared test fixtures: where the shared data lives, and a file writer.

The original DRONA workspaces and the MovingAI maps live outside the repository,
in ``../shared`` beside the clone. Tests that take one of the arguments named in
:data:`SHARED_FILES` run once per matching file (one test id each); when none
is found they are skipped with a reason that says where we looked.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

SHARED_DIR = Path(__file__).resolve().parents[1].parent / "shared"

#: Test argument -> glob patterns under SHARED_DIR of the files it runs over.
SHARED_FILES: dict[str, tuple[str, ...]] = {
    "drona_xml": ("drona-workspaces/*/Workspace.xml",),
    "movingai_map": ("movingai/*.map", "movingai/*.grid"),
}


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    for arg, patterns in SHARED_FILES.items():
        if arg not in metafunc.fixturenames:
            continue
        files = sorted(f for pattern in patterns for f in SHARED_DIR.glob(pattern))
        params = [pytest.param(f, id=f.relative_to(SHARED_DIR).as_posix()) for f in files]
        if not params:
            wanted = " or ".join(str(SHARED_DIR / p) for p in patterns)
            params = [pytest.param(None, marks=pytest.mark.skip(reason=f"shared data not found: no {wanted}"))]
        metafunc.parametrize(arg, params)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The shared data folder (``../shared`` beside the repository); skips when it is missing."""
    if not SHARED_DIR.is_dir():
        pytest.skip(f"shared data folder not found: looked for {SHARED_DIR}")
    return SHARED_DIR


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
