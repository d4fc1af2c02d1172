"""Run every benchmark module in bench/ on one core and rewrite BENCHMARKS.md.

Each module ``bench/<name>.py`` defines ``run() -> dict[str, object]``: figure name
(with its unit) to value. Its docstring's first line is the section title, the rest
says what is measured and against which target. ``python -m bench NAME ...`` runs
only those modules and keeps the other sections of BENCHMARKS.md as they were.
"""

from __future__ import annotations

import datetime as dt
import importlib
import os
import pkgutil
import platform
import re
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "BENCHMARKS.md"
SECTION = re.compile(r"^## (\w+)\n", re.M)
# What the file's header said of the machine before the stamps named one.
_BEFORE_STAMPS = (
    "predate 2026-11-26; the file's header then named an AMD EPYC, 2 cores, 25 GB, "
    "Linux x86_64, Python 3.11.7"
)


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("model name", "Model")):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem_gb = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 1e9
    return (
        f"{cpu}, {os.cpu_count()} cores, {mem_gb:.0f} GB, {platform.system()} "
        f"{platform.machine()}, Python {platform.python_version()}"
    )


def _format(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _section(name: str, module: object, figures: dict[str, object], seconds: float) -> str:
    doc = (getattr(module, "__doc__", None) or name).strip().splitlines()
    title, body = doc[0], "\n".join(doc[1:]).strip()
    rows = "\n".join(f"| {k} | {_format(v)} |" for k, v in figures.items())
    stamp = f"{dt.date.today().isoformat()}, {seconds:.0f} s, {_machine()}"
    return (
        f"## {name}\n\n**{title}** ({stamp})\n\n{body}\n\n| figure | value |\n|---|---|\n{rows}\n"
    )


def _existing_sections() -> dict[str, str]:
    if not OUT.exists():
        return {}
    text = OUT.read_text()
    parts = SECTION.split(text)
    # rstrip: the blank line between sections is the join's, not part of a section.
    return {
        parts[i]: f"## {parts[i]}\n{parts[i + 1].rstrip()}\n" for i in range(1, len(parts) - 1, 2)
    }


def main(argv: list[str]) -> int:
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    names = sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)]))
    names = [n for n in names if not n.startswith("_")]
    wanted = argv or names
    unknown = set(wanted) - set(names)
    if unknown:
        print(
            f"bench: no module {', '.join(sorted(unknown))}; have {', '.join(names)}",
            file=sys.stderr,
        )
        return 2
    sections = _existing_sections()
    for name in wanted:
        module = importlib.import_module(f"bench.{name}")
        print(f"bench: {name} ...", flush=True)
        start = time.perf_counter()
        figures = module.run()
        sections[name] = _section(name, module, figures, time.perf_counter() - start)
        for k, v in figures.items():
            print(f"  {k}: {_format(v)}")
    header = (
        "# Benchmarks\n\nWritten by `make bench` (`python -m bench`), each module pinned to one "
        "core. Each section's stamp names its date, run time and machine; sections whose "
        f"stamp names no machine {_BEFORE_STAMPS}.\n\n"
    )
    # Sections with no module here (pi_check, written from ``make pi-check``'s output)
    # are kept as they are, in their place in the alphabet.
    OUT.write_text(header + "\n".join(sections[n] for n in sorted(sections)))
    print(f"bench: wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
