"""The planner's mypyc-compiled modules (setup.py) and the guard that keeps them honest.

The compiled modules sit next to their sources after an editable install, and
Python's import prefers them: :mod:`drona_gcs.planner._native` uses them only
while the sources still hash as they did when compiled.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from importlib.machinery import EXTENSION_SUFFIXES
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
    (tmp / f"{_native.GROUP_LIBRARY}{EXTENSION_SUFFIXES[0]}").write_bytes(b"")
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


def test_compiled_modules_without_their_shared_library_or_a_source_are_not_used(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_package(tmp_path, monkeypatch)
    (tmp_path / "grid.py").unlink()
    assert _native._stale() is not None and "grid.py cannot be read" in str(_native._stale())
    (tmp_path / f"{_native.GROUP_LIBRARY}{EXTENSION_SUFFIXES[0]}").unlink()
    assert _native._stale() == f"{_native.GROUP_LIBRARY} is missing for this interpreter"


def test_a_stamp_for_other_modules_is_not_trusted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_package(tmp_path, monkeypatch)
    with (tmp_path / _native.STAMP).open("a", encoding="utf-8") as f:
        f.write(f"{'0' * 64}  layers.py\n")
    assert "names other modules" in str(_native._stale())


def test_the_planner_runs_compiled_where_the_build_had_to_compile_it() -> None:
    # CI sets DRONA_NATIVE_REQUIRED=1: there the install fails rather than fall back, so
    # the suite must be running the compiled modules, as users of the same install do.
    if not _native.flag("DRONA_NATIVE_REQUIRED") or _native.flag("DRONA_PURE_PYTHON"):
        pytest.skip("DRONA_NATIVE_REQUIRED is not set: this install may be pure Python")
    from drona_gcs.planner import sipp

    assert planner.NATIVE
    assert not str(sipp.__file__).endswith(".py"), sipp.__file__


_STREAM = """
import json, random, sys
import drona_gcs.planner as planner
from drona_gcs.workload import TaskStream, random_workspace
from drona_gcs.errors import NoPlanFound
from drona_gcs.planner import sipp

def costs(delta):
    rng = random.Random(f"native-{delta}")
    ws = random_workspace(16, 16, rng)
    plan, stream, out = planner.SafePlanner(ws, delta, fleet_size=12), TaskStream(ws, 12, rng), []
    for _ in range(60):
        task = stream.next_task()
        try:
            found = plan.plan(task.start, task.goal, task.start_step, task.others)
        except NoPlanFound:
            out.append(None)
            stream.complete(task, None)
        else:
            out.append([found.cost, [list(c) for c in found.trajectory.cells]])
            stream.complete(task, found.trajectory)
    return out

print(json.dumps({"native": planner.NATIVE, "file": sipp.__file__, "costs": [costs(0), costs(1)]}))
"""


def _run_stream(pure: bool) -> dict[str, object]:
    env = {k: v for k, v in os.environ.items() if k != "DRONA_PURE_PYTHON"}
    if pure:
        env["DRONA_PURE_PYTHON"] = "1"
    done = subprocess.run([sys.executable, "-c", _STREAM], env=env, capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    result: dict[str, object] = json.loads(done.stdout)
    return result


def test_the_pure_python_planner_plans_as_the_compiled_one() -> None:
    # DRONA_PURE_PYTHON=1 loads the sources even beside compiled modules (what users without a
    # compiler, and developers after an edit, run); both must give the same plans.
    pure, default = _run_stream(pure=True), _run_stream(pure=False)
    assert pure["native"] is False and str(pure["file"]).endswith(".py"), pure["file"]
    assert default["native"] is planner.NATIVE
    assert pure["costs"] == default["costs"]
    assert any(c is not None for c in pure["costs"][0])  # type: ignore[index]
