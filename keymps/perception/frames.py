"""Image pixels <-> board metres (Appendix B, or a calibrated homography) and heights (Appendix C).

Pixel coordinates are continuous: pixel (column i, row j) covers [i, i+1) x [j, j+1), so its
centre is (i + 0.5, j + 0.5) and the image spans [0, width] x [0, height]. This is the convention
of Appendix B (p_norm = p / s_img): the left image edge is x = 0, the bottom edge is y = height.

Board frame (metres): origin at the bottom-left corner of the workspace as seen in the image,
x to the image's right, y to the image's top, z up. With the linear (Appendix B) frame:

    board_x = x_px / w_img * w_env + shift_x
    board_y = h_env - y_px / h_img * h_env + shift_y

task.scene.workspace.shift is in metres in the board frame; the paper's pixel shift g_shift =
(gx, gy) is the same as shift = (gx * w_env / w_img, -gy * h_env / h_img).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from keymps.errors import KeympsError, StageError
from keymps.types import Detection, Grounding, Plan, SceneImage, Segment

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.perception.scene_objects import SceneObject

FrameMode = Literal["linear", "homography", "top_plane"]


def _as_points(points: np.ndarray, what: str) -> np.ndarray:
    array = np.asarray(points, dtype=float)
    if array.ndim == 1 and array.shape[0] == 2:
        array = array.reshape(1, 2)
    if array.ndim != 2 or array.shape[1] != 2:
        raise KeympsError(f"{what}: expected an (N, 2) array of points, got shape {array.shape}")
    return array


def _apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    homogeneous = np.hstack([points, np.ones((len(points), 1))]) @ matrix.T
    return homogeneous[:, :2] / homogeneous[:, 2:3]


def _check_quadrilateral(corners: np.ndarray) -> None:
    """The corners must be bottom-left, bottom-right, top-right, top-left of a convex quad."""
    edges = np.roll(corners, -1, axis=0) - corners
    following = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * following[:, 1] - edges[:, 1] * following[:, 0]
    # In image coordinates (y down) that order turns clockwise on screen: every cross < 0.
    if not np.all(cross < 0):
        shown = ", ".join(f"({x:g}, {y:g})" for x, y in corners)
        raise KeympsError(
            "scene.camera.board_corners_px: the four corners must be the workspace's "
            f"bottom-left, bottom-right, top-right and top-left pixels of a convex quadrilateral "
            f"(got {shown})"
        )


@dataclass(frozen=True)
class ImageFrame:
    """The map between full-image pixels and the board frame for one image size."""

    matrix: np.ndarray
    """3x3 homogeneous map from pixels to board metres."""
    image_size_px: tuple[int, int]
    workspace_size: tuple[float, float]
    shift: tuple[float, float]
    mode: FrameMode

    @classmethod
    def linear(
        cls,
        image_size_px: tuple[int, int],
        workspace_size: tuple[float, float],
        shift: tuple[float, float] = (0.0, 0.0),
    ) -> ImageFrame:
        """Appendix B: the image spans the workspace exactly, seen from straight above."""
        width_px, height_px = _check_size(image_size_px)
        w_env, h_env = (float(v) for v in workspace_size)
        sx, sy = (float(v) for v in shift)
        matrix = np.array(
            [
                [w_env / width_px, 0.0, sx],
                [0.0, -h_env / height_px, h_env + sy],
                [0.0, 0.0, 1.0],
            ]
        )
        return cls(matrix, (width_px, height_px), (w_env, h_env), (sx, sy), "linear")

    @classmethod
    def from_corners(
        cls,
        image_size_px: tuple[int, int],
        workspace_size: tuple[float, float],
        corners_px: np.ndarray,
        shift: tuple[float, float] = (0.0, 0.0),
    ) -> ImageFrame:
        """Calibrated camera: the homography taking the workspace's four corner pixels
        (bottom-left, bottom-right, top-right, top-left) to the board's corners."""
        size = _check_size(image_size_px)
        corners = np.asarray(corners_px, dtype=float).reshape(4, 2)
        _check_quadrilateral(corners)
        w_env, h_env = (float(v) for v in workspace_size)
        sx, sy = (float(v) for v in shift)
        board = np.array(
            [[sx, sy], [sx + w_env, sy], [sx + w_env, sy + h_env], [sx, sy + h_env]],
            dtype=np.float64,
        )
        matrix = homography(corners, board)
        return cls(matrix, size, (w_env, h_env), (sx, sy), "homography")

    @classmethod
    def from_task(cls, task: Task, image_size_px: tuple[int, int]) -> ImageFrame:
        """The frame the task file asks for: the homography when board corners are given."""
        workspace = task.scene.workspace
        corners = task.scene.camera.board_corners_px
        if corners is not None:
            return cls.from_corners(
                image_size_px, workspace.size, np.array(corners), workspace.shift
            )
        return cls.linear(image_size_px, workspace.size, workspace.shift)

    @classmethod
    def for_scene(cls, task: Task, scene: SceneImage | tuple[int, int]) -> ImageFrame:
        """The frame of the image the stages work in: Appendix B on a rectified image (it
        spans the workspace exactly), else what the task file asks for (from_task)."""
        if isinstance(scene, SceneImage):
            info = scene.rectification
            if info is not None:
                workspace = task.scene.workspace
                board = cls.linear(scene.size_px, workspace.size, workspace.shift)
                if info.camera_position_m is None or info.plane_z <= 0:
                    return board
                # the top plane appears scaled by Cz / (Cz - h) about the camera's foot point
                cx, cy, cz = info.camera_position_m
                shrink = (cz - info.plane_z) / cz
                about_foot = np.array(
                    [[shrink, 0, cx * (1 - shrink)], [0, shrink, cy * (1 - shrink)], [0, 0, 1]]
                )
                return cls(
                    about_foot @ board.matrix,
                    board.image_size_px,
                    board.workspace_size,
                    board.shift,
                    "top_plane",
                )
            return cls.from_task(task, scene.size_px)
        return cls.from_task(task, scene)

    @property
    def inverse(self) -> np.ndarray:
        return np.linalg.inv(self.matrix)

    def to_board(self, px: np.ndarray) -> np.ndarray:
        """(N, 2) image pixels -> (N, 2) board metres."""
        return _apply(self.matrix, _as_points(px, "to_board"))

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) board metres -> (N, 2) image pixels."""
        return _apply(self.inverse, _as_points(xy, "to_pixels"))

    def footprint_m(self, contour_px: np.ndarray, bbox_px: tuple[int, int, int, int]) -> np.ndarray:
        """A contour (pixel centres; the box's corners without one) as a counter-clockwise
        board polygon in metres."""
        contour = np.asarray(contour_px, dtype=float).reshape(-1, 2)
        if len(contour) >= 3:
            pixels = contour + 0.5
        else:
            x0, y0, x1, y1 = (float(v) for v in bbox_px)
            pixels = np.array([[x0, y1], [x1, y1], [x1, y0], [x0, y0]])
        outline = self.to_board(pixels)
        return outline if polygon_area(outline) >= 0 else outline[::-1].copy()

    def metres_per_pixel(self, px: np.ndarray | None = None) -> float:
        """Mean size of one pixel on the board (at the image centre unless px is given)."""
        if px is None:
            px = np.array([self.image_size_px]) / 2.0
        centre = _as_points(px, "metres_per_pixel")[0]
        probes = np.array([centre, centre + (1.0, 0.0), centre + (0.0, 1.0)])
        board = self.to_board(probes)
        return float(
            (np.linalg.norm(board[1] - board[0]) + np.linalg.norm(board[2] - board[0])) / 2
        )


SQUARE_PIXEL_TOLERANCE = 0.05
"""Pixels more than 5 % wider than tall (or the reverse) mean the image does not span
scene.workspace.size: a photo not cropped to the board, or a size written wrong."""


def pixel_shape_warning(task: Task, image_size_px: tuple[int, int]) -> str | None:
    """Why the image and scene.workspace.size disagree (pixels far from square), or None.
    Only for the linear frame: with board corners a homography maps any pixel shape."""
    if task.scene.camera.board_corners_px is not None:
        return None
    width_px, height_px = _check_size(image_size_px)
    w_env, h_env = task.scene.workspace.size
    wide_mm, tall_mm = 1000.0 * w_env / width_px, 1000.0 * h_env / height_px
    if abs(wide_mm / tall_mm - 1.0) <= SQUARE_PIXEL_TOLERANCE:
        return None
    return (
        f"the image is {width_px} x {height_px} px but scene.workspace.size is "
        f"{w_env:g} x {h_env:g} m, so a pixel is {wide_mm:.2f} mm wide and {tall_mm:.2f} mm "
        "tall: crop the image to the board, correct the size, or give "
        "scene.camera.board_corners_px"
    )


def homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The 3x3 map taking four points to four points (direct linear solve in float64).

    Args:
        src: (4, 2) points, in any unit.
        dst: (4, 2) the points they map to.

    Returns:
        (3, 3) the homography, its last entry 1.

    Raises:
        KeympsError: When three of the points lie on a line.
    """
    rows = []
    rhs = []
    for (x, y), (u, v) in zip(src, dst, strict=True):
        rows.append([x, y, 1, 0, 0, 0, -u * x, -u * y])
        rows.append([0, 0, 0, x, y, 1, -v * x, -v * y])
        rhs.extend([u, v])
    try:
        h = np.linalg.solve(np.array(rows, dtype=float), np.array(rhs, dtype=float))
    except np.linalg.LinAlgError:
        raise KeympsError(
            "scene.camera.board_corners_px: the four corners are degenerate (three on a line?)"
        ) from None
    return np.append(h, 1.0).reshape(3, 3)


def _check_size(image_size_px: tuple[int, int]) -> tuple[int, int]:
    width, height = (int(v) for v in image_size_px)
    if width <= 0 or height <= 0:
        raise KeympsError(f"image size must be positive, got {width} x {height} px")
    return width, height


def height_pair(task: Task, object_height: float | None = None) -> tuple[float, float]:
    """Appendix C: (start z, goal z) from task.height.mode, its margin and the object height
    (`object_height`, else scene.object_height)."""
    height = task.scene.object_height if object_height is None else object_height
    top = float(height) + float(task.height.margin)
    mode = task.height.mode
    if mode == "both":
        return top, top
    if mode == "start":
        return top, 0.0
    return 0.0, top


def pairs_full_image_px(plan: Plan, detection: Detection) -> np.ndarray:
    """Appendix B translation: p' = p_local + b_offset, checked against plan.pairs_px."""
    local = np.asarray(plan.pairs_crop_px, dtype=float)
    if local.ndim != 3 or local.shape[1:] != (2, 2):
        raise StageError("ground", f"keypoint pairs must have shape (K, 2, 2), got {local.shape}")
    if local.shape[0] == 0:
        raise StageError("ground", "the plan has no keypoint pairs")
    if not np.all(np.isfinite(local)):
        raise StageError("ground", "the plan's keypoint pairs contain NaN or infinite values")
    full = local + np.asarray(detection.crop_origin_px, dtype=float)
    given = np.asarray(plan.pairs_px, dtype=float)
    if given.shape != full.shape or not np.allclose(given, full, atol=1e-6):
        raise StageError(
            "ground",
            "plan.pairs_px is not pairs_crop_px + the detection's crop origin "
            f"{tuple(detection.crop_origin_px)}: the plan was made for another detection",
        )
    return full


def ground(
    plan: Plan,
    detection: Detection,
    task: Task,
    image: SceneImage | tuple[int, int],
    objects: tuple[SceneObject, ...] | None = None,
) -> Grounding:
    """Appendix B (crop pixels -> board metres) and Appendix C (heights, per object): each
    pair takes the height of the object it lies on (plan.pair_objects).

    `image` is the scene the plan was made on (or its size, for an unrectified image)."""
    from keymps.perception.scene_objects import grounded_objects, scene_objects

    pairs = pairs_full_image_px(plan, detection)
    frame = ImageFrame.for_scene(task, image)
    if objects is None:
        objects = scene_objects(detection, task, frame)
    by_id = {o.id: o for o in objects}
    owners = plan.pair_objects or (objects[0].id,) * len(pairs)
    if len(owners) != len(pairs) or any(i not in by_id for i in owners):
        raise StageError(
            "ground",
            f"the plan assigns its {len(pairs)} pairs to objects {list(owners)}, but the "
            f"scene's objects are {sorted(by_id)}",
        )
    board = frame.to_board(pairs.reshape(-1, 2)).reshape(-1, 2, 2)
    segments = []
    for k, owner in enumerate(owners):
        z_start, z_goal = height_pair(task, by_id[owner].height)
        segments.append(
            Segment(
                start=np.array([*board[k, 0], z_start]),
                goal=np.array([*board[k, 1], z_goal]),
                start_px=(float(pairs[k, 0, 0]), float(pairs[k, 0, 1])),
                goal_px=(float(pairs[k, 1, 0]), float(pairs[k, 1, 1])),
                object_id=owner,
            )
        )
    return Grounding(
        segments=tuple(segments),
        object_height=max(o.height for o in objects),
        workspace_size=(float(task.scene.workspace.size[0]), float(task.scene.workspace.size[1])),
        objects=grounded_objects(objects, frame),
    )


def object_outline_m(
    detection: Detection, task: Task, image: SceneImage | tuple[int, int]
) -> np.ndarray:
    """The (primary) object's footprint polygon (N, 2) in board metres, counter-clockwise.

    Uses the detected contour (pixel centres) or, without one, the bounding box's corners.
    """
    frame = ImageFrame.for_scene(task, image)
    return frame.footprint_m(detection.contour_px, detection.bbox_px)


def polygon_area(points: np.ndarray) -> float:
    """Signed area (shoelace): positive for a counter-clockwise polygon in a y-up frame."""
    x, y = np.asarray(points, dtype=float).T
    return float(0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
