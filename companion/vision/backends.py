"""The configured detector backend: ``make_detector(config.detector)``.

Builds the configured backend (people, classic, dnn, hog), with enhancement inside it
when ``enhance = true`` (each backend enhances at its own working resolution: cheaper
than enhancing the full frame first). Each detector's ``detect(image_bgr, geometry,
t_mono_s)`` returns one ``fusion.types.Detection`` per victim.
"""

from __future__ import annotations

from companion.config import DetectorConfig
from companion.vision.base import Detector, DetectorUnavailable
from companion.vision.enhance import Enhancer


def make_detector(config: DetectorConfig, single_images: bool = False) -> Detector:
    """The configured detector; DetectorUnavailable when it cannot be built here.

    ``single_images``: each frame stands alone (photos, ``rescue-companion detect``),
    so no work is spread across frames."""
    enhancer = Enhancer() if config.enhance else None
    if config.backend == "people":
        from companion.vision.people import PeopleDetector
        from companion.vision.people_params import PeopleParams

        return PeopleDetector(
            PeopleParams(
                silhouette_fill=config.body_silhouette_fill,
                extra_passes=99 if single_images else PeopleParams.extra_passes,
                parts_take_turns=not single_images,
                landmarks=config.pose_landmarks,
            ),
            enhancer,
            config.min_score,
            config.model_dir,
            config.model_threads,
        )
    if config.backend == "classic":
        from companion.vision.classic import ClassicDetector
        from companion.vision.classic_params import ClassicParams

        params = ClassicParams(work_width_px=config.work_width_px)
        return ClassicDetector(params, enhancer, config.min_score)
    if config.backend == "dnn":
        from companion.vision.dnn import DnnDetector

        if config.dnn_model is None:  # the config rejects this already; say it anyway
            raise DetectorUnavailable("detector.dnn_model: required with backend = 'dnn'")
        return DnnDetector(
            config.dnn_model,
            input_px=config.dnn_input_px,
            person_class_ids=config.dnn_person_class_ids,
            min_score=config.min_score,
            nms_iou=config.dnn_nms_iou,
            layout=config.dnn_output_layout,
            fill_ratio=config.box_fill_ratio,
            enhancer=enhancer,
        )
    from companion.vision.hog import HogDetector

    return HogDetector(
        min_score=config.min_score,
        nms_iou=config.dnn_nms_iou,
        fill_ratio=config.box_fill_ratio,
        enhancer=enhancer,
    )
