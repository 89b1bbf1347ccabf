"""Appendix B/C grounding, axis conventions and the calibrated (homography) frame."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.perception.frames import ImageFrame, ground, height_pair, object_outline_m, polygon_area
from keymps.types import Detection, Plan


def make_task(**scene: Any) -> Task:
    height = scene.pop("height", {})
    data = {
        "name": "t",
        "instruction": "cut it",
        "scene": {"image": "x.png", "object_height": 0.06, **scene},
        "primitives": ["straight"],
        "height": height,
    }
    return Task.model_validate(data)


def make_detection(crop_origin: tuple[int, int] = (100, 50)) -> Detection:
    return Detection(
        bbox_px=(110, 60, 300, 200),
        crop=np.zeros((170, 220, 3), np.uint8),
        crop_origin_px=crop_origin,
    )


def make_plan(pairs_crop: np.ndarray, crop_origin: tuple[int, int]) -> Plan:
    pairs_crop = np.asarray(pairs_crop, dtype=float)
    return Plan(
        keyword="straight",
        pairs_crop_px=pairs_crop,
        pairs_px=pairs_crop + np.asarray(crop_origin, dtype=float),
        backend="test",
    )


def test_axis_conventions_corners_of_the_image() -> None:
    frame = ImageFrame.from_task(make_task(workspace={"size": [0.30, 0.18]}), (600, 360))
    corners_px = np.array([[0, 360], [600, 360], [600, 0], [0, 0], [300, 180]], dtype=float)
    expected = np.array([[0, 0], [0.30, 0], [0.30, 0.18], [0, 0.18], [0.15, 0.09]])
    np.testing.assert_allclose(frame.to_board(corners_px), expected, atol=1e-12)
    # Moving right in the image is +x on the board; moving down in the image is -y.
    step = frame.to_board(np.array([[10.0, 10.0], [11.0, 10.0], [10.0, 11.0]]))
    assert step[1, 0] - step[0, 0] == pytest.approx(0.0005)
    assert step[2, 1] - step[0, 1] == pytest.approx(-0.0005)
    np.testing.assert_allclose(frame.to_pixels(expected), corners_px, atol=1e-9)


def test_appendix_b_formula_with_offset_and_shift() -> None:
    """p' = p_local + b_offset (+ g_shift), / s_img, * s_env, then board y = h_env - y."""
    width_px, height_px, w_env, h_env = 640, 480, 0.32, 0.24
    shift_m = (0.02, -0.01)
    task = make_task(workspace={"size": [w_env, h_env], "shift": list(shift_m)})
    origin = (120, 40)
    local = np.array([[[10.0, 20.0], [50.0, 20.0]], [[0.0, 0.0], [7.5, 99.25]]])
    grounding = ground(
        make_plan(local, origin), make_detection(origin), task, (width_px, height_px)
    )
    # The paper's g_shift in pixels equivalent to the metric shift above:
    g_shift_px = np.array([shift_m[0] * width_px / w_env, -shift_m[1] * height_px / h_env])
    for k, segment in enumerate(grounding.segments):
        for point, local_px in ((segment.start, local[k, 0]), (segment.goal, local[k, 1])):
            p_prime = local_px + origin + g_shift_px
            p_norm = p_prime / (width_px, height_px)
            x_env, y_env = p_norm[0] * w_env, p_norm[1] * h_env
            assert point[0] == pytest.approx(x_env, abs=1e-12)
            assert point[1] == pytest.approx(h_env - y_env, abs=1e-12)
    assert grounding.segments[1].goal_px == (127.5, 139.25)
    assert grounding.workspace_size == (w_env, h_env)


@pytest.mark.parametrize(
    ("mode", "expected"),
    [("both", (0.065, 0.065)), ("start", (0.065, 0.0)), ("end", (0.0, 0.065))],
)
def test_appendix_c_height_modes(mode: str, expected: tuple[float, float]) -> None:
    task = make_task(height={"mode": mode, "margin": 0.005})
    assert height_pair(task) == pytest.approx(expected)
    local = np.array([[[1.0, 2.0], [30.0, 40.0]], [[5.0, 5.0], [5.0, 5.0]]])
    grounding = ground(make_plan(local, (0, 0)), make_detection((0, 0)), task, (600, 360))
    segments = grounding.segments_m
    assert segments.shape == (2, 2, 3)
    np.testing.assert_allclose(segments[:, 0, 2], expected[0])
    np.testing.assert_allclose(segments[:, 1, 2], expected[1])
    assert grounding.object_height == 0.06


def test_ground_rejects_inconsistent_or_empty_plans() -> None:
    task = make_task()
    local = np.array([[[1.0, 2.0], [30.0, 40.0]]])
    plan = make_plan(local, (10, 10))
    with pytest.raises(KeympsError, match="made for another detection"):
        ground(plan, make_detection((20, 20)), task, (600, 360))
    empty = make_plan(np.zeros((0, 2, 2)), (0, 0))
    with pytest.raises(KeympsError, match="no keypoint pairs"):
        ground(empty, make_detection((0, 0)), task, (600, 360))
    bad = make_plan(np.array([[[np.nan, 2.0], [30.0, 40.0]]]), (0, 0))
    with pytest.raises(KeympsError, match="NaN"):
        ground(bad, make_detection((0, 0)), task, (600, 360))


def test_homography_from_corners_maps_corners_and_matches_linear_when_square_on() -> None:
    size = (600, 360)
    straight = [[0, 360], [600, 360], [600, 0], [0, 0]]
    task = make_task(camera={"board_corners_px": straight})
    frame = ImageFrame.from_task(task, size)
    assert frame.mode == "homography"
    linear = ImageFrame.linear(size, (0.30, 0.18))
    pixels = np.random.default_rng(0).uniform(0, 600, size=(50, 2))
    np.testing.assert_allclose(frame.to_board(pixels), linear.to_board(pixels), atol=1e-12)

    tilted = [[80, 400], [560, 420], [500, 90], [130, 70]]
    frame = ImageFrame.from_task(make_task(camera={"board_corners_px": tilted}), (640, 480))
    expected = np.array([[0, 0], [0.30, 0], [0.30, 0.18], [0, 0.18]])
    np.testing.assert_allclose(frame.to_board(np.array(tilted, float)), expected, atol=1e-12)
    back = frame.to_pixels(frame.to_board(pixels))
    np.testing.assert_allclose(back, pixels, atol=1e-9)


def test_corners_in_the_wrong_order_are_rejected() -> None:
    mirrored = [[0, 0], [600, 0], [600, 360], [0, 360]]  # top-left first: y is flipped
    with pytest.raises(KeympsError, match="bottom-left, bottom-right, top-right and top-left"):
        ImageFrame.from_task(make_task(camera={"board_corners_px": mirrored}), (600, 360))


def test_object_outline_from_contour_and_from_box() -> None:
    task = make_task()
    square = np.array([[99, 99], [99, 199], [199, 199], [199, 99]])  # pixel indices
    detection = Detection(
        bbox_px=(99, 99, 200, 200),
        crop=np.zeros((1, 1, 3), np.uint8),
        crop_origin_px=(99, 99),
        contour_px=square,
    )
    outline = object_outline_m(detection, task, (600, 360))
    assert polygon_area(outline) > 0  # counter-clockwise in the board frame
    np.testing.assert_allclose(outline[:, 0].min(), 99.5 * 0.0005)
    np.testing.assert_allclose(outline[:, 1].max(), 0.18 - 99.5 * 0.0005)
    box_only = Detection(
        bbox_px=(100, 100, 200, 200), crop=np.zeros((1, 1, 3), np.uint8), crop_origin_px=(0, 0)
    )
    outline = object_outline_m(box_only, task, (600, 360))
    assert polygon_area(outline) == pytest.approx(0.05 * 0.05)


def distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    ap = points[:, None, :] - a[None]
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-18), 0, 1)
    return np.linalg.norm(ap - t[..., None] * ab[None], axis=-1).min(axis=1)


def centroid(polygon: np.ndarray) -> np.ndarray:
    x, y = polygon.T
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    return np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (3 * cross.sum())


def _index_to_edge(matrix_edge: np.ndarray) -> np.ndarray:
    """The same warp for cv2, whose pixel (i, j) sits at (i, j) instead of (i + 0.5, j + 0.5)."""
    to_edge = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])
    return np.linalg.inv(to_edge) @ matrix_edge @ to_edge


@pytest.mark.parametrize("kind", ["round_cake", "eggplant", "banana_bread", "chiffon_cake"])
def test_homography_recovers_board_coordinates_from_a_perspective_warped_scene(kind: str) -> None:
    import cv2

    from keymps.default_plugins.threshold_detector import ThresholdDetector
    from keymps.scenes.render import SceneSpec, render_scene

    scene = render_scene(SceneSpec.from_kinds([kind], seed=3, px_per_m=2000))
    (truth,) = scene.truth["objects"]
    workspace_px = np.array([[0, 360], [600, 360], [600, 0], [0, 0]], dtype=float)
    photo_corners = np.array([[60, 440], [660, 420], [600, 70], [110, 95]], dtype=float)
    warp = cv2.getPerspectiveTransform(
        workspace_px.astype(np.float32), photo_corners.astype(np.float32)
    ).astype(float)
    photo = cv2.warpPerspective(
        scene.image, _index_to_edge(warp), (720, 480), borderMode=cv2.BORDER_REPLICATE
    )
    task = make_task(camera={"board_corners_px": photo_corners.tolist()})
    frame = ImageFrame.from_task(task, (720, 480))

    # Exact points: the true outline carried into the photo comes back to its metres.
    outline_photo = cv2.perspectiveTransform(
        np.array(truth["outline_px"], dtype=np.float64).reshape(-1, 1, 2), warp
    ).reshape(-1, 2)
    true_outline = np.array(truth["outline_m"])
    assert np.abs(frame.to_board(outline_photo) - true_outline).max() < 1e-6

    # Detected in the photo: the object's outline lands within 2 mm of the truth.
    detection = ThresholdDetector().detect(photo)
    outline = object_outline_m(detection, task, (720, 480))
    assert distance_to_polygon(outline, true_outline).max() < 0.002
    assert np.linalg.norm(centroid(outline) - centroid(true_outline)) < 0.001
