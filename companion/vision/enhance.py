"""Dark-scene enhancement: adaptive gamma and CLAHE on luminance, denoising when dark.

Steps, on the image at whatever resolution the detector works at:

1. Brightness: mean luma (Y of YCrCb) on a 1/16 subsample, and the local level: a
   Gaussian (sigma ``zone_block_px``) of the luma.
2. Dark frames (mean below ``dark_mean``) and frames with a dark zone (a local
   level needing more than ``denoise_zone_gain``): a 3x3 median against
   salt-and-pepper noise, then a 3x3 Gaussian: sensor noise would otherwise break
   colour cues.
3. Dark zones: luma times target / local level (at most ``max_zone_gain``, never
   darker), so a pool of 7 % light comes up like the rest of the floor. A global
   gamma cannot do that when the frame as a whole is well exposed.
4. Adaptive gamma on luma, Y' = 255 (Y/255)^gamma with gamma = log(target)/log(mean)
   clamped to [gamma_min, gamma_max], so the mean moves towards ``target_mean``.
5. CLAHE on the gamma-corrected luma (local contrast, clip-limited so noise in
   flat areas is not blown up).
6. Colour: B, G, R are multiplied by the per-pixel luma gain y_out / y (capped at
   ``max_gain``). Luma is linear in B, G, R, so the result has luma y_out, and hue
   and saturation are kept (rg chromaticity is unchanged up to clipping).

Luma (YCrCb's Y, cv2's grey) is used rather than LAB's L: the LAB round trip costs
about 5 ms more per 640x480 frame on this machine for the same information, and the
gain trick needs no conversion back (bench/vision.py has the figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class EnhanceParams:
    target_mean: float = 0.45  # luma the gamma aims at, 0..1
    gamma_min: float = 0.35  # strongest brightening
    gamma_max: float = 1.5  # strongest darkening of an over-exposed frame
    gamma_dead_band: float = 0.05  # |gamma - 1| below this: no gamma
    clahe_clip: float = 2.0
    clahe_tiles: int = 8
    dark_mean: float = 0.25  # frames darker than this (mean luma) get denoised
    max_gain: float = 4.0  # cap of the per-pixel luma gain applied to chroma
    zone_block_px: int = 12  # sigma of the local level, pixels
    max_zone_gain: float = 12.0  # a 7 % light zone needs ~8x
    denoise_zone_gain: float = 2.5  # a zone needing more than this gets the frame denoised
    strong_denoise_zone_gain: float = 5.0  # ... and more than this a 5x5 mean there


@dataclass(frozen=True)
class EnhanceInfo:
    mean_luma: float  # 0..1, before enhancement
    gamma: float
    denoised: bool


class Enhancer:
    """Reusable enhancement (owns its CLAHE object; one per thread)."""

    def __init__(self, params: EnhanceParams | None = None) -> None:
        self.params = params or EnhanceParams()
        p = self.params
        self._clahe = cv2.createCLAHE(p.clahe_clip, (p.clahe_tiles, p.clahe_tiles))
        self.last: EnhanceInfo | None = None

    def gamma_for(self, mean_luma: float) -> float:
        p = self.params
        m = min(max(mean_luma, 1e-3), 0.999)
        gamma = math.log(p.target_mean) / math.log(m)
        gamma = min(p.gamma_max, max(p.gamma_min, gamma))
        return 1.0 if abs(gamma - 1.0) < p.gamma_dead_band else gamma

    def __call__(self, image_bgr: np.ndarray) -> np.ndarray:
        p = self.params
        mean_luma = float(image_bgr[::4, ::4].mean()) / 255.0  # ~ mean luma, 1/16 of pixels
        y0 = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)  # the Y of YCrCb
        level = _local_level(y0, p.zone_block_px)
        zone_gain = np.clip(p.target_mean * 255.0 / np.maximum(level, 1.0), 1.0, p.max_zone_gain)
        zone_max = float(zone_gain.max())
        dark = mean_luma < p.dark_mean or zone_max > p.denoise_zone_gain
        work = image_bgr
        y = y0
        if dark:
            work = cv2.GaussianBlur(cv2.medianBlur(work, 3), (3, 3), 0)
            if zone_max > p.strong_denoise_zone_gain:
                # Deep zones: a few grey levels of signal, chroma mostly sensor and JPEG
                # noise. Average 5x5 there (colour survives, texture does not matter).
                deep = zone_gain > p.strong_denoise_zone_gain
                work = np.where(deep[..., None], cv2.blur(work, (5, 5)), work)
            y = cv2.cvtColor(work, cv2.COLOR_BGR2GRAY)
        y_out = y
        if zone_max > 1.0 + p.gamma_dead_band:
            y_out = cv2.multiply(y, zone_gain, dtype=cv2.CV_8U)
            mean_luma = float(y_out[::4, ::4].mean()) / 255.0  # what the gamma sees now
        gamma = self.gamma_for(mean_luma)
        if gamma != 1.0:
            lut = (255.0 * (np.arange(256) / 255.0) ** gamma).round().astype(np.uint8)
            y_out = cv2.LUT(y_out, lut)
        y_out = self._clahe.apply(y_out)
        # Per-pixel luma gain applied to B, G, R alike: Y becomes y_out (Y is linear in
        # B, G, R) and chroma scales with it. gain = (y_out + 1) / (y + 1), capped.
        gain: np.ndarray = (y_out.astype(np.float32) + 1.0) / (y.astype(np.float32) + 1.0)
        np.clip(gain, 1.0 / p.max_gain, max(p.max_gain, p.max_zone_gain), out=gain)
        self.last = EnhanceInfo(mean_luma, gamma, dark)
        return cv2.multiply(work, cv2.merge([gain, gain, gain]), dtype=cv2.CV_8U)


def _local_level(luma: np.ndarray, scale_px: int) -> np.ndarray:
    """The smooth local brightness (float32): a Gaussian of sigma ``scale_px`` over a
    4x reduced copy (a zone's rim is followed; a body only dents it)."""
    h, w = luma.shape
    small = cv2.resize(luma, (max(1, w // 4), max(1, h // 4)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small.astype(np.float32), (0, 0), max(1.0, scale_px / 4.0))
    level: np.ndarray = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return level


def enhance(image_bgr: np.ndarray, params: EnhanceParams | None = None) -> np.ndarray:
    """The enhanced copy of a BGR uint8 image (same size)."""
    return Enhancer(params)(image_bgr)
