"""The scene's objects as the planner sees them, and a plan's pairs given back to their objects.

A backend receives every object in crop pixels (PlanObject). Whatever it answers, keymps assigns
each keypoint pair to the object it lies on (a pair that touches two objects is refused, naming
both) and orders the pairs so the tool visits the objects along a short tour, each object's pairs
together and in the backend's order. With one object every pair is that object's, in order.
"""

from __future__ import annotations

import math

import numpy as np

from keymps.errors import KeympsError
from keymps.perception.scene_objects import SceneObject, object_mask
from keymps.text_drawing import on_text_thread
from keymps.types import PlanObject

SAMPLES_PER_PAIR = 65
"""Points along a pair tested against the objects' masks."""
SPAN_PX = 2
"""A pair spans two objects when more than this many pixels of it lie on each."""


def plan_objects(
    objects: tuple[SceneObject, ...],
    crop_origin_px: tuple[int, int],
    crop_size_px: tuple[int, int],
    image_shape: tuple[int, ...],
    metres_per_px: tuple[float, float],
    single_mask: np.ndarray | None,
) -> tuple[PlanObject, ...]:
    """The objects in crop pixels; `single_mask` is the crop mask used when there is one object
    (the detector's own, so that the one-object case sees exactly what it always saw)."""
    ox, oy = crop_origin_px
    width, height = crop_size_px
    found = []
    for obj in objects:
        x0, y0, x1, y1 = obj.detected.bbox_px
        if len(objects) == 1:
            mask = single_mask
        else:
            mask = object_mask(obj.detected, image_shape)[oy : oy + height, ox : ox + width]
        found.append(
            PlanObject(
                id=obj.id,
                name=obj.name,
                height=obj.height,
                bbox_px=(x0 - ox, y0 - oy, x1 - ox, y1 - oy),
                mask=mask,
                size_m=((x1 - x0) * metres_per_px[0], (y1 - y0) * metres_per_px[1]),
            )
        )
    return tuple(found)


def scaled_objects(
    objects: tuple[PlanObject, ...],
    crop_size_px: tuple[int, int],
    sent_size_px: tuple[int, int],
    single_mask: np.ndarray | None,
) -> tuple[PlanObject, ...]:
    """The objects in the pixels of the image sent (the crop downscaled for a provider);
    `single_mask` is the downscaled mask of a one-object crop."""
    if sent_size_px == crop_size_px:
        return objects
    import cv2

    sx, sy = sent_size_px[0] / crop_size_px[0], sent_size_px[1] / crop_size_px[1]
    scaled = []
    for o in objects:
        x0, y0, x1, y1 = o.bbox_px
        if len(objects) == 1:
            mask = single_mask
        elif o.mask is not None:
            small = cv2.resize(
                o.mask.astype(np.uint8), sent_size_px, interpolation=cv2.INTER_NEAREST
            )
            mask = small > 0
        else:
            mask = None
        box = (int(x0 * sx), int(y0 * sy), int(np.ceil(x1 * sx)), int(np.ceil(y1 * sy)))
        scaled.append(PlanObject(o.id, o.name, o.height, box, mask, o.size_m))
    return tuple(scaled)


def describe_objects(objects: tuple[PlanObject, ...]) -> str:
    """The prompt's list of objects: id, name, size and box in the image sent."""
    if len(objects) <= 1:
        return ""
    lines = [
        f"The image shows {len(objects)} objects, numbered on it (ids left to right, then top "
        "to bottom). Every keypoint pair must lie on one object; a pair never spans two:"
    ]
    for o in objects:
        what = f" {o.name}," if o.name else ""
        lines.append(
            f"- object {o.id}:{what} about {o.size_m[0] * 100:.1f} x {o.size_m[1] * 100:.1f} cm, "
            f"box {list(o.bbox_px)} px, height {o.height * 100:.3g} cm"
        )
    return "\n".join(lines)


def mark_objects(crop: np.ndarray, objects: tuple[PlanObject, ...]) -> np.ndarray:
    """The crop with each object's id written at its box's top-left corner (several objects
    only: one object's crop is sent unmarked, as always)."""
    if len(objects) <= 1:
        return crop
    return on_text_thread(_mark_objects, crop, objects)


def _mark_objects(crop: np.ndarray, objects: tuple[PlanObject, ...]) -> np.ndarray:
    import cv2

    marked = np.ascontiguousarray(crop.copy())
    height, width = marked.shape[:2]
    scale = max(0.4, min(width, height) / 500)
    thick = max(1, round(scale * 2))
    for o in objects:
        label = str(o.id)
        (tw, th), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        x = int(np.clip(o.bbox_px[0], 0, max(0, width - tw - 4)))
        y = int(np.clip(o.bbox_px[1], 0, max(0, height - th - base - 4)))
        cv2.rectangle(marked, (x, y), (x + tw + 4, y + th + base + 4), (255, 255, 255), -1)
        cv2.putText(
            marked, label, (x + 2, y + th + 2), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick,
            cv2.LINE_AA,
        )  # fmt: skip
    return marked


def assign_pairs(pairs_crop_px: np.ndarray, objects: tuple[PlanObject, ...]) -> tuple[int, ...]:
    """Per pair, the id of the object it lies on: the one its points fall on, else the nearest.

    KeympsError when a pair lies on two objects (a cut from one into the other)."""
    pairs = np.asarray(pairs_crop_px, dtype=float).reshape(-1, 2, 2)
    if len(objects) == 1:
        return (objects[0].id,) * len(pairs)
    fractions = np.linspace(0.0, 1.0, SAMPLES_PER_PAIR)
    owners = []
    for number, (start, end) in enumerate(pairs, start=1):
        points = start + fractions[:, None] * (end - start)
        step = float(np.linalg.norm(end - start)) / (SAMPLES_PER_PAIR - 1)
        on = [(o, _pixels_on(o, points)) for o in objects]
        touched = [(o, count) for o, count in on if count > 0]
        if not touched:
            owners.append(min(objects, key=lambda o: _distance(o, (start + end) / 2)).id)
            continue
        spanning = [o for o, count in touched if count * step > SPAN_PX]
        if len(spanning) >= 2:
            names = " and ".join(o.label for o in spanning)
            raise KeympsError(
                f"pair {number} ({_point(start)} to {_point(end)} in the image sent) spans "
                f"objects {names}: a pair must lie on one object"
            )
        owners.append(max(touched, key=lambda item: item[1])[0].id)
    return tuple(owners)


def visit_order(
    owners: tuple[int, ...], objects: tuple[PlanObject, ...], start_px: tuple[float, float]
) -> list[int]:
    """Pair indices grouped by object, the objects in nearest-neighbour order from start_px
    (then improved by 2-opt), each object's pairs in the backend's order."""
    used = [o for o in objects if o.id in owners]
    if len(used) <= 1:
        return list(range(len(owners)))
    centres = {o.id: np.array(o.centre_px) for o in used}
    tour: list[int] = []
    here = np.asarray(start_px, dtype=float)
    left = [o.id for o in used]
    while left:
        nearest = min(left, key=lambda i: float(np.linalg.norm(centres[i] - here)))
        tour.append(nearest)
        left.remove(nearest)
        here = centres[nearest]
    tour = _two_opt(tour, centres, np.asarray(start_px, dtype=float))
    return [k for object_id in tour for k, owner in enumerate(owners) if owner == object_id]


def _two_opt(tour: list[int], centres: dict[int, np.ndarray], start: np.ndarray) -> list[int]:
    def length(order: list[int]) -> float:
        points = [start, *(centres[i] for i in order), start]
        return sum(float(np.linalg.norm(b - a)) for a, b in zip(points, points[1:], strict=False))

    best, improved = tour, True
    while improved:
        improved = False
        for i in range(len(best) - 1):
            for j in range(i + 2, len(best) + 1):
                candidate = best[:i] + best[i:j][::-1] + best[j:]
                if length(candidate) < length(best) - 1e-9:
                    best, improved = candidate, True
    return best


def _pixels_on(obj: PlanObject, points: np.ndarray) -> int:
    if obj.mask is None:
        x0, y0, x1, y1 = obj.bbox_px
        inside = (points[:, 0] >= x0) & (points[:, 0] < x1)
        inside &= (points[:, 1] >= y0) & (points[:, 1] < y1)
        return int(inside.sum())
    height, width = obj.mask.shape[:2]
    ij = np.floor(points).astype(int)
    valid = (ij[:, 0] >= 0) & (ij[:, 0] < width) & (ij[:, 1] >= 0) & (ij[:, 1] < height)
    ij = ij[valid]
    return int(obj.mask[ij[:, 1], ij[:, 0]].sum())


def _distance(obj: PlanObject, point: np.ndarray) -> float:
    x0, y0, x1, y1 = obj.bbox_px
    return math.hypot(max(x0 - point[0], 0, point[0] - x1), max(y0 - point[1], 0, point[1] - y1))


def _point(p: np.ndarray) -> str:
    return f"({p[0]:.0f}, {p[1]:.0f})"
