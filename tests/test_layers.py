"""Each package imports only what its docstring allows (docs/ARCHITECTURE.md).

A rule that breaks here is a design change: change the package's docstring and
ARCHITECTURE.md with the rule, not only this table. Imports inside functions and
under TYPE_CHECKING count too: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
import functools
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


_PROJECT = ("companion", "hq", "fusion", "mavlink_io", "scenarios", "npmfetch", "bench", "tools")


@functools.cache
def _defined_names(module: str) -> tuple[Path, set[str]] | None:
    """A project module's folder or file and the names it defines itself (defs,
    classes, assignments, also under ``if`` and ``try``); None when it is not ours."""
    path = ROOT.joinpath(*module.split("."))
    source = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    if not source.exists():
        return None
    names: set[str] = set()
    for top in ast.parse(source.read_text(encoding="utf-8")).body:
        nodes = ast.walk(top) if isinstance(top, ast.If | ast.Try) else [top]
        for node in nodes:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Assign | ast.AnnAssign):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
    return path, names


def test_every_import_names_the_module_that_defines_it() -> None:
    """No re-exports: ``from M import N`` takes N from the module that defines it (or N
    is a submodule of the package M), so a reader finds N where the import says."""
    found = []
    files = [
        p for p in ROOT.rglob("*.py") if p.relative_to(ROOT).parts[0] not in (".venv", "build")
    ]
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.ImportFrom) and node.level == 0 and node.module):
                continue
            if node.module.split(".")[0] not in _PROJECT:
                continue
            defined = _defined_names(node.module)
            if defined is None:
                continue
            where, names = defined
            for alias in node.names:
                submodule = (where / f"{alias.name}.py").exists() or (where / alias.name).is_dir()
                if alias.name not in names and not submodule:
                    found.append(
                        f"{path.relative_to(ROOT)}:{node.lineno} {node.module}.{alias.name}"
                    )
    assert found == []
