"""The mission map's labels: readable where victims and true victims crowd together."""

from __future__ import annotations

from companion.commands.missionmap import place_labels


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> int:
    return max(0, min(a[2], b[2]) - max(a[0], b[0])) * max(0, min(a[3], b[3]) - max(a[1], b[1]))


def test_crowded_labels_overlap_no_marker_and_no_other_label_and_stay_inside() -> None:
    # A reported victim beside its true one, pairs near the map's right edge (as the
    # demo's map had them: "T1 LIGHT" was hidden under V2's marker).
    markers = [(165, 645), (175, 650), (320, 335), (335, 330), (178, 105), (170, 146)]
    texts = [
        "T1 LIGHT",
        "V2 LIGHT 100%",
        "T2 MEDIUM",
        "V3 LIGHT 81%",
        "T3 CRITICAL",
        "V1 MEDIUM 16%",
    ]
    area = (0, 0, 370, 900)
    placed = place_labels(list(zip(texts, markers, strict=True)), markers, area)
    assert [p[0] for p in placed] == texts
    boxes = [box for _text, _origin, box in placed]
    for i, box in enumerate(boxes):
        assert area[0] <= box[0] < box[2] <= area[2] and area[1] <= box[1] < box[3] <= area[3]
        for x, y in markers:
            assert _overlap(box, (x - 9, y - 9, x + 9, y + 9)) == 0, (texts[i], (x, y))
        for j in range(i):
            assert _overlap(box, boxes[j]) == 0, (texts[i], texts[j])


def test_a_buried_true_victim_is_joined_to_its_uncovered_part(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A buried victim is found where it shows, and scored so: the map draws the
    uncovered part of a simulated victim (a ring, joined to the body's centre), so
    a report there does not look 0.6 m off. None for a whole body."""
    import cv2

    from companion.commands.missionmap import MapTruth, draw_mission_map
    from fusion.types import Urgency

    def draw(visible_ne_m: tuple[float, float] | None):  # type: ignore[no-untyped-def]
        path = tmp_path / "map.png"
        truth = [MapTruth("T1", Urgency.CRITICAL, 1.0, 1.0, visible_ne_m)]
        draw_mission_map(path, [], [], truth, extent_ne_m=(0.0, 4.0, 0.0, 4.0))
        return cv2.imread(str(path))

    img = draw((3.0, 3.0))
    scale = (900 - 2 * 50) / 4.0
    x, y = int(50 + 3.0 * scale), int(img.shape[0] - 50 - 3.0 * scale)  # (3, 3) m
    grey = img.min(axis=2)
    # A ring of radius 5 around (3, 3) m: dark east and north of it, where the line
    # to the body's centre (to the south-west) does not run.
    assert grey[y, x + 5] < 60 and grey[y - 5, x] < 60
    plain = draw(None)
    assert (plain != img).any()
    # No part known, or one beside the centre (the cross says it): the plain map.
    assert (draw((float("nan"), float("nan"))) == plain).all()
    assert (draw((1.1, 1.0)) == plain).all()
