"""The console's downloads: the exports of hq/export.py, and a CSV of every victim."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from hq import export
from hq.registry import Registry
from hq.view import HqVictim, hq_victims
from hq.web.notes import Notes


def _iso_utc(unix_s: float) -> str:
    return datetime.fromtimestamp(unix_s, UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def csv_bytes(victims: list[HqVictim]) -> bytes:
    """Every HQ victim, one row each, local and global positions (spreadsheets, paper)."""
    out = io.StringIO()
    w = csv.writer(out)
    w.writerow(
        [
            "id", "urgency", "state", "visibility_pct", "robots", "north_m", "east_m",
            "sigma_m", "lat_deg", "lon_deg", "alt_m", "first_seen", "last_seen", "sightings",
        ]
    )  # fmt: skip
    for v in victims:
        w.writerow(
            [
                v.hq_id,
                v.urgency.name,
                v.state.name,
                f"{v.visibility_pct:.1f}",
                " ".join(str(r) for r in v.robots),
                f"{v.north_m:.2f}",
                f"{v.east_m:.2f}",
                f"{v.sigma_m:.2f}",
                "" if v.lat_deg is None else f"{v.lat_deg:.7f}",
                "" if v.lon_deg is None else f"{v.lon_deg:.7f}",
                "" if v.alt_m is None else f"{v.alt_m:.2f}",
                _iso_utc(v.first_seen_unix_s),
                _iso_utc(v.last_seen_unix_s),
                v.observations,
            ]
        )
    return out.getvalue().encode()


EXPORTS: dict[str, tuple[str, Callable[[list[HqVictim], Any], bytes]]] = {
    export.GEOJSON_NAME: (
        "application/geo+json",
        lambda vs, _o: json.dumps(export.geojson(vs), indent=1).encode(),
    ),
    export.KML_NAME: ("application/vnd.google-earth.kml+xml", lambda vs, _o: export.kml(vs)),
    export.PLAN_NAME: (
        "application/json",
        lambda vs, o: json.dumps(export.plan(vs, o), indent=4).encode(),
    ),
    "victims.csv": ("text/csv", lambda vs, _o: csv_bytes(vs)),
}


def export_job(name: str) -> Callable[[Registry, Notes], bytes]:
    def job(registry: Registry, _notes: Notes) -> bytes:
        return EXPORTS[name][1](hq_victims(registry), registry.default_origin())

    return job
