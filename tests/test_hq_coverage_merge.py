"""rescue-hq's merged searched-area map: robots combine as independent chances, in
one frame, kept in the registry across restarts; its unsearched places and GeoJSON."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fusion.geodesy import ned_to_geodetic
from fusion.types import GlobalOrigin
from hq import coverage
from hq.merge import Origins
from hq.registry import Registry
from hq.registry_file import SCHEMA_VERSION

ORIGIN = GlobalOrigin(47.397742, 8.545594, 488.0)


def test_robots_combine_as_independent_chances_and_survive_a_restart(tmp_path: Path) -> None:
    db = tmp_path / "hq.sqlite"
    with Registry(db) as reg:
        reg.store_coverage(1, [(0, 0, 153), (0, 1, 51)])  # 0.6, 0.2
        reg.store_coverage(2, [(0, 0, 128), (5, 5, 255)])  # ~0.5, 1.0
    with Registry(db) as reg:  # a restarted HQ
        merged = coverage.load(reg)
    p = dict(zip(map(tuple, merged.cells.tolist()), merged.p.tolist(), strict=True))
    assert p[(0, 0)] == pytest.approx(1 - (1 - 153 / 255) * (1 - 128 / 255))
    assert p[(0, 1)] == pytest.approx(51 / 255)
    assert p[(5, 5)] == pytest.approx(1.0)
    assert merged.robots == (1, 2) and merged.origin is None
    s = merged.summary()
    assert s["area_m2"] == pytest.approx(36 * 0.0625)  # the 6 x 6 cells' box
    assert s["searched_well_m2"] == pytest.approx(0.0625)
    assert s["glanced_at_m2"] == pytest.approx(2 * 0.0625)


def test_robots_with_origins_meet_in_the_first_robots_frame() -> None:
    lat, lon, alt = ned_to_geodetic(ORIGIN, 10.0, -5.0, 0.0)  # robot 2 started 10 m N, 5 m W
    origins = Origins({1: ORIGIN, 2: GlobalOrigin(lat, lon, alt)}, None)
    cells = {1: [(40, -20, 255)], 2: [(0, 0, 255)], 3: [(1, 1, 255)]}
    merged = coverage.merged_map(cells, origins)
    assert merged.origin == ORIGIN and merged.robots == (1, 2)
    assert merged.unplaced == (3,)  # no origin: cannot be placed among the others
    assert sorted(map(tuple, merged.cells.tolist())) == [(40, -20)]
    assert merged.p.tolist() == [1.0]  # the same cell: robot 2's (0, 0) is robot 1's (40, -20)


def test_a_robot_whose_origin_is_kilometres_off_is_left_out_not_drawn_across_them() -> None:
    # A wrong origin (or another site) 5 km away would span 20,000 cells of empty box.
    lat, lon, alt = ned_to_geodetic(ORIGIN, 5000.0, 0.0, 0.0)
    origins = Origins({1: ORIGIN, 2: GlobalOrigin(lat, lon, alt)}, None)
    merged = coverage.merged_map({1: [(0, 0, 200)], 2: [(0, 0, 200)]}, origins)
    assert merged.robots == (1,) and merged.unplaced == (2,)
    assert merged.box() == (0, 0, 0, 0)
    assert coverage.console_json(merged, {1: (0.0, 0.0)})["unplaced"] == [2]


def test_unsearched_places_near_the_robots_largest_first() -> None:
    # A 20 x 20 cell room glanced at, but for a 6 x 6 hole and a 2 x 2 hole.
    nn, ee = np.meshgrid(np.arange(20), np.arange(20), indexing="ij")
    keep = ~(
        ((nn >= 2) & (nn < 8) & (ee >= 2) & (ee < 8))
        | ((nn >= 15) & (nn < 17) & (ee >= 15) & (ee < 17))
    )
    cells = [(int(n), int(e), 200) for n, e in zip(nn[keep], ee[keep], strict=True)]
    merged = coverage.merged_map({1: cells}, Origins({}, None))
    places = merged.unsearched_places({1: (4.0, 4.0)})
    assert [p.area_m2 for p in places] == [36 * 0.0625, 4 * 0.0625]
    assert places[0].north_m == pytest.approx(1.25) and places[0].robot_sysid == 1
    assert merged.unsearched_places({1: (500.0, 500.0)}) == []  # none near that robot


def test_geojson_is_lon_lat_with_an_origin_else_says_local_metres() -> None:
    local = coverage.merged_map({1: [(4, 8, 255)]}, Origins({}, None)).geojson()
    ring = local["features"][0]["geometry"]["coordinates"][0]
    assert ring[0] == [2.0, 1.0] and ring[2] == [2.25, 1.25]  # [east, north] metres
    assert "local NED" in local["properties"]["crs_note"]
    assert local["features"][0]["properties"]["class"] == "searched well"
    geo = coverage.merged_map({1: [(4, 8, 100)]}, Origins({1: ORIGIN}, None)).geojson()
    lon, lat = geo["features"][0]["geometry"]["coordinates"][0][0]
    want_lat, want_lon, _ = ned_to_geodetic(ORIGIN, 1.0, 2.0, 0.0)
    assert (lat, lon) == pytest.approx((want_lat, want_lon), abs=1e-7)
    assert "crs_note" not in geo["properties"]
    assert geo["features"][0]["properties"]["class"] == "glanced at"


def test_rescue_hq_export_writes_the_grid(tmp_path: Path) -> None:
    db = tmp_path / "hq.sqlite"
    with Registry(db) as reg:
        reg.store_coverage(1, [(0, 0, 250), (0, 1, 100), (3, 3, 20)])
    out = tmp_path / "out"
    for extra, where in (([], "local NED metres"), (["--origin", "47.4,8.5,400"], "WGS-84")):
        run = subprocess.run(
            [sys.executable, "-m", "hq.cli", "export", "--db", str(db), "--out", str(out), *extra],
            capture_output=True, text=True, timeout=60, cwd=Path(__file__).parents[1],
        )  # fmt: skip
        assert run.returncode == 0, run.stderr
        assert str(out / "coverage.geojson") in run.stdout
        doc = json.loads((out / "coverage.geojson").read_text())
        assert doc["properties"]["coordinates"].startswith(where)
        classes = sorted(f["properties"]["class"] for f in doc["features"])
        assert classes == ["glanced at", "looked at", "searched well"]
    lon, lat = doc["features"][0]["geometry"]["coordinates"][0][0]
    assert lat == pytest.approx(47.4, abs=1e-4) and lon == pytest.approx(8.5, abs=1e-4)


def test_a_version_4_registry_gains_the_coverage_table_and_keeps_its_pictures(
    tmp_path: Path,
) -> None:
    path = tmp_path / "v4.sqlite"
    with Registry(path) as reg:
        assert reg.store_picture(1, 2, 3, b"\xff\xd8 jpeg \xff\xd9", 0.0)
    raw = sqlite3.connect(path, isolation_level=None)
    raw.execute("DROP TABLE coverage")  # what version 4 wrote
    raw.execute("UPDATE meta SET value='4' WHERE key='schema_version'")
    raw.close()
    with Registry(path) as reg:
        reg.store_coverage(1, [(0, 0, 99)])
        assert reg.coverage() == {1: [(0, 0, 99)]}
        assert reg.picture(1, 2) == b"\xff\xd8 jpeg \xff\xd9"
    raw = sqlite3.connect(path, isolation_level=None)
    version = raw.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0]
    raw.close()
    assert version == str(SCHEMA_VERSION)
