"""Small synthetic top-down scenes for the planning tests: a disk, an ellipse or a rectangle on a
plain board, with a known scale (so distances can be checked in millimetres)."""

from __future__ import annotations

import math
import tempfile
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from keymps.config.task import Task
from keymps.run import Run, RunOptions
from keymps.types import Detection, Plan, SceneImage

MM_PER_PX = 0.5
BOARD_BGR = (205, 205, 205)
CUTTING = {
    "straight": "Straight downward cut: the knife moves down, for soft objects.",
    "sawing": "Forward and backward sawing strokes with downward force, for hard or crusty objects.",
}
ICING = {
    "line": "Icing line: descend to the surface, then pipe laterally; start = end makes a dot."
}


@dataclass(frozen=True)
class Scene:
    scene: SceneImage
    detection: Detection
    centre_px: tuple[float, float]
    """Object centre in full-image pixels."""
    workspace_m: tuple[float, float]

    def to_mm(self, points_px: np.ndarray) -> np.ndarray:
        """Full-image pixels to millimetres (same axes)."""
        return np.asarray(points_px, float) * MM_PER_PX


def make_scene(
    shape: str, size_mm: tuple[float, float], angle_deg: float = 0.0, colour=(40, 110, 200)
) -> Scene:
    """A scene with one object: 'disk' (size = diameter), 'ellipse' or 'rect' (length, width)."""
    import cv2

    length_px, width_px = size_mm[0] / MM_PER_PX, size_mm[1] / MM_PER_PX
    w = int(length_px + 160)
    h = int(max(length_px, width_px) + 160) if angle_deg else int(width_px + 160)
    image = np.full((h, w, 3), BOARD_BGR, np.uint8)
    centre = (w / 2, h / 2)
    mask = np.zeros((h, w), np.uint8)
    if shape == "disk":
        cv2.circle(
            mask,
            (int(round(centre[0] * 16)), int(round(centre[1] * 16))),
            int(round(length_px / 2 * 16)),
            255,
            -1,
            cv2.LINE_8,
            4,
        )
    elif shape == "ellipse":
        cv2.ellipse(mask, ((centre[0], centre[1]), (length_px, width_px), angle_deg), 255, -1)
    elif shape == "rect":
        box = cv2.boxPoints(((centre[0], centre[1]), (length_px, width_px), angle_deg))
        cv2.fillPoly(mask, [np.round(box).astype(np.int32)], 255)
    else:
        raise ValueError(shape)
    image[mask > 0] = colour
    ys, xs = np.nonzero(mask)
    x0, y0, x1, y1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
    pad = 20
    cx0, cy0 = max(x0 - pad, 0), max(y0 - pad, 0)
    cx1, cy1 = min(x1 + pad, w), min(y1 + pad, h)
    detection = Detection(
        bbox_px=(int(x0), int(y0), int(x1), int(y1)),
        crop=image[cy0:cy1, cx0:cx1].copy(),
        crop_origin_px=(int(cx0), int(cy0)),
    )
    workspace = (w * MM_PER_PX / 1000, h * MM_PER_PX / 1000)
    return Scene(SceneImage(image, "synthetic"), detection, centre, workspace)


def make_task(instruction: str, scene: Scene, primitives: Mapping[str, str], **planner) -> Task:
    return Task(
        name=planner.pop("name", "planning-test"),
        instruction=instruction,
        scene={"source": "synthetic", "workspace": {"size": list(scene.workspace_m)}},
        primitives=list(primitives),
        robot=planner.pop("robot", {}),
        planner=planner,
    )


def plan_for(
    instruction: str,
    scene: Scene,
    primitives: Mapping[str, str] = CUTTING,
    backend: str = "offline",
    folder: Path | None = None,
    options: RunOptions | None = None,
    **planner,
) -> tuple[Plan, Run]:
    from keymps.planning.planner import make_plan

    """Plan with `backend`; without `folder` the run folder is temporary (gone on return)."""
    task = make_task(instruction, scene, primitives, **planner)
    with tempfile.TemporaryDirectory() as scratch:
        run = Run(task=task, folder=folder or Path(scratch), options=options or RunOptions())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            plan = make_plan(task, scene.detection, scene.scene, primitives, run, backend)
    return plan, run


def segment_angle(pair: np.ndarray) -> float:
    """Direction of a segment in degrees, folded into [0, 180)."""
    d = pair[1] - pair[0]
    return math.degrees(math.atan2(d[1], d[0])) % 180.0


def distance_point_to_line(point: np.ndarray, pair: np.ndarray) -> float:
    a, b = pair
    d = b - a
    return float(abs(d[0] * (point[1] - a[1]) - d[1] * (point[0] - a[0])) / np.linalg.norm(d))


def piece_areas(scene: Scene, plan: Plan) -> list[int]:
    """Pixel areas of the pieces the cuts divide the object into (largest first)."""
    import cv2

    image = scene.scene.image
    mask = (np.abs(image.astype(int) - np.array(BOARD_BGR)).max(axis=2) > 30).astype(np.uint8)
    for start, end in plan.pairs_px:
        cv2.line(mask, tuple(int(round(v)) for v in start), tuple(int(round(v)) for v in end), 0, 2)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
    areas = sorted((int(a) for a in stats[1:, cv2.CC_STAT_AREA] if a > 50), reverse=True)
    return areas
