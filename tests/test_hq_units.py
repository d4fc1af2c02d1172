"""rescue-hq's parts in process: merge gating, the registry's rules, exports, the table."""

from __future__ import annotations

import csv
import json
import sqlite3
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fusion.geodesy import ned_to_geodetic
from fusion.types import GlobalOrigin, TrackState, Urgency, VictimReport
from hq import export, merge, table
from hq.merge import Placed
from hq.records import IncomingReport, OperatorAction, StoreResult
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.view import hq_victims

ORIGIN = GlobalOrigin(47.397742, 8.545594, 488.0)


def report(
    robot: int,
    victim: int,
    north_m: float,
    east_m: float,
    *,
    sigma_m: float = 0.5,
    urgency: Urgency = Urgency.MEDIUM,
    geo: bool = False,
    state: TrackState = TrackState.CONFIRMED,
    t: float = 1_700_000_000.0,
) -> VictimReport:
    lat = lon = alt = None
    if geo:
        lat, lon, alt = ned_to_geodetic(ORIGIN, north_m, east_m, 0.0)
    return VictimReport(
        victim_id=victim,
        robot_sysid=robot,
        state=state,
        urgency=urgency,
        visibility_pct={Urgency.LIGHT: 70.0, Urgency.MEDIUM: 30.0, Urgency.CRITICAL: 5.0}[urgency],
        north_m=north_m,
        east_m=east_m,
        down_m=0.0,
        cov_ne_m2=((sigma_m**2, 0.0), (0.0, sigma_m**2)),
        observations=3,
        first_seen_unix_s=t - 1.0,
        last_seen_unix_s=t,
        lat_deg=lat,
        lon_deg=lon,
        alt_m=alt,
    )


def incoming(r: VictimReport, seq: int, t_usec: int = 1_700_000_000_000_000) -> IncomingReport:
    return IncomingReport(r, seq, t_usec, 0, 191, 1_700_000_000.0)


def placed(r: VictimReport) -> Placed:
    geo = None if r.lat_deg is None else (r.lat_deg, r.lon_deg, r.alt_m)
    return Placed(r.robot_sysid, r.victim_id, r.north_m, r.east_m, r.cov_ne_m2, geo)  # type: ignore[arg-type]


# -- merge -----------------------------------------------------------------------


def test_gate_is_the_chi_square_99_percent_point_for_two_dof() -> None:
    from scipy.stats import chi2

    assert pytest.approx(chi2.ppf(0.99, df=2), abs=1e-4) == merge.CHI2_GATE_2DOF_99


def test_mahalanobis_in_local_and_geodetic_frames_agree() -> None:
    # 1 m apart, sigma 0.5 m each: d² = 1 / (0.25 + 0.25) = 2
    a, b = report(1, 1, 10.0, 5.0), report(2, 1, 11.0, 5.0)
    assert merge.mahalanobis2(placed(a), placed(b)) == pytest.approx(2.0)
    ga, gb = report(1, 1, 10.0, 5.0, geo=True), report(2, 1, 11.0, 5.0, geo=True)
    # Exact geodesy round trip: millimetre agreement over 10 m.
    assert merge.mahalanobis2(placed(ga), placed(gb)) == pytest.approx(2.0, abs=1e-3)
    assert merge.mahalanobis2(placed(a), placed(gb)) is None  # no common frame


def test_assign_merges_across_robots_only_within_the_gate() -> None:
    groups = {1: [placed(report(1, 1, 0.0, 0.0))]}
    assert merge.assign(placed(report(2, 7, 0.5, 0.5)), None, groups) == 1
    assert merge.assign(placed(report(2, 7, 3.0, 0.0)), None, groups) is None  # d² = 18
    assert merge.assign(placed(report(1, 2, 0.1, 0.0)), None, groups) is None  # same robot


def test_assign_detaches_a_source_that_moved_away() -> None:
    a, b = placed(report(1, 1, 0.0, 0.0)), placed(report(2, 1, 0.2, 0.0))
    moved = placed(report(2, 1, 8.0, 0.0))
    assert merge.assign(moved, 1, {1: [a, b]}) is None
    assert merge.assign(placed(report(2, 1, 0.3, 0.0)), 1, {1: [a, b]}) == 1


def test_fuse_weights_by_information() -> None:
    sharp, blurred = report(1, 1, 0.0, 0.0, sigma_m=0.1), report(2, 1, 1.0, 0.0, sigma_m=1.0)
    fused = merge.fuse([placed(sharp), placed(blurred)])
    # x = (0/0.01 + 1/1) / (1/0.01 + 1/1) = 1/101
    assert fused.north_m == pytest.approx(1.0 / 101.0)
    assert fused.cov_ne_m2[0][0] == pytest.approx(1.0 / 101.0)


# -- registry --------------------------------------------------------------------


def test_registry_duplicates_stale_and_merge(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        a = incoming(report(1, 1, 0.0, 0.0, urgency=Urgency.LIGHT), 1)
        b = incoming(report(2, 5, 0.3, 0.0, urgency=Urgency.CRITICAL), 1)
        assert reg.store_reports([a, b]) == [StoreResult.ACCEPTED] * 2
        assert reg.store_reports([a]) == [StoreResult.DUPLICATE]
        older = incoming(report(1, 1, 9.0, 9.0), 0, t_usec=1_600_000_000_000_000)
        assert reg.store_reports([older]) == [StoreResult.STALE]
        (v,) = hq_victims(reg)
        assert v.sources == ((1, 1), (2, 5))
        assert v.urgency == Urgency.CRITICAL and v.visibility_pct == 5.0
        assert reg.report_count() == 3


def test_robot_merged_track_folds_into_its_target(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        reg.store_reports([incoming(report(1, 1, 0.0, 0.0), 1)])
        reg.store_reports([incoming(report(1, 2, 4.0, 0.0), 2)])
        assert len(hq_victims(reg)) == 2
        gone = IncomingReport(
            report(1, 2, 4.0, 0.0, state=TrackState.MERGED), 3, 2 * 10**15, 1, 191, 0.0
        )
        reg.store_reports([gone])
        (v,) = hq_victims(reg)
        assert v.sources == ((1, 1),)


def test_actions_need_a_known_victim_and_count_as_pending(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        reg.store_reports([incoming(report(3, 4, 0.0, 0.0), 1)])
        with pytest.raises(KeyError):
            reg.add_action(3, 99, OperatorAction.RESCUED)
        seq = reg.add_action(3, 4, OperatorAction.FALSE_ALARM)
        (v,) = hq_victims(reg)
        assert (v.state, v.actions_pending) == (TrackState.FALSE_ALARM, 1)
        assert reg.ack_action(seq, 1.0, 0) and not reg.ack_action(seq, 2.0, 0)
        assert hq_victims(reg)[0].actions_pending == 0


def test_foreign_sqlite_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "other.sqlite"
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE photos (id INTEGER)")
    db.close()
    with pytest.raises(RegistryError, match="not a rescue-hq registry"):
        Registry(path)


# -- exports and table -----------------------------------------------------------


def test_exports_hold_every_placed_victim(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        reg.set_default_origin(ORIGIN)
        reg.store_reports(
            [
                incoming(report(1, 1, 0.0, 0.0, urgency=Urgency.CRITICAL), 1),
                incoming(report(2, 1, 20.0, 0.0, geo=True, urgency=Urgency.LIGHT), 1),
            ]
        )
        victims = hq_victims(reg)
    result = export.export_all(victims, tmp_path / "out")
    assert (result.placed, result.local_only) == (2, 0)
    geo = json.loads((tmp_path / "out" / export.GEOJSON_NAME).read_text())
    coords = np.array([f["geometry"]["coordinates"][:2] for f in geo["features"]])
    lat0, _, _ = ned_to_geodetic(ORIGIN, 0.0, 0.0, 0.0)
    lat20, _, _ = ned_to_geodetic(ORIGIN, 20.0, 0.0, 0.0)
    assert sorted(coords[:, 1]) == pytest.approx([lat0, lat20], abs=1e-9)
    root = ET.parse(tmp_path / "out" / export.KML_NAME).getroot()
    assert len(root.findall(".//{http://www.opengis.net/kml/2.2}Placemark")) == 2
    with (tmp_path / "out" / export.CSV_NAME).open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["urgency"] for r in rows] == ["CRITICAL", "LIGHT"]  # most urgent first
    assert float(rows[0]["lat_deg"]) == pytest.approx(lat0, abs=1e-8)
    # No QGC .plan: uploading one replaces the vehicle's mission, fence and rally
    # points, and RTL would drive the rover to a victim.
    assert sorted(p.name for p in result.written) == sorted(
        [export.GEOJSON_NAME, export.KML_NAME, export.CSV_NAME]
    )
    assert not list((tmp_path / "out").glob("*.plan"))


def test_victims_without_lat_lon_or_origin_stay_out_of_the_files(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        reg.store_reports([incoming(report(1, 1, 0.0, 0.0), 1)])
        victims = hq_victims(reg)
    result = export.export_all(victims, tmp_path)
    assert (result.placed, result.local_only) == (0, 1)
    assert json.loads((tmp_path / export.GEOJSON_NAME).read_text())["features"] == []


def test_table_colours_only_on_a_terminal(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        reg.store_reports([incoming(report(1, 1, 0.0, 0.0, urgency=Urgency.CRITICAL), 1)])
        victims, robots = hq_victims(reg), reg.robots()
    header = table.Header(245, ["udpin:0.0.0.0:14600"], 1, False)
    now = victims[0].last_seen_unix_s + 125.0
    plain = table.render(header, victims, robots, now, colour=False)
    assert "\x1b[" not in plain
    assert "CRITICAL" in plain and "1:1" in plain and "2m05s" in plain
    coloured = table.render(header, victims, robots, now, colour=True)
    assert "\x1b[1;97;41mCRITICAL" in coloured  # red


def test_newer_report_wins_by_sequence_even_when_the_robot_clock_stepped_back(
    tmp_path: Path,
) -> None:
    # The robot's clock was corrected an hour back between two reports: report_seq,
    # not the wall clock, says which is newer.
    with Registry(tmp_path / "r.sqlite") as reg:
        t = 1_700_000_000_000_000
        first = incoming(report(1, 1, 0.0, 0.0, urgency=Urgency.LIGHT), 11, t_usec=t)
        after_step = incoming(
            report(1, 1, 0.2, 0.0, urgency=Urgency.CRITICAL), 12, t_usec=t - 3_600_000_000
        )
        assert reg.store_reports([first]) == [StoreResult.ACCEPTED]
        assert reg.store_reports([after_step]) == [StoreResult.ACCEPTED]
        (src,) = reg.sources()
        assert (src.report_seq, src.report.urgency) == (12, Urgency.CRITICAL)
        late = incoming(report(1, 1, 9.0, 0.0), 10, t_usec=t + 10_000_000)  # older seq, later clock
        assert reg.store_reports([late]) == [StoreResult.STALE]


def test_table_says_what_the_visibility_number_is(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        r = report(1, 1, 0.0, 0.0, urgency=Urgency.LIGHT)
        reg.store_reports([incoming(replace(r, visibility_pct=48.0), 1)])
        victims = hq_victims(reg)
    text = table.render(table.Header(245, ["udp"], 1, False), victims, [], 0.0, colour=False)
    head, row = text.splitlines()[2:4]
    assert "VISIBLE" in head and "LIGHT" in row and "48%" in row
