"""The Appendix A threshold detector against synthetic scenes with known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from keymps.config.task import Task
from keymps.default_plugins.threshold_detector import ThresholdDetector, ThresholdOptions
from keymps.errors import KeympsError
from keymps.perception.frames import object_outline_m
from keymps.plugin.manager import create_component
from keymps.scenes.render import KINDS, ObjectSpec, SceneSpec, render_scene
from keymps.types import SceneImage

SEEDS = range(20)


def distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance of each point to the closed polygon's boundary."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    ap = points[:, None, :] - a[None]
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-18), 0, 1)
    nearest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - nearest, axis=-1).min(axis=1)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_box_matches_the_true_box_within_2px_for_20_seeds(kind: str) -> None:
    detector = ThresholdDetector()
    errors = []
    for seed in SEEDS:
        scene = render_scene(SceneSpec.from_kinds([kind], seed=seed, px_per_m=1000))
        detection = detector.detect(SceneImage(scene.image, "synthetic"))
        truth = scene.truth["objects"][0]["bbox_px"]
        errors.append(np.abs(np.subtract(detection.bbox_px, truth)).max())
        assert detection.warnings == (), (seed, detection.warnings)
    assert max(errors) <= 2, f"{kind}: box errors per seed {errors}"


@pytest.mark.parametrize("kind", ["round_cake", "eggplant", "banana", "chiffon_cake"])
def test_detected_outline_lies_within_a_millimetre_of_the_true_outline(kind: str) -> None:
    scene = render_scene(SceneSpec.from_kinds([kind], seed=4, px_per_m=2000))
    detection = ThresholdDetector().detect(scene.image)
    task = Task.model_validate(
        {"name": "t", "instruction": "x", "scene": {"image": "x.png"}, "primitives": ["a"]}
    )
    outline = object_outline_m(detection, task, (600, 360))
    truth = np.array(scene.truth["objects"][0]["outline_m"])
    assert distance_to_polygon(outline, truth).max() < 0.0012


def test_mask_crop_padding_and_inputs() -> None:
    scene = render_scene(SceneSpec.from_kinds(["potato"], seed=1, px_per_m=1000))
    image = scene.image
    detection = ThresholdDetector(ThresholdOptions(padding=7)).detect(image)
    x0, y0, x1, y1 = detection.bbox_px
    assert detection.crop_origin_px == (x0 - 7, y0 - 7)
    assert detection.crop_size_px == (x1 - x0 + 14, y1 - y0 + 14)
    np.testing.assert_array_equal(detection.crop, image[y0 - 7 : y1 + 7, x0 - 7 : x1 + 7])
    assert detection.mask is not None and detection.mask.shape == image.shape[:2]
    truth_area = scene.truth["objects"][0]["area_m2"] * 1000**2
    assert detection.mask.sum() == pytest.approx(truth_area, rel=0.05)
    assert detection.contour_px.shape[1] == 2

    gray = image.mean(axis=2).astype(np.uint8)
    assert ThresholdDetector().detect(gray).bbox_px == pytest.approx(detection.bbox_px, abs=2)
    sixteen = image.astype(np.uint16) * 257
    assert ThresholdDetector().detect(sixteen).bbox_px == detection.bbox_px


def test_crop_padding_is_clipped_at_the_image_border() -> None:
    image = np.full((100, 160, 3), 120, np.uint8)
    image[0:30, 0:40] = 230  # touches the top-left corner
    detection = ThresholdDetector(ThresholdOptions(padding=10, blur=0)).detect(image)
    assert detection.bbox_px == (0, 0, 40, 30)
    assert detection.crop_origin_px == (0, 0)
    assert detection.crop_size_px == (50, 40)
    assert any("touches the image border (left, top)" in w for w in detection.warnings)


def test_no_object_and_empty_image_messages() -> None:
    flat = np.full((90, 120, 3), 128, np.uint8)
    flat += np.random.default_rng(0).integers(0, 4, size=flat.shape, dtype=np.uint8)
    with pytest.raises(
        KeympsError, match=r"detect: no object found: .*background intensity 1[23]\d"
    ):
        ThresholdDetector().detect(flat)
    with pytest.raises(KeympsError, match="detect: the scene image is empty"):
        ThresholdDetector().detect(np.zeros((0, 0, 3), np.uint8))


def two_object_scene() -> tuple[np.ndarray, list[list[int]]]:
    spec = SceneSpec(
        objects=(
            ObjectSpec("potato", 0.09, 0.062, 0.05, 0.0, centre=(0.08, 0.09)),
            ObjectSpec("potato", 0.085, 0.06, 0.05, 10.0, centre=(0.22, 0.09)),
        ),
        seed=2,
        px_per_m=1000,
    )
    scene = render_scene(spec)
    return scene.image, [obj["bbox_px"] for obj in scene.truth["objects"]]


def test_every_object_is_listed_and_pick_keeps_one_naming_the_other() -> None:
    image, boxes = two_object_scene()
    first = ThresholdDetector().detect(image)
    assert np.abs(np.subtract(first.bbox_px, boxes[0])).max() <= 2
    assert len(first.others_px) == 1
    assert np.abs(np.subtract(first.others_px[0], boxes[1])).max() <= 2
    # both are objects (numbered left to right), the crop covers both, nothing to warn about
    assert [o.id for o in first.objects] == [1, 2] and first.warnings == ()
    for obj, box in zip(first.objects, boxes, strict=True):
        assert np.abs(np.subtract(obj.bbox_px, box)).max() <= 2
        assert obj.mask is not None and obj.mask.sum() == pytest.approx(obj.area_px, rel=0.05)
    x0, y0 = first.crop_origin_px
    width, height = first.crop_size_px
    assert x0 <= boxes[0][0] and x0 + width >= boxes[1][2]

    picked = ThresholdDetector(ThresholdOptions(pick=0)).detect(image)
    (warning,) = picked.warnings
    assert "another of comparable size" in warning
    assert str(list(picked.bbox_px)) in warning and str(list(picked.others_px[0])) in warning
    assert "detector.pick: 1 keeps that one (by decreasing area, from 0)" in warning
    assert len(picked.objects) == 1

    second = ThresholdDetector(ThresholdOptions(pick=1)).detect(image)
    assert np.abs(np.subtract(second.bbox_px, boxes[1])).max() <= 2
    with pytest.raises(KeympsError, match=r"detector.pick is 2 but only 2 region\(s\)"):
        ThresholdDetector(ThresholdOptions(pick=2)).detect(image)
    # A small second object is listed but not warned about.
    quiet = ThresholdDetector(ThresholdOptions(comparable=1.0, pick=0)).detect(image)
    assert quiet.warnings == () and len(quiet.others_px) == 1


def test_plugin_options_are_validated_with_clear_messages() -> None:
    detector = create_component("detector", "threshold", {"threshold": 45, "blur": 3})
    assert isinstance(detector, ThresholdDetector)
    assert detector.options.threshold == 45
    with pytest.raises(KeympsError, match=r"option 'threshold': Input should be greater"):
        create_component("detector", "threshold", {"threshold": 0})
    with pytest.raises(KeympsError, match=r"option 'blur': must be odd"):
        create_component("detector", "threshold", {"blur": 4})
    with pytest.raises(KeympsError, match=r"option 'thresh': unknown option \(options: threshold"):
        create_component("detector", "threshold", {"thresh": 20})


def test_fixed_background_option_overrides_the_most_common_intensity() -> None:
    # The object covers most of the image: the most common intensity is the object's, and
    # Appendix A then finds the strip of board instead.
    image = np.full((100, 100), 120, np.uint8)
    image[:, :70] = 220
    options = {"blur": 0, "threshold": 30}
    assert ThresholdDetector(ThresholdOptions(**options)).detect(image).bbox_px == (70, 0, 100, 100)
    fixed = ThresholdDetector(ThresholdOptions(background=120, **options)).detect(image)
    assert fixed.bbox_px == (0, 0, 70, 100)


def test_roi_limits_the_search_to_the_board_in_a_photo() -> None:
    """A photo at an angle shows a dark table around the board: search the board polygon only."""
    import cv2

    scene = render_scene(SceneSpec.from_kinds(["round_cake"], seed=2, px_per_m=1000))
    board_px = np.array([[0, 180], [300, 180], [300, 0], [0, 0]], np.float32)
    corners = np.array([[30, 220], [330, 210], [300, 35], [55, 48]], np.float32)
    warp = cv2.getPerspectiveTransform(board_px, corners)
    photo = cv2.warpPerspective(scene.image, warp, (360, 240), borderValue=(30, 30, 30))
    truth = cv2.perspectiveTransform(
        np.array(scene.truth["objects"][0]["outline_px"]).reshape(-1, 1, 2), warp.astype(float)
    ).reshape(-1, 2)
    expected = [*truth.min(axis=0), *truth.max(axis=0)]
    whole = ThresholdDetector().detect(photo)
    assert np.abs(np.subtract(whole.bbox_px, expected)).max() > 20  # it takes the table
    detector = create_component("detector", "threshold", {"roi": corners.tolist()})
    detection = detector.detect(photo)
    assert np.abs(np.subtract(detection.bbox_px, expected)).max() <= 2
    assert detection.warnings == ()
    box = ThresholdDetector(ThresholdOptions(roi=[0, 0, 150, 240])).detect(photo)
    assert any("touches the border of detector.roi" in w for w in box.warnings)
    with pytest.raises(KeympsError, match=r"option 'roi': .*a box must be"):
        create_component("detector", "threshold", {"roi": [10, 10, 5, 50]})
