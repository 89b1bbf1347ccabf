"""The objects of a scene: what the detector found, matched to what the task file describes.

Detected objects are numbered left to right, then top to bottom (DetectedObject.id). A task's
`scene.objects` list is matched to them in that order, except entries with `at: [x, y]` (board
metres), which take the detected object at (or nearest to) that point. Without the list every
object has `scene.object_height` and no name. A detector that reports no `objects` is read as
one object: the detection's own box, contour and mask (the single-object case of everything).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from keymps.errors import KeympsError
from keymps.types import DetectedObject, Detection, GroundedObject

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.perception.frames import ImageFrame


@dataclass(frozen=True)
class SceneObject:
    """A detected object with what the task says about it."""

    detected: DetectedObject
    name: str | None
    height: float
    """Top surface above the board, metres."""

    @property
    def id(self) -> int:
        return self.detected.id

    @property
    def label(self) -> str:
        """'#2 banana' (or '#2' without a name)."""
        return f"#{self.id} {self.name}" if self.name else f"#{self.id}"

    @property
    def centre_px(self) -> tuple[float, float]:
        x0, y0, x1, y1 = self.detected.bbox_px
        return (x0 + x1) / 2, (y0 + y1) / 2


def detected_objects(detection: Detection) -> tuple[DetectedObject, ...]:
    """detection.objects, or the detection itself as object 1 for a one-object detector."""
    if detection.objects:
        return detection.objects
    contour = np.asarray(detection.contour_px, dtype=float).reshape(-1, 2)
    x0, y0, x1, y1 = detection.bbox_px
    area = _polygon_area_px(contour) if len(contour) >= 3 else float((x1 - x0) * (y1 - y0))
    return (DetectedObject(1, detection.bbox_px, contour, area, detection.mask),)


def crop_covering_objects(detection: Detection, image: np.ndarray) -> Detection:
    """The detection with a crop around every object (a detector may crop its chosen object
    only), padded as the detector padded its own crop; unchanged with one object."""
    from dataclasses import replace

    objects = detection.objects
    if len(objects) < 2:
        return detection
    x0 = min(o.bbox_px[0] for o in objects)
    y0 = min(o.bbox_px[1] for o in objects)
    x1 = max(o.bbox_px[2] for o in objects)
    y1 = max(o.bbox_px[3] for o in objects)
    ox, oy = detection.crop_origin_px
    width, height = detection.crop_size_px
    if x0 >= ox and y0 >= oy and x1 <= ox + width and y1 <= oy + height:
        return detection
    bx0, by0, bx1, by1 = detection.bbox_px
    pad = max(0, bx0 - ox, by0 - oy, ox + width - bx1, oy + height - by1)
    image_h, image_w = image.shape[:2]
    cx0, cy0 = max(0, min(ox, x0 - pad)), max(0, min(oy, y0 - pad))
    cx1 = min(image_w, max(ox + width, x1 + pad))
    cy1 = min(image_h, max(oy + height, y1 + pad))
    crop = np.ascontiguousarray(image[cy0:cy1, cx0:cx1])
    return replace(detection, crop=crop, crop_origin_px=(int(cx0), int(cy0)))


def object_mask(obj: DetectedObject, image_shape: tuple[int, ...]) -> np.ndarray:
    """The object's pixels (bool, full image): its mask, else its filled contour, else its box."""
    import cv2

    height, width = image_shape[:2]
    if obj.mask is not None and obj.mask.shape[:2] == (height, width):
        return np.asarray(obj.mask, dtype=bool)
    filled = np.zeros((height, width), np.uint8)
    contour = np.asarray(obj.contour_px, dtype=float).reshape(-1, 2)
    if len(contour) >= 3:
        cv2.drawContours(filled, [np.round(contour).astype(np.int32).reshape(-1, 1, 2)], -1, 1, -1)
    else:
        x0, y0, x1, y1 = obj.bbox_px
        filled[y0:y1, x0:x1] = 1
    return filled > 0


def scene_objects(detection: Detection, task: Task, frame: ImageFrame) -> tuple[SceneObject, ...]:
    """Every object in id order, with its name and height; KeympsError on a count mismatch."""
    detected = detected_objects(detection)
    specs = task.scene.objects
    default = float(task.scene.object_height)
    if specs is None:
        return tuple(SceneObject(obj, None, default) for obj in detected)
    if len(specs) != len(detected):
        found = ", ".join(f"#{o.id} box {list(o.bbox_px)}" for o in detected)
        raise KeympsError(
            f"{task.where('scene', 'objects')}: scene.objects: the task describes "
            f"{len(specs)} object(s) but the detector found {len(detected)} ({found}): "
            "describe each object found, or change the scene (or detector.min_area)"
        )
    chosen: dict[int, int] = {}  # spec index -> index into detected
    for index, spec in enumerate(specs):
        if spec.at is None:
            continue
        target = _at(detected, spec.at, frame)
        if target in chosen.values():
            other = next(i for i, t in chosen.items() if t == target)
            raise KeympsError(
                f"{task.where('scene', 'objects', index, 'at')}: scene.objects[{index}].at: "
                f"{list(spec.at)} picks object #{detected[target].id}, already picked by "
                f"scene.objects[{other}] ({specs[other].name})"
            )
        chosen[index] = target
    free = iter(i for i in range(len(detected)) if i not in chosen.values())
    for index in range(len(specs)):
        if index not in chosen:
            chosen[index] = next(free)
    by_detected = {target: specs[index] for index, target in chosen.items()}
    result = []
    for i, obj in enumerate(detected):
        height = by_detected[i].height
        result.append(SceneObject(obj, by_detected[i].name, default if height is None else height))
    return tuple(result)


def _at(detected: tuple[DetectedObject, ...], at: tuple[float, float], frame: ImageFrame) -> int:
    """Index of the detected object whose outline contains the board point (else the nearest)."""
    import cv2

    point = frame.to_pixels(np.array([at], float))[0]
    best, best_distance = 0, float("inf")
    for index, obj in enumerate(detected):
        contour = np.asarray(obj.contour_px, dtype=np.float32).reshape(-1, 1, 2)
        if len(contour) >= 3:
            # signed: positive inside; the negated value is the distance outside
            distance = -cv2.pointPolygonTest(contour, (float(point[0]), float(point[1])), True)
        else:
            x0, y0, x1, y1 = obj.bbox_px
            distance = float(
                np.hypot(max(x0 - point[0], 0, point[0] - x1), max(y0 - point[1], 0, point[1] - y1))
            )
        if distance < best_distance:
            best, best_distance = index, distance
    return best


def grounded_objects(
    objects: tuple[SceneObject, ...], frame: ImageFrame
) -> tuple[GroundedObject, ...]:
    """Every object's footprint in board metres (counter-clockwise) with its name and height."""
    return tuple(
        GroundedObject(
            o.id, o.name, o.height, frame.footprint_m(o.detected.contour_px, o.detected.bbox_px)
        )
        for o in objects
    )


def _polygon_area_px(contour: np.ndarray) -> float:
    x, y = contour.T
    return float(abs(0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))))


def describe(objects: tuple[SceneObject, ...]) -> str:
    """'#1 banana (left), #2 cucumber (right)' style listing for messages."""
    return ", ".join(f"{o.label} box {list(o.detected.bbox_px)}" for o in objects)
