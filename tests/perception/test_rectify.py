"""Photos at an angle: rectified to board millimetres first, grounded on the object's top."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from keymps.config.task import Task, parse_task
from keymps.errors import KeympsError, TaskFileError
from keymps.eval.perception import _photo_design_error, _reference_m, design_error_mm
from keymps.perception.rectify import rectify_scene
from keymps.run import RunOptions, RunOverrides
from keymps.scenes.perception_cases import BOARD_M, photo_case
from keymps.types import SceneImage

ROOT = Path(__file__).resolve().parents[2]


def task_of(text: str) -> Task:
    return Task.model_validate(yaml.safe_load(text))


@pytest.fixture(scope="module")
def tall() -> object:
    return photo_case(3, markers=False)


def camera_yaml(case: object, height: float | None = None, intrinsics: bool = True) -> str:
    corners = json.dumps(np.round(case.corners_px, 3).tolist())  # type: ignore[attr-defined]
    lines = [
        "name: photo",
        "instruction: Put 15 icing dots around the cake, leave space from the edge and between dots.",
        "scene:",
        "  image: photo.png",
        f"  workspace: {{size: [{BOARD_M[0]}, {BOARD_M[1]}]}}",
        f"  object_height: {case.object_height if height is None else height}",  # type: ignore[attr-defined]
        "  camera:",
        f"    board_corners_px: {corners}",
    ]
    if intrinsics:
        given = case.intrinsics  # type: ignore[attr-defined]
        lines.append(
            f"    intrinsics: {{fx: {given['fx']}, fy: {given['fy']}, cx: {given['cx']}, "
            f"cy: {given['cy']}, distortion: {given['distortion']}}}"
        )
    lines += [
        f"planner: {{backend: offline, prompt: {ROOT / 'prompts' / 'icing.md'}}}",
        "primitives: [line]",
        "height: {mode: both, margin: 0.005}",
        "robot: {model: ur3, tool: piping_bag}",
        "executor: {name: sim}",
    ]
    return "\n".join(lines) + "\n"


def test_the_rectified_photo_is_the_board_seen_from_above() -> None:
    case = photo_case(1, markers=False, flat_object=True)
    task = task_of(camera_yaml(case))
    scene = rectify_scene(SceneImage(case.photo, "photo"), task)
    assert scene.size_px == (600, 360) and scene.rectification is not None
    assert scene.rectification.mm_per_px == 0.5 and scene.rectification.plane_z == 0.0
    truth = np.clip(np.rint(case.flat.image), 0, 255).astype(np.int16)
    inner = (slice(10, -10), slice(10, -10))  # the board's very edge blends with the table
    assert np.median(np.abs(scene.image.astype(np.int16) - truth)[inner]) <= 4
    corners_back = cv2.perspectiveTransform(
        np.array([[[0.0, 360.0]], [[600.0, 0.0]]]), scene.rectification.to_photo
    ).reshape(-1, 2)
    # without distortion the map's board corners are the undistorted corners of the photo
    assert np.all(np.isfinite(corners_back))


def test_designs_on_photos_are_within_1_5_mm_with_intrinsics(tall: object) -> None:
    assert tall.object_height >= 0.02 and tall.tilt_deg >= 20  # type: ignore[attr-defined]
    assert _photo_design_error(tall, "board+intrinsics") <= 1.5  # type: ignore[arg-type]
    # the homography alone puts a tall cake's ring height x tan(angle) away
    assert _photo_design_error(tall, "board") > 5  # type: ignore[arg-type]
    flat = photo_case(2, markers=True, flat_object=True)
    assert _photo_design_error(flat, "board") <= 1.5


def test_design_error_ignores_where_the_ring_starts() -> None:
    angles = np.linspace(0, 2 * np.pi, 15, endpoint=False)
    ring = np.c_[np.cos(angles), np.sin(angles)] * 0.05
    turned = np.c_[np.cos(angles + 0.2), np.sin(angles + 0.2)] * 0.05
    assert design_error_mm(turned, ring) < 1.0
    assert design_error_mm(ring + [0.002, 0.0], ring) == pytest.approx(2.0, abs=0.05)


def test_a_run_on_a_photo_plans_in_board_millimetres(tall: object, tmp_path: Path) -> None:
    from keymps.pipeline.engine import run_task

    cv2.imwrite(str(tmp_path / "photo.png"), tall.photo)  # type: ignore[attr-defined]
    (tmp_path / "task.yaml").write_text(camera_yaml(tall))
    run = run_task(
        tmp_path / "task.yaml",
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path / "run"),
    )
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["ok"], record["error"]
    rectified = record["image"]["rectified"]
    assert record["image"]["size_px"] == [600, 360] and rectified["photo_size_px"] == [960, 720]
    assert rectified["plane_z_m"] == pytest.approx(tall.object_height, abs=1e-6)  # type: ignore[attr-defined]
    assert rectified["camera_position_m"][2] > 0.3
    assert "top_surface" in record["detection"]["report"]
    assert (tmp_path / "run" / "plan_photo.jpg").exists() or (
        tmp_path / "run" / "plan_photo.png"
    ).exists()
    dots = np.array(record["segments_m"])[:, 0, :2]
    assert design_error_mm(dots, _reference_m(tall)) <= 1.5  # type: ignore[arg-type]
    assert run.stages.image is not None and run.stages.image.rectification is not None


def test_camera_errors_are_one_line(tall: object, tmp_path: Path) -> None:
    with pytest.raises(
        TaskFileError, match=r"t.yaml:\d+:\d+: scene.camera.intrinsics.distortion: .*4, 5 or 8"
    ):
        parse_task(camera_yaml(tall).replace("distortion: [", "distortion: [0.1, "), "t.yaml")
    task = task_of(camera_yaml(tall, height=0.9))  # an object above the camera: a height error
    with pytest.raises(
        KeympsError,
        match=r"^scene.object_height: 0.9 m is not below the camera, which the board corners and "
        r"intrinsics put 0\.\d+ m above the board: the unit is metres$",
    ):
        rectify_scene(SceneImage(tall.photo, "photo"), task)  # type: ignore[attr-defined]
    text = camera_yaml(tall, intrinsics=False).replace("mode: both", "mode: both")
    corners = tall.corners_px  # type: ignore[attr-defined]
    mirrored = json.dumps(np.round(corners[::-1], 3).tolist())
    text = text.replace(json.dumps(np.round(corners, 3).tolist()), mirrored)
    task = task_of(text)
    with pytest.raises(KeympsError, match=r"board_corners_px: the four corners must be"):
        rectify_scene(SceneImage(tall.photo, "photo"), task)  # type: ignore[attr-defined]
