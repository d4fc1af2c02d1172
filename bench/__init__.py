"""Benchmarks: each module here has ``run() -> dict`` of figures; ``python -m bench``
runs them all pinned to one core and rewrites BENCHMARKS.md."""
