"""Build hook: compile the planner's hot modules with mypyc; their .py sources stay the fallback.

pyproject.toml holds all the metadata; this file only adds optional extension modules.
They are skipped, and the install stays pure Python, when ``DRONA_PURE_PYTHON=1``, when mypy
is not importable, or when mypyc or the C compiler fails (set ``DRONA_NATIVE_REQUIRED=1`` to
make those failures fatal instead, e.g. in CI). A successful build also writes
``drona_gcs/planner/_native_sources.<cache tag>.sha256``, the hashes of the sources it compiled,
which :mod:`drona_gcs.planner._native` checks at import so a stale build never shadows edited
code. The list of modules, the stamp's name and the on/off rule of the environment variables
come from that module, loaded here by path (it needs only the standard library).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import sys
import sysconfig
from pathlib import Path
from typing import Any

from setuptools import setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

PACKAGE = "drona_gcs.planner"
SOURCE_DIR = Path("drona_gcs", "planner")


def _load_native() -> Any:
    spec = importlib.util.spec_from_file_location("_drona_native", SOURCE_DIR / "_native.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


NATIVE = _load_native()
HOT: tuple[str, ...] = NATIVE.HOT  # NOT __init__: tests patch its names
STAMP: str = NATIVE.STAMP
_flag = NATIVE.flag
GROUP = f"{PACKAGE}._native"  # the shared library: drona_gcs/planner/_native__mypyc.*.so


def _give_up(why: str) -> None:
    if _flag("DRONA_NATIVE_REQUIRED"):
        raise SystemExit(f"drona-gcs: compiling the planner failed: {why}")
    print(f"WARNING drona-gcs: installing the planner as pure Python: {why}", file=sys.stderr)


def _stamp_text() -> str:
    """sha256sum-format lines for the sources being compiled (read now, as mypyc reads them)."""
    return "".join(f"{digest}  {name}\n" for name, digest in NATIVE.source_digests(str(SOURCE_DIR)).items())


#: setup.py commands that build: pip runs setup.py three times per install (egg_info, dist_info,
#: then bdist_wheel or editable_wheel), and mypyc's type check and codegen take ~8 s.
BUILDING = {"build", "build_ext", "bdist_wheel", "editable_wheel", "install", "develop", "bdist_egg"}


def _mypyc_extensions() -> tuple[list[Any], str | None]:
    if _flag("DRONA_PURE_PYTHON") or not BUILDING.intersection(sys.argv[1:]):
        return [], None  # (sdist must not get them either: it would ship the generated C)
    if sys.implementation.name != "cpython":
        _give_up(f"mypyc needs CPython, not {sys.implementation.name}")
        return [], None
    compiler = (os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(compiler) is None:  # checked first: mypyc's type check and codegen take a while
        _give_up(f"no C compiler ({compiler} is not on PATH)")
        return [], None
    try:
        from mypyc.build import mypycify
    except ImportError as exc:
        _give_up(f"mypyc is not importable ({exc})")
        return [], None
    stamp = _stamp_text()
    paths = [str(SOURCE_DIR / f"{m}.py") for m in HOT]
    try:
        # Strictness and the other mypy options come from [tool.mypy] in pyproject.toml. The build
        # environment holds only the build requirements: numpy (heuristic.py) is then missing,
        # which mypyc does not need (numpy arrays are plain objects to it).
        exts = mypycify(["--ignore-missing-imports", *paths], opt_level="3", group_name=GROUP)
    except (Exception, SystemExit) as exc:  # mypy type errors end in SystemExit
        _give_up(f"mypyc failed ({exc!r})")
        return [], None
    return exts, stamp


def _stale_outputs(package_dir: Path, keep: set[str]) -> list[Path]:
    """Compiled files of earlier builds in ``package_dir`` (a build dir, or the source tree after
    an editable install) except this interpreter's of the modules in ``keep``, and every stamp
    but this interpreter's (none without ``keep``). Another interpreter's compiled modules go
    too: this build's stamp would vouch for them, and they were compiled from older sources."""
    if not package_dir.is_dir():
        return []
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    found = []
    for path in package_dir.iterdir():  # the package has no other extension modules
        if path.suffix in (".so", ".pyd"):
            if not (path.name.split(".", 1)[0] in keep and path.name.endswith(suffix)):
                found.append(path)
        elif (path.name.startswith(STAMP.split(".", 1)[0] + ".") and path.name.endswith(".sha256")
              and (not keep or path.name != STAMP)):
            found.append(path)
    return found


class CleanBuildPy(build_py):
    """build_py that drops what earlier builds compiled and this one does not (it always runs).

    setuptools reuses build/lib for ``pip install .``, and anything left there ships; an editable
    install copies the extensions into the source tree, where they would shadow the sources.
    """

    def run(self) -> None:
        super().run()
        keep = {*HOT, NATIVE.GROUP_LIBRARY} if EXTENSIONS else set()
        dirs = [Path(self.build_lib, *PACKAGE.split("."))]
        if getattr(self, "editable_mode", False):
            dirs.append(SOURCE_DIR)
        for d in dirs:
            for path in _stale_outputs(d, keep):
                print(f"drona-gcs: removing stale {path}", file=sys.stderr)
                path.unlink()


class OptionalBuildExt(build_ext):
    """build_ext that falls back to pure Python instead of failing, all or nothing.

    A partial build must never ship: a compiled module whose shared library is missing fails
    at import, it does not fall back to its .py file.
    """

    def run(self) -> None:
        dirs = [Path(self.build_lib, *PACKAGE.split("."))] + ([SOURCE_DIR] if self.inplace else [])
        try:
            super().run()  # builds into build_lib, then copies into the source tree when inplace
        except Exception as exc:  # CCompilerError, DistutilsExecError, PlatformError, OSError ...
            for d in dirs:
                for path in _stale_outputs(d, set()):
                    path.unlink()
            self.extensions = []
            _give_up(f"building the extensions failed ({exc!r})")
            return
        for d in dirs:
            (d / STAMP).write_text(STAMP_TEXT or "", encoding="utf-8")

    def get_outputs(self) -> list[str]:
        outputs: list[str] = super().get_outputs()
        if self.extensions:
            outputs.append(str(Path(self.build_lib, *PACKAGE.split("."), STAMP)))
        return outputs


EXTENSIONS, STAMP_TEXT = _mypyc_extensions()
setup(ext_modules=EXTENSIONS, cmdclass={"build_py": CleanBuildPy, "build_ext": OptionalBuildExt})
