"""The console's downloads: the files of hq/export.py, built from the registry on request."""

from __future__ import annotations

import json
from collections.abc import Callable

from hq import export
from hq.registry import Registry
from hq.view import HqVictim, hq_victims
from hq.web.notes import Notes

EXPORTS: dict[str, tuple[str, Callable[[list[HqVictim]], bytes]]] = {
    export.GEOJSON_NAME: (
        "application/geo+json",
        lambda vs: json.dumps(export.geojson(vs), indent=1).encode(),
    ),
    export.KML_NAME: ("application/vnd.google-earth.kml+xml", lambda vs: export.kml(vs)),
    export.CSV_NAME: ("text/csv", lambda vs: export.csv_text(vs)),
}


def export_job(name: str) -> Callable[[Registry, Notes], bytes]:
    def job(registry: Registry, _notes: Notes) -> bytes:
        return EXPORTS[name][1](hq_victims(registry))

    return job
