"""One exception root: every error class the project defines derives from
fusion.errors.RescueError, through its package's base (docs/ARCHITECTURE.md)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

from fusion.errors import FusionError, RescueError

PACKAGES = ("companion", "mavlink_io", "fusion", "hq", "scenarios", "npmfetch")


def _error_classes() -> list[type[BaseException]]:
    found: dict[str, type[BaseException]] = {}
    for name in PACKAGES:
        package = importlib.import_module(name)
        modules = [package] + [
            importlib.import_module(info.name)
            for info in pkgutil.walk_packages(package.__path__, f"{name}.")
        ]
        for module in modules:
            for cls_name, cls in inspect.getmembers(module, inspect.isclass):
                if (
                    issubclass(cls, BaseException)
                    and cls.__module__.split(".")[0] in PACKAGES
                    and not cls_name.startswith("_")  # a module's private control flow
                ):
                    found[f"{cls.__module__}.{cls_name}"] = cls
    return list(found.values())


def test_every_project_error_has_the_one_root() -> None:
    classes = _error_classes()
    assert len(classes) >= 30  # the walk found the packages' errors
    strays = [f"{c.__module__}.{c.__name__}" for c in classes if not issubclass(c, RescueError)]
    assert strays == []


@pytest.mark.parametrize(
    ("module", "base"),
    [
        ("companion.errors", "CompanionError"),
        ("mavlink_io.errors", "MavlinkIOError"),
        ("hq.errors", "HqError"),
        ("scenarios.errors", "SimError"),
    ],
)
def test_each_package_has_one_base_under_the_root(module: str, base: str) -> None:
    cls = getattr(importlib.import_module(module), base)
    assert cls.__bases__ == (RescueError,)
    assert FusionError.__bases__ == (RescueError,)
