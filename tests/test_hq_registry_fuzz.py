"""Fuzz the HQ registry's rows, its state on disk: any value of any SQLite type in any
cell of a registry that rescue-hq wrote (a file damaged or edited by hand) leaves
every read the HQ, its console and its exports make working: the row is skipped
and named, never an exception. A damaged schema version or epoch is a RegistryError
naming the file (rescue-hq then moves the file aside or refuses it: test_hq_recovery)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st

from fusion.types import GlobalOrigin
from hq import coverage
from hq.export import coverage_geojson, export_all
from hq.records import OperatorAction, RobotStatus
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.view import hq_victims
from hq.web.feed import picture_versions
from tests.jsonfuzz import fuzz_settings
from tests.sqlitefuzz import Cell, cell_values, cells, damaged_copy, template_dir
from tests.test_hq_units import ORIGIN, incoming, report


def _template() -> Path:
    """A registry as a mission leaves it: reports of two robots, a status, origins, an
    action sent and acknowledged, a picture, two robots' searched-area cells."""
    path = template_dir("hq-fuzz-") / "template.sqlite"
    ok, jpeg = cv2.imencode(".jpg", np.full((32, 48, 3), 120, np.uint8))
    assert ok
    with Registry(path) as reg:
        reg.store_reports(
            [
                incoming(report(1, 1, 1.0, 2.0, geo=True), 1),
                incoming(report(1, 2, 6.0, 2.0), 2),
                incoming(report(2, 1, 1.2, 2.1), 1),
            ]
        )
        reg.store_status(1, 191, RobotStatus(60.0, 5.0, 0.0, 40.0, 7, 2, 0, 0), 1.7e9)
        reg.set_robot_origin(1, 191, ORIGIN)
        reg.set_default_origin(GlobalOrigin(47.0, 8.0, 400.0))
        seq = reg.add_action(1, 1, OperatorAction.RESCUED)
        reg.note_action_sent(seq, 1.7e9)
        reg.ack_action(seq, 1.7e9 + 1, 0)
        reg.store_picture(1, 1, 3, jpeg.tobytes(), 1.7e9)
        reg.store_coverage(1, [(0, 0, 200), (0, 1, 90), (3, -2, 12)])
        reg.store_coverage(2, [(0, 0, 150), (5, 5, 255)])
    return path


TEMPLATE = _template()


CELLS = cells(TEMPLATE)
VALUES = cell_values | st.sampled_from(
    ['{"victim_id": 1}', "{}", "[]", "null", '{"lat_deg": 91}', "NaN"]  # JSON payloads
)


@fuzz_settings(150)
@given(edits=st.lists(st.tuples(st.sampled_from(CELLS), VALUES), min_size=1, max_size=3))
# Found by this test (2026-11-29): a robot's sysid cell holding a newline named its row on
# two lines of the log ("reports robot \n victim 1").
@example(edits=[(("reports", "robot_sysid", 1), "\n")])
def test_any_value_in_any_cell_is_skipped_and_named(
    edits: list[tuple[Cell, Any]],
) -> None:
    with tempfile.TemporaryDirectory(prefix="hq-fuzz-", ignore_cleanup_errors=True) as tmp:
        work = Path(tmp)
        path = work / "hq.sqlite"
        damaged_copy(TEMPLATE, path, edits)
        try:
            reg = Registry(path)
        except RegistryError as exc:  # its schema version or epoch: the file as a whole
            assert str(path) in str(exc) and "\n" not in str(exc), str(exc)
            return
        with reg:
            victims = hq_victims(reg)
            reg.robots()
            reg.report_count()
            reg.first_received_unix_s()
            picture_versions(reg, victims)
            for v in victims:
                for robot, victim in v.sources:
                    reg.picture(robot, victim)
                    reg.picture_id(robot, victim)
            export_all(victims, work / "exports")
            merged = coverage.load(reg)  # the searched-area map: console and exports
            coverage.console_json(merged, {1: (0.0, 0.0)})
            coverage_geojson(merged)
            assert all(where and "\n" not in where for where in reg.bad_rows)


def test_a_picture_row_with_a_damaged_number_is_replaced_by_the_next_picture(
    tmp_path: Path,
) -> None:
    """SQLite orders any text above every number: a damaged picture_id would have kept
    every later picture of that victim out."""
    path = tmp_path / "hq.sqlite"
    (rowid,) = [r for t, c, r in CELLS if (t, c) == ("pictures", "picture_id")]
    damaged_copy(TEMPLATE, path, [(("pictures", "picture_id", rowid), "x")])
    _, jpeg = cv2.imencode(".jpg", np.full((24, 32, 3), 60, np.uint8))
    with Registry(path) as reg:
        assert reg.picture_id(1, 1) is None
        assert "pictures robot 1 victim 1" in reg.bad_rows
        assert reg.store_picture(1, 1, 1, jpeg.tobytes(), 1.7e9 + 5)
        assert reg.picture_id(1, 1) == 1 and reg.picture(1, 1) == jpeg.tobytes()
