"""The planner's mypyc-compiled modules (setup.py) and the guard that keeps them honest.

The compiled modules sit next to their sources after an editable install, and
Python's import prefers them: :mod:`drona_gcs.planner._native` uses them only
while the sources still hash as they did when compiled.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

import drona_gcs.planner as planner
from drona_gcs.planner import _native


def _fake_package(tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Sources of every hot module in ``tmp`` and the stamp a build of them would leave."""
    lines = []
    for module in _native.HOT:
        source = tmp / f"{module}.py"
        source.write_text(f"# {module}\n", encoding="utf-8")
        lines.append(f"{hashlib.sha256(source.read_bytes()).hexdigest()}  {module}.py")
    (tmp / _native.STAMP).write_text("\n".join(lines) + "\n", encoding="utf-8")
    monkeypatch.setattr(_native, "_DIR", str(tmp))


def test_compiled_modules_are_used_while_their_sources_are_as_compiled(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_package(tmp_path, monkeypatch)
    assert _native._stale() is None


def test_an_edited_source_makes_the_compiled_modules_stale(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_package(tmp_path, monkeypatch)
    with (tmp_path / "sipp.py").open("a", encoding="utf-8") as f:
        f.write("# edited\n")
    assert _native._stale() == "sipp.py changed since it was compiled"


def test_compiled_modules_without_the_builds_stamp_are_not_trusted(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_package(tmp_path, monkeypatch)
    (tmp_path / _native.STAMP).unlink()
    assert "no valid" in str(_native._stale())
    (tmp_path / _native.STAMP).write_text("not a sha256sum line\n", encoding="utf-8")
    assert "no valid" in str(_native._stale())


def test_the_planner_runs_compiled_where_the_build_had_to_compile_it() -> None:
    # CI sets DRONA_NATIVE_REQUIRED=1: there the install fails rather than fall back, so
    # the suite must be running the compiled modules, as users of the same install do.
    if os.environ.get("DRONA_NATIVE_REQUIRED", "") in ("", "0") or os.environ.get("DRONA_PURE_PYTHON"):
        pytest.skip("DRONA_NATIVE_REQUIRED is not set: this install may be pure Python")
    from drona_gcs.planner import sipp

    assert planner.NATIVE
    assert not str(sipp.__file__).endswith(".py"), sipp.__file__
