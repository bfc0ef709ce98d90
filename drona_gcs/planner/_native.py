"""Use the mypyc-compiled hot modules of the planner only when they match their sources.

``pip install`` (and ``pip install -e .``) may compile :data:`HOT` with mypyc (see setup.py).
The extension modules sit next to the .py files, and Python's import prefers them. So after an
edit to one of the sources, an editable install would run the stale compiled code. The build
records the sources' sha256 in :data:`STAMP`; :func:`select` compares them before the planner
imports anything, and when they differ (or ``DRONA_PURE_PYTHON=1``) it loads all of
:data:`HOT` from source instead: all of them, since compiled code of this group only accepts
the compiled classes of the others. Not compiled itself.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import warnings
from importlib.machinery import EXTENSION_SUFFIXES

#: The compiled modules, in an order in which each imports only earlier ones of them. The one
#: list: setup.py reads it from here (this module imports nothing but the standard library).
HOT = ("grid", "reservations", "heuristic", "sipp", "astar")
#: mypyc's shared library of the group, which every compiled module of it needs.
GROUP_LIBRARY = "_native__mypyc"
#: The sources' hashes, written by the build; one per interpreter ABI, as its .so files are.
STAMP = f"_native_sources.{sys.implementation.cache_tag}.sha256"
_PACKAGE = __name__.rpartition(".")[0]
_DIR = os.path.dirname(os.path.abspath(__file__))


def flag(name: str) -> bool:
    """Whether the environment variable ``name`` is on: set, and not 0, false or no."""
    return os.environ.get(name, "").strip().lower() not in ("", "0", "false", "no")


def source_digests(directory: str) -> dict[str, str]:
    """The sha256 of each :data:`HOT` module's source in ``directory``, by file name, in order:
    what the build records in :data:`STAMP` and what :func:`select` compares (OSError if one is
    missing)."""
    digests = {}
    for m in HOT:
        with open(os.path.join(directory, f"{m}.py"), "rb") as src:
            digests[f"{m}.py"] = hashlib.sha256(src.read()).hexdigest()
    return digests


def _compiled_present(names: list[str]) -> bool:
    return any(f"{m}{suffix}" in names for m in HOT for suffix in EXTENSION_SUFFIXES)


def _stale() -> str | None:
    """Why the compiled modules must not be used, or None when they match the sources."""
    names = os.listdir(_DIR)
    if not any(f"{GROUP_LIBRARY}{suffix}" in names for suffix in EXTENSION_SUFFIXES):
        return f"{GROUP_LIBRARY} is missing for this interpreter"
    try:
        with open(os.path.join(_DIR, STAMP), encoding="utf-8") as f:
            recorded = dict(line.split()[::-1] for line in f if line.strip())
    except (OSError, ValueError):
        return f"no valid {STAMP} (built by something else than setup.py?)"
    try:
        now = source_digests(_DIR)
    except OSError as exc:
        return f"{os.path.basename(str(exc.filename))} cannot be read ({exc.strerror})"
    if set(recorded) != set(now):
        return f"{STAMP} names other modules than {', '.join(HOT)}"
    changed = [name for name, digest in now.items() if digest != recorded[name]]
    return f"{changed[0]} changed since it was compiled" if changed else None


def _load_source(module: str) -> None:
    name = f"{_PACKAGE}.{module}"
    spec = importlib.util.spec_from_file_location(name, os.path.join(_DIR, f"{module}.py"))
    assert spec is not None and spec.loader is not None
    loaded = importlib.util.module_from_spec(spec)
    sys.modules[name] = loaded
    try:
        spec.loader.exec_module(loaded)
    except BaseException:
        del sys.modules[name]
        raise
    setattr(sys.modules[_PACKAGE], module, loaded)


def select() -> bool:
    """Make the planner's imports of :data:`HOT` load the compiled modules when they are present
    and fresh, else the sources; return whether they are compiled. Call before importing them."""
    grid = sys.modules.get(f"{_PACKAGE}.grid")
    if grid is not None:  # already chosen (the package is reloaded)
        return not str(grid.__file__).endswith(".py")
    if not _compiled_present(os.listdir(_DIR)):
        return False  # a pure-Python install
    if not flag("DRONA_PURE_PYTHON"):  # (set: the sources, as asked, with no warning)
        why = _stale()
        if why is None:
            return True
        warnings.warn(f"drona_gcs.planner runs its .py sources, not its compiled modules ({why}). They are "
                      f"slower: rebuild with `pip install --no-deps -e .`, or delete {_DIR}/*.so",
                      RuntimeWarning, stacklevel=2)
    for m in HOT:
        _load_source(m)
    return False
