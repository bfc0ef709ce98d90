"""The one error tree: every error class of the product derives from DronaError and is drawn in its docstring."""

from __future__ import annotations

import importlib
import pkgutil
import re
from types import ModuleType

import drona_gcs.errors
from drona_gcs.errors import DronaError

PACKAGES = ("drona_gcs", "fleet", "api")


def every_module() -> list[ModuleType]:
    modules = []
    for name in PACKAGES:
        package = importlib.import_module(name)
        for found in pkgutil.walk_packages(package.__path__, f"{name}."):
            if not found.name.endswith(".__main__"):  # running it is what importing it does
                modules.append(importlib.import_module(found.name))
    return modules


def drawn() -> dict[str, str]:
    """Each class in the docstring's drawing, and the class it hangs from (by the column its name starts at)."""
    at_column: dict[int, str] = {}
    tree: dict[str, str] = {}
    for line in (drona_gcs.errors.__doc__ or "").splitlines():
        match = re.match(r"^    [ │├└─]*([A-Z]\w+)", line)
        if match is not None:
            column = match.start(1)
            at_column[column] = match.group(1)
            tree[match.group(1)] = at_column.get(column - 4, "")
    return tree


def subclasses(cls: type[BaseException]) -> set[type[BaseException]]:
    found = set(cls.__subclasses__())
    return found.union(*(subclasses(c) for c in found)) if found else found


def test_every_error_class_is_drawn_under_its_parent() -> None:
    every_module()
    actual = {c.__name__: next(b.__name__ for b in c.__bases__ if issubclass(b, DronaError))
              for c in subclasses(DronaError) if not c.__module__.startswith("tests")}
    tree = drawn()
    assert {name: tree.get(name) for name in actual} == actual
    assert set(tree) - set(actual) == {"DronaError"}  # nothing drawn that does not exist


def test_every_public_exception_class_is_a_drona_error() -> None:
    outside = [f"{module.__name__}.{name}" for module in every_module() for name, obj in vars(module).items()
               if isinstance(obj, type) and issubclass(obj, BaseException) and obj.__module__ == module.__name__
               and not name.startswith("_") and not issubclass(obj, DronaError)]
    assert outside == []
