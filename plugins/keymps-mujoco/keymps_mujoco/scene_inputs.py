"""What the simulated scene is made of, taken from a run: the arm, the board, the objects.

The objects are the detector's (every one of `Detection.objects`, or the single detection),
each its outline in board metres extruded to `scene.object_height`, coloured by its mean pixel
colour. The scene image, rectified to the workspace, becomes the texture of the board's and the
objects' tops, so the top-down camera sees what the task's camera saw.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps_mujoco.model import Prop

if TYPE_CHECKING:
    from keymps.run import Run


@dataclass(frozen=True)
class SceneInputs:
    robot: Any
    """keymps.robot.model.RobotModel: the arm placed on the board with the task's tool."""
    board_size: tuple[float, float]
    board_shift: tuple[float, float]
    props: tuple[Prop, ...]
    texture_rgb: np.ndarray | None
    """RGB image spanning the workspace (row 0 at the board's top edge), or None."""
    top_size_px: tuple[int, int]
    footprint_masks: list[np.ndarray]
    """Per object, a boolean mask over the top-down image."""

    def surface_under(self, xy: np.ndarray) -> tuple[float, bool]:
        """The height of the surface under a board point, and whether an object is there."""
        width, height = self.top_size_px
        u = (float(xy[0]) - self.board_shift[0]) / self.board_size[0] * width
        v = height - (float(xy[1]) - self.board_shift[1]) / self.board_size[1] * height
        col, row = int(np.floor(u)), int(np.floor(v))
        if not (0 <= col < width and 0 <= row < height):
            return 0.0, False
        for prop, mask in zip(self.props, self.footprint_masks, strict=True):
            if mask[row, col]:
                return float(prop.height), True
        return 0.0, False


def scene_from_run(run: Run, px_per_m: float = 2000.0) -> SceneInputs:
    """The scene of a run that has reached its execute stage (or of a bare task)."""
    from keymps.robot.model import RobotModel

    task = run.task
    robot = run.robot if run.robot is not None else RobotModel.from_task(task)
    workspace = task.scene.workspace
    size = (float(workspace.size[0]), float(workspace.size[1]))
    shift = (float(workspace.shift[0]), float(workspace.shift[1]))
    scene, detection = run.stages.image, run.stages.detect
    if scene is not None:
        texture, top_size = rectified(scene.image, task)
    else:
        top_size = (round(size[0] * px_per_m), round(size[1] * px_per_m))
        texture = None
    outlines: list[np.ndarray] = []
    if detection is not None and scene is not None:
        outlines = detected_outlines(detection, task, scene.size_px)
    elif run.outline_m is not None:  # a footprint without a detection (a run built by hand)
        outlines = [np.asarray(run.outline_m, dtype=float)]
    props = tuple(
        Prop(
            outline,
            float(task.scene.object_height),
            _mean_colour(texture, mask) if texture is not None else (0.8, 0.6, 0.35, 1.0),
            f"object_{k + 1}",
        )
        for k, (outline, mask) in enumerate(
            zip(outlines, [footprint_mask(o, size, shift, top_size) for o in outlines], strict=True)
        )
    )
    masks = [footprint_mask(prop.outline_m, size, shift, top_size) for prop in props]
    return SceneInputs(robot, size, shift, props, texture, top_size, masks)


def rectified(image: np.ndarray, task: Any) -> tuple[np.ndarray, tuple[int, int]]:
    """The scene image as seen straight from above over exactly the workspace (RGB)."""
    import cv2

    from keymps.perception.frames import ImageFrame

    height_px, width_px = image.shape[:2]
    frame = ImageFrame.from_task(task, (width_px, height_px))
    if frame.mode == "linear":
        return np.ascontiguousarray(image[:, :, ::-1]), (width_px, height_px)
    w, h = frame.workspace_size
    per_metre = 1.0 / frame.metres_per_pixel()
    size = (round(w * per_metre), round(h * per_metre))
    linear = ImageFrame.linear(size, (w, h), frame.shift)
    # texture pixel -> board -> scene pixel
    texture_to_image = frame.inverse @ linear.matrix
    warped = cv2.warpPerspective(
        image, texture_to_image, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    )
    return np.ascontiguousarray(warped[:, :, ::-1]), size


def detected_outlines(
    detection: Any, task: Any, image_size_px: tuple[int, int]
) -> list[np.ndarray]:
    """Every detected object's footprint in board metres, counter-clockwise, simplified."""
    from keymps.perception.frames import ImageFrame, object_outline_m, polygon_area

    frame = ImageFrame.from_task(task, image_size_px)
    objects: list[Any] = list(detection.objects) or [detection]
    outlines = []
    for found in objects:
        contour = np.asarray(found.contour_px, dtype=float).reshape(-1, 2)
        if len(contour) < 3:
            outline = object_outline_m(detection, task, image_size_px)
        else:
            outline = frame.to_board(_simplified(contour) + 0.5)
        if polygon_area(outline) < 0:
            outline = outline[::-1].copy()
        outlines.append(outline)
    return outlines


def _simplified(contour: np.ndarray, tolerance_px: float = 0.7) -> np.ndarray:
    """The contour with at most ~sub-pixel deviation and fewer points (an extruded mesh)."""
    import cv2

    points = np.round(contour).astype(np.int32).reshape(-1, 1, 2)
    simple = cv2.approxPolyDP(points, tolerance_px, True).reshape(-1, 2).astype(float)
    return simple if len(simple) >= 3 else contour


def footprint_mask(
    outline: np.ndarray,
    size: tuple[float, float],
    shift: tuple[float, float],
    image_size_px: tuple[int, int],
) -> np.ndarray:
    """Boolean mask of the outline over the top-down image."""
    import cv2

    width, height = image_size_px
    u = (outline[:, 0] - shift[0]) / size[0] * width
    v = height - (outline[:, 1] - shift[1]) / size[1] * height
    mask = np.zeros((height, width), np.uint8)
    cv2.fillPoly(mask, [np.round(np.column_stack([u, v]) * 16).astype(np.int32)], 1, 8, 4)
    return mask.astype(bool)


def _mean_colour(texture: np.ndarray, mask: np.ndarray) -> tuple[float, float, float, float]:
    if not mask.any():
        return (0.8, 0.6, 0.35, 1.0)
    mean = texture[mask].mean(axis=0) / 255.0
    return (float(mean[0]), float(mean[1]), float(mean[2]), 1.0)
