"""Exports of the HQ victims for other tools, written atomically.

- ``victims.geojson``: a FeatureCollection of Points (RFC 7946: [lon, lat, alt]);
  properties: id, urgency, visibility_pct, state, robots, sources, first/last seen
  (ISO 8601 UTC), sigma_m, north_m/east_m/down_m, cues (what saw the person:
  ``colour_body``, ``colour_part``, ``warm``; empty when the robots do not say).
- ``victims.kml``: one Placemark per victim with a style per urgency (Google
  Earth, and any GIS or phone map app a ground team uses).
- ``victims.csv``: one row per victim for a ground team's list or a spreadsheet
  (RFC 4180, a header row, UTF-8).
- ``coverage.geojson``: where the robots have looked (hq.coverage): each 0.25 m
  floor cell any robot looked at, a Polygon with p (the merged probability that a
  person there would have been found) and its class (searched well, glanced at,
  looked at); in lon/lat when the robots have a global origin, else in local NED
  metres, which its properties say (``coordinates``, ``crs_note``).

There is deliberately no QGroundControl ``.plan``: uploading a plan to a vehicle
replaces its mission, geofence and rally points, and rally points are where RTL
drives the rover. QGC shows the victims live through rescue-hq's SBS-1 feed
(hq/sbs.py, docs/HQ.md) instead.

Only victims with a latitude/longitude appear in these files: a victim is placed
on the globe when its robot reported lat/lon, or when the HQ knows an EKF origin
for its robot (GPS_GLOBAL_ORIGIN from the vehicle, or the operator's ``--origin``).
Victims known only in a local NED frame are counted in ``ExportResult.local_only``
and shown by the live table and ``rescue-hq list``.

Each file is written to a temporary file in the same directory, flushed to disk
and renamed over the old one: a reader never sees half a file.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from fusion.types import Urgency
from hq.coverage import MergedMap
from hq.records import cue_words
from hq.view import HqVictim

GEOJSON_NAME = "victims.geojson"
KML_NAME = "victims.kml"
CSV_NAME = "victims.csv"
COVERAGE_NAME = "coverage.geojson"
CSV_COLUMNS = (
    "id",
    "urgency",
    "state",
    "lat_deg",
    "lon_deg",
    "alt_m",
    "sigma_m",
    "visibility_pct",
    "robots",
    "sources",
    "first_seen",
    "last_seen",
    "north_m",
    "east_m",
    "cues",
)

# KML colours are aabbggrr.
_KML_COLOURS = {
    Urgency.CRITICAL: "ff0000ff",  # red
    Urgency.MEDIUM: "ff00a5ff",  # orange
    Urgency.LIGHT: "ff00c000",  # green
}


@dataclass(frozen=True)
class ExportResult:
    written: tuple[Path, ...]
    placed: int  # victims in the files
    local_only: int  # victims without lat/lon (not in the files)


def _iso(unix_s: float) -> str:
    return datetime.fromtimestamp(unix_s, UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def _name(v: HqVictim) -> str:
    return f"V{v.hq_id} {v.urgency.name}"


def geojson(victims: list[HqVictim]) -> dict[str, Any]:
    features = []
    for v in victims:
        if not v.has_global:
            continue
        features.append(
            {
                "type": "Feature",
                "id": v.hq_id,
                "geometry": {"type": "Point", "coordinates": [v.lon_deg, v.lat_deg, v.alt_m]},
                "properties": {
                    "id": v.hq_id,
                    "name": _name(v),
                    "urgency": v.urgency.name,
                    "visibility_pct": round(v.visibility_pct, 1),
                    "state": v.state.name,
                    "robots": list(v.robots),
                    "sources": [{"robot": r, "victim_id": i} for r, i in v.sources],
                    "first_seen": _iso(v.first_seen_unix_s),
                    "last_seen": _iso(v.last_seen_unix_s),
                    "sigma_m": round(v.sigma_m, 3),
                    "north_m": round(v.north_m, 3),
                    "east_m": round(v.east_m, 3),
                    "down_m": round(v.down_m, 3),
                    "cues": v.cues.names(),
                },
            }
        )
    return {"type": "FeatureCollection", "features": features}


def kml(victims: list[HqVictim]) -> bytes:
    ns = "http://www.opengis.net/kml/2.2"
    root = ET.Element("kml", xmlns=ns)
    doc = ET.SubElement(root, "Document")
    ET.SubElement(doc, "name").text = "rescue-hq victims"
    for urgency, colour in _KML_COLOURS.items():
        style = ET.SubElement(doc, "Style", id=urgency.name.lower())
        icon_style = ET.SubElement(style, "IconStyle")
        ET.SubElement(icon_style, "color").text = colour
        ET.SubElement(icon_style, "scale").text = "1.2" if urgency == Urgency.CRITICAL else "1.0"
        icon = ET.SubElement(icon_style, "Icon")
        ET.SubElement(
            icon, "href"
        ).text = "http://maps.google.com/mapfiles/kml/shapes/placemark_circle.png"
    for v in victims:
        if not v.has_global:
            continue
        mark = ET.SubElement(doc, "Placemark", id=f"victim-{v.hq_id}")
        ET.SubElement(mark, "name").text = _name(v)
        ET.SubElement(mark, "description").text = (
            f"{v.urgency.name}, {v.visibility_pct:.0f}% visible, {v.state.name}; "
            f"robots {', '.join(str(r) for r in v.robots)}; ±{v.sigma_m:.1f} m; "
            f"last seen {_iso(v.last_seen_unix_s)}; seen: {cue_words(v.cues)}"
        )
        ET.SubElement(mark, "styleUrl").text = f"#{v.urgency.name.lower()}"
        stamp = ET.SubElement(mark, "TimeStamp")
        ET.SubElement(stamp, "when").text = _iso(v.last_seen_unix_s)
        point = ET.SubElement(mark, "Point")
        ET.SubElement(point, "coordinates").text = f"{v.lon_deg:.8f},{v.lat_deg:.8f},{v.alt_m:.2f}"
    ET.indent(root)
    return bytes(ET.tostring(root, encoding="utf-8", xml_declaration=True))


def csv_text(victims: list[HqVictim]) -> bytes:
    """Placed victims, most urgent first; sources as ``robot:victim`` separated by spaces."""
    out = io.StringIO(newline="")
    writer = csv.writer(out, lineterminator="\r\n")
    writer.writerow(CSV_COLUMNS)
    for v in victims:
        if not v.has_global:
            continue
        writer.writerow(
            [
                v.hq_id,
                v.urgency.name,
                v.state.name,
                f"{v.lat_deg:.8f}",
                f"{v.lon_deg:.8f}",
                f"{v.alt_m:.2f}",
                f"{v.sigma_m:.2f}",
                f"{v.visibility_pct:.0f}",
                " ".join(str(r) for r in v.robots),
                " ".join(f"{r}:{i}" for r, i in v.sources),
                _iso(v.first_seen_unix_s),
                _iso(v.last_seen_unix_s),
                f"{v.north_m:.2f}",
                f"{v.east_m:.2f}",
                " ".join(v.cues.names()),
            ]
        )
    return out.getvalue().encode("utf-8")


def coverage_geojson(coverage: MergedMap) -> bytes:
    """The merged searched-area map as GeoJSON (compact: a map has many cells)."""
    return json.dumps(coverage.geojson(), separators=(",", ":")).encode()


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old or the new file, never half."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def export_all(
    victims: list[HqVictim], out_dir: Path, coverage: MergedMap | None = None
) -> ExportResult:
    """Write the victims' three files into ``out_dir`` (created if missing), and the
    searched-area map when given; OSError on failure."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {
        GEOJSON_NAME: json.dumps(geojson(victims), indent=1).encode(),
        KML_NAME: kml(victims),
        CSV_NAME: csv_text(victims),
    }
    if coverage is not None:
        files[COVERAGE_NAME] = coverage_geojson(coverage)
    for name, data in files.items():
        write_atomic(out_dir / name, data)
    placed = sum(1 for v in victims if v.has_global)
    return ExportResult(
        tuple(out_dir / n for n in files), placed=placed, local_only=len(victims) - placed
    )
