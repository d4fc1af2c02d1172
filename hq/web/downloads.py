"""The console's downloads: the files of hq/export.py, built from the registry on
request; and the searched-area map the console draws (``coverage_job``)."""

from __future__ import annotations

import json
from collections.abc import Callable

from hq import coverage, export
from hq.registry import Registry
from hq.view import hq_victims
from hq.web.notes import Notes
from hq.web.state import LiveRobots

EXPORTS: dict[str, tuple[str, Callable[[Registry], bytes]]] = {
    export.GEOJSON_NAME: (
        "application/geo+json",
        lambda reg: json.dumps(export.geojson(hq_victims(reg)), indent=1).encode(),
    ),
    export.KML_NAME: (
        "application/vnd.google-earth.kml+xml",
        lambda reg: export.kml(hq_victims(reg)),
    ),
    export.CSV_NAME: ("text/csv", lambda reg: export.csv_text(hq_victims(reg))),
    export.COVERAGE_NAME: (
        "application/geo+json",
        lambda reg: export.coverage_geojson(coverage.load(reg)),
    ),
}


def export_job(name: str) -> Callable[[Registry, Notes], bytes]:
    def job(registry: Registry, _notes: Notes) -> bytes:
        return EXPORTS[name][1](registry)

    return job


def coverage_job(live: LiveRobots) -> Callable[[Registry, Notes], bytes]:
    """The merged searched-area map for the console to draw, with the largest
    unsearched places near the robots whose positions the HQ hears."""

    def job(registry: Registry, _notes: Notes) -> bytes:
        robots = {
            s: (t.north_m, t.east_m)
            for s, t in live.tracks().items()
            if t.north_m is not None and t.east_m is not None
        }
        return json.dumps(coverage.console_json(coverage.load(registry), robots)).encode()

    return job
