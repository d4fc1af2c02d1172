"""Each package imports only what its docstring allows (docs/ARCHITECTURE.md).

A rule that breaks here is a design change: change the package's docstring and
ARCHITECTURE.md with the rule, not only this table. Imports inside functions and
under TYPE_CHECKING count too: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
_IO = ("cv2", "pymavlink", "serial", "socket", "sqlite3", "subprocess", "os", "pathlib")

# The companion's parts; each may import only those named for it below (and itself).
_PARTS = ("sources", "vision", "pipeline", "coverage", "reporting", "storage", "looks")
_PARTS += ("service", "commands")


def _companion_except(*allowed: str) -> tuple[str, ...]:
    return (*(f"companion.{p}" for p in _PARTS if p not in allowed), "hq", "scenarios")


# package (a folder, or one module): the imports it must not make (a name forbids
# that module and everything under it)
RULES: dict[str, tuple[str, ...]] = {
    "fusion": ("companion", "mavlink_io", "hq", "scenarios", "npmfetch", *_IO),
    "mavlink_io": ("companion", "hq", "scenarios"),
    "hq": ("companion", "scenarios"),
    "npmfetch": ("companion", "mavlink_io", "hq", "scenarios"),
    "companion": ("hq", "scenarios", "bench"),
    "companion/sources": (*_companion_except(), "mavlink_io"),
    "companion/vision": (*_companion_except(), "mavlink_io", "pymavlink"),
    "companion/coverage.py": _companion_except(),
    "companion/looks": _companion_except(),
    "companion/pipeline.py": (
        *_companion_except("sources", "vision", "coverage", "reporting"),
        "mavlink_io",
    ),
    "companion/reporting": _companion_except("sources", "vision", "coverage", "storage"),
    "companion/storage": _companion_except("coverage", "reporting"),
    "companion/service": _companion_except(*(p for p in _PARTS if p != "commands")),
}


def _imports(path: Path) -> list[tuple[int, str]]:
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
            # ``from companion import service`` names a subpackage too
            found += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return found


def _breaks(package: str, forbidden: tuple[str, ...]) -> list[str]:
    target = ROOT / package
    files = sorted(target.rglob("*.py")) if target.is_dir() else [target]
    own = package.removesuffix(".py").replace("/", ".")
    out = []
    for path in files:
        for line, name in _imports(path):
            if name == own or name.startswith(own + "."):
                continue
            if any(name == f or name.startswith(f + ".") for f in forbidden):
                out.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    return out


@pytest.mark.parametrize("package", sorted(RULES))
def test_a_package_imports_only_what_its_docstring_allows(package: str) -> None:
    assert (ROOT / package).exists(), f"{package}: the rule names a package that is gone"
    assert _breaks(package, RULES[package]) == []


def test_the_check_sees_an_import_inside_a_function(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from companion.service.run import Service\n")
    assert _imports(module) == [(2, "companion.service.run"), (2, "companion.service.run.Service")]


def test_every_package_says_what_it_holds() -> None:
    """Each package's docstring is more than its name (the issue: "companion." was all)."""
    short = []
    for init in sorted(ROOT.glob("*/__init__.py")) + sorted(ROOT.glob("*/*/__init__.py")):
        if init.parts[-2] in ("tests", ".venv") or ".venv" in init.parts:
            continue
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8"))) or ""
        if len(doc.split()) < 12:
            short.append(str(init.relative_to(ROOT)))
    assert short == []
