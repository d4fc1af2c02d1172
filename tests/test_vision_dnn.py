"""The dnn backend's whole path with real cv2.dnn and tiny ONNX models built here.

The model's output is a constant table of candidate boxes, except that one box's
person score is the mean of the network input's red channel: that checks the
letterbox padding (grey 114), BGR->RGB swap and 1/255 scaling on the way in, and
decoding, un-letterboxing and NMS on the way out, with exactly known answers.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from companion.config import DetectorConfig
from companion.vision.backends import make_detector
from companion.vision.base import DetectorUnavailable, FrameGeometry
from companion.vision.dnn import decode, letterbox

INPUT_PX = 320
# Candidates in input pixels (cx, cy, w, h) with (person, other) class scores.
# Frame 640x480 -> scale 0.5, pad_y 40.
CANDIDATES = [
    ((50.0, 90.0, 20.0, 50.0), (None, 0.0)),  # A: person score = mean red of the input
    ((51.0, 91.0, 20.0, 50.0), (0.70, 0.0)),  # B: overlaps A (IoU ~0.86): NMS removes it
    ((200.0, 150.0, 60.0, 30.0), (0.90, 0.0)),  # C: a lying person
    ((250.0, 200.0, 20.0, 20.0), (0.30, 0.0)),  # D: below min_score
    ((100.0, 200.0, 40.0, 40.0), (0.10, 0.95)),  # E: not a person class
]
N_CANDIDATES = 8  # rows beyond the list are zero


def _table(layout: str) -> tuple[np.ndarray, np.ndarray]:
    """(constant, mask) tables; output = constant + mask * mean_red."""
    channels = 4 + 2 if layout == "yolov8" else 5 + 2
    rows = np.zeros((N_CANDIDATES, channels), np.float32)
    mask = np.zeros_like(rows)
    first = 4 if layout == "yolov8" else 5
    for i, ((cx, cy, w, h), (person, other)) in enumerate(CANDIDATES):
        rows[i, :4] = (cx, cy, w, h)
        if layout == "yolov5":
            rows[i, 4] = 1.0  # objectness
        if person is None:
            mask[i, first] = 1.0
        else:
            rows[i, first] = person
        rows[i, first + 1] = other
    if layout == "yolov8":
        return rows.T[None].copy(), mask.T[None].copy()
    return rows[None], mask[None]


def _model(path: Path, layout: str) -> Path:
    const, mask = _table(layout)
    nodes = [
        helper.make_node("Slice", ["images", "s0", "s1", "ax"], ["red"]),
        helper.make_node("ReduceMean", ["red"], ["mean4"], axes=[1, 2, 3], keepdims=1),
        helper.make_node("Reshape", ["mean4", "shape3"], ["mean3"]),
        helper.make_node("Mul", ["mask", "mean3"], ["varying"]),
        helper.make_node("Add", ["const", "varying"], ["output0"]),
    ]
    inits = [
        numpy_helper.from_array(np.array([0], np.int64), "s0"),
        numpy_helper.from_array(np.array([1], np.int64), "s1"),
        numpy_helper.from_array(np.array([1], np.int64), "ax"),
        numpy_helper.from_array(np.array([1, 1, 1], np.int64), "shape3"),
        numpy_helper.from_array(const, "const"),
        numpy_helper.from_array(mask, "mask"),
    ]
    graph = helper.make_graph(
        nodes,
        "tiny_yolo",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, INPUT_PX, INPUT_PX])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(const.shape))],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def _red_frame() -> np.ndarray:
    frame = np.zeros((480, 640, 3), np.uint8)
    frame[:, :, 2] = 255  # BGR: pure red
    return frame


# Mean of the input's red channel: 3/4 of the square is the red frame, 1/4 padding (114).
MEAN_RED = (0.75 * 255 + 0.25 * 114) / 255


@pytest.mark.parametrize("layout", ["yolov8", "yolov5"])
def test_boxes_scores_letterbox_and_nms(tmp_path: Path, layout: str) -> None:
    model = _model(tmp_path / f"tiny_{layout}.onnx", layout)
    config = DetectorConfig(
        backend="dnn", dnn_model=model, dnn_input_px=INPUT_PX, enhance=False, min_score=0.5
    )
    dets = make_detector(config).detect(_red_frame(), None, t_mono_s=12.5)
    dets.sort(key=lambda d: d.score)
    assert [d.source for d in dets] == ["dnn", "dnn"]
    a, c = dets  # B lost to A in NMS, D too weak, E not a person
    assert a.score == pytest.approx(MEAN_RED, abs=1e-3)  # float32 mean over 320^2 pixels
    # A: input box (40, 65, 20, 50) -> frame ((40-0)/0.5, (65-40)/0.5) = (80, 50), 40 x 100.
    assert a.bbox_xywh_px == (80, 50, 40, 100)
    assert (a.u_px, a.v_px) == pytest.approx((100.0, 149.5))  # upright: bottom centre
    assert a.visible_area_px == pytest.approx(40 * 100 * 0.5)  # box x fill ratio
    # C: input (170, 135, 60, 30) -> frame (340, 190, 120, 60): lying, centre.
    assert c.score == pytest.approx(0.9, abs=1e-6)
    assert c.bbox_xywh_px == (340, 190, 120, 60)
    assert (c.u_px, c.v_px) == pytest.approx((400.0, 220.0))
    assert all(d.t_mono_s == 12.5 for d in dets)


def test_a_dark_frame_drops_the_input_dependent_box(tmp_path: Path) -> None:
    model = _model(tmp_path / "tiny.onnx", "yolov8")
    config = DetectorConfig(backend="dnn", dnn_model=model, dnn_input_px=INPUT_PX, enhance=False)
    dets = make_detector(config).detect(np.zeros((480, 640, 3), np.uint8), None, 0.0)
    # Mean red is now 0.25 * 114 / 255 = 0.11 < 0.5: A is gone, so B (0.7) survives NMS.
    assert sorted(round(d.score, 3) for d in dets) == [0.7, 0.9]


def test_geometry_drops_boxes_off_the_floor(tmp_path: Path) -> None:
    model = _model(tmp_path / "tiny.onnx", "yolov8")
    config = DetectorConfig(backend="dnn", dnn_model=model, dnn_input_px=INPUT_PX, enhance=False)
    floor_below_row_200 = FrameGeometry.constant(0.01, floor_from_v_px=200.0)
    dets = make_detector(config).detect(_red_frame(), floor_below_row_200, 0.0)
    assert [d.bbox_xywh_px for d in dets] == [(340, 190, 120, 60)]  # A's feet are at row 150


def test_class_ids_from_config_select_the_class(tmp_path: Path) -> None:
    model = _model(tmp_path / "tiny.onnx", "yolov8")
    config = DetectorConfig(
        backend="dnn",
        dnn_model=model,
        dnn_input_px=INPUT_PX,
        dnn_person_class_ids=(1,),
        enhance=False,
    )
    dets = make_detector(config).detect(_red_frame(), None, 0.0)
    assert [(d.bbox_xywh_px, round(d.score, 3)) for d in dets] == [
        ((160, 280, 80, 80), 0.95)
    ]  # (100-20)/.5, (200-20-40)/.5


def test_letterbox_pads_a_portrait_frame_sideways() -> None:
    boxed, lb = letterbox(np.zeros((640, 320, 3), np.uint8), 320)
    assert boxed.shape == (320, 320, 3)
    assert (lb.scale, lb.pad_x, lb.pad_y) == (0.5, 80.0, 0.0)
    assert boxed[:, :80].min() == 114 and boxed[:, 80:240].max() == 0


def test_decode_rejects_outputs_that_do_not_fit_the_classes() -> None:
    from companion.vision.base import VisionError

    with pytest.raises(VisionError, match="person class ids"):
        decode(np.zeros((1, 6, 100), np.float32), "yolov8", (5,), 0.5)
    with pytest.raises(VisionError, match="expected"):
        decode(np.zeros((6, 100), np.float32)[None, None], "auto", (0,), 0.5)


def test_missing_or_broken_model_is_detector_unavailable(tmp_path: Path) -> None:
    with pytest.raises(DetectorUnavailable, match="no such file"):
        make_detector(DetectorConfig(backend="dnn", dnn_model=tmp_path / "none.onnx"))
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"this is not protobuf")
    with pytest.raises(DetectorUnavailable, match="cannot load"):
        make_detector(DetectorConfig(backend="dnn", dnn_model=junk))


def test_hog_backend_builds_here_or_says_why() -> None:
    if hasattr(cv2, "HOGDescriptor"):
        det = make_detector(DetectorConfig(backend="hog"))
        assert det.name == "hog"
        assert det.detect(np.full((240, 320, 3), 90, np.uint8), None, 0.0) == []
    else:
        with pytest.raises(DetectorUnavailable, match="OpenCV 5"):
            make_detector(DetectorConfig(backend="hog"))
