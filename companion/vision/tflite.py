"""Running a ``.tflite`` model on the CPU, and the image crops models expect.

``Model`` wraps LiteRT's interpreter (pip ``ai-edge-litert``; wheels for aarch64
and x86-64), on one thread by default: the Pi's other cores belong to the link and
camera threads (``detector.model_threads`` gives it more). Inputs are float RGB
scaled to the range each model was trained with.

Two crops: ``letterbox`` (the whole frame padded to a square, as MediaPipe feeds
its detectors, so people keep their shape) and ``RotatedRect`` (an oriented square
around one body, as the landmark model expects it: head up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from companion.vision.base import DetectorUnavailable


class Model:
    """One TFLite model on ``threads`` CPU threads. Not thread-safe: one per pipeline."""

    def __init__(self, path: Path, threads: int = 1) -> None:
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError:
            raise DetectorUnavailable(
                "the person models need the `ai-edge-litert` package (pip install ai-edge-litert)"
            ) from None
        self.threads = threads
        try:
            self._it = Interpreter(model_path=str(path), num_threads=threads)
            self._it.allocate_tensors()
        except (ValueError, RuntimeError) as exc:
            raise DetectorUnavailable(f"model file {path} cannot be loaded: {exc}") from None
        inp = self._it.get_input_details()[0]
        self._input_index = inp["index"]
        self.input_hw: tuple[int, int] = (int(inp["shape"][1]), int(inp["shape"][2]))
        self._outputs = [d["index"] for d in self._it.get_output_details()]

    def __call__(self, rgb01: np.ndarray) -> list[np.ndarray]:
        """Outputs for one float32 HxWx3 input; each output without its batch axis."""
        self._it.set_tensor(self._input_index, rgb01[None].astype(np.float32, copy=False))
        self._it.invoke()
        return [self._it.get_tensor(i)[0] for i in self._outputs]


def to_range(rgb_u8: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """uint8 RGB to float32 in [lo, hi]."""
    return rgb_u8.astype(np.float32) * np.float32((hi - lo) / 255.0) + np.float32(lo)


@dataclass(frozen=True)
class Letterbox:
    """A frame padded to a square of side ``side_px`` then resized to the model input."""

    side_px: float
    pad_x_px: float
    pad_y_px: float

    def to_image(self, xy01: np.ndarray) -> np.ndarray:
        """Points in [0, 1] of the model input to frame pixels."""
        out = np.asarray(xy01, dtype=np.float64) * self.side_px
        out[..., 0] -= self.pad_x_px
        out[..., 1] -= self.pad_y_px
        return out


def letterbox(rgb: np.ndarray, size_px: int) -> tuple[np.ndarray, Letterbox]:
    h, w = rgb.shape[:2]
    side = max(h, w)
    pad_x, pad_y = (side - w) // 2, (side - h) // 2
    scale = size_px / side
    resized = cv2.resize(
        rgb, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA
    )
    out = np.zeros((size_px, size_px, 3), dtype=rgb.dtype)
    oy, ox = round(pad_y * scale), round(pad_x * scale)
    out[oy : oy + resized.shape[0], ox : ox + resized.shape[1]] = resized[
        : size_px - oy, : size_px - ox
    ]
    return out, Letterbox(float(side), float(pad_x), float(pad_y))


@dataclass(frozen=True)
class RotatedRect:
    """A square of side ``size_px`` centred at ``(cx, cy)``, turned by ``angle_rad``
    (clockwise in the image, y down): its own "down" points from head to feet."""

    cx_px: float
    cy_px: float
    size_px: float
    angle_rad: float

    def _corners(self) -> np.ndarray:
        c, s = math.cos(self.angle_rad), math.sin(self.angle_rad)
        ux, uy = np.array([c, s]), np.array([-s, c])
        centre = np.array([self.cx_px, self.cy_px])
        half = self.size_px / 2.0
        return np.array(
            [
                centre - half * ux - half * uy,
                centre + half * ux - half * uy,
                centre - half * ux + half * uy,
            ],
            dtype=np.float32,
        )

    def affine_to_crop(self, crop_px: int) -> np.ndarray:
        dst = np.array([[0, 0], [crop_px, 0], [0, crop_px]], dtype=np.float32)
        return cv2.getAffineTransform(self._corners(), dst)

    def crop(self, image: np.ndarray, crop_px: int) -> np.ndarray:
        return cv2.warpAffine(
            image,
            self.affine_to_crop(crop_px),
            (crop_px, crop_px),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
        )

    def to_image(self, xy_crop: np.ndarray, crop_px: int) -> np.ndarray:
        """Points in crop pixels back to frame pixels."""
        inv = cv2.invertAffineTransform(self.affine_to_crop(crop_px))
        pts = np.asarray(xy_crop, dtype=np.float64).reshape(-1, 2)
        return pts @ inv[:, :2].T + inv[:, 2]

    def paste(self, crop: np.ndarray, frame_hw: tuple[int, int]) -> np.ndarray:
        """A crop-sized float map drawn back onto a frame-sized one (0 outside)."""
        return cv2.warpAffine(
            crop,
            self.affine_to_crop(crop.shape[0]),
            (frame_hw[1], frame_hw[0]),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
