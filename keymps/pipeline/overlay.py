"""plan.png: the scene with the detection box and the numbered keypoint pairs (paper Fig. 13);
plan_photo.png: the same carried back into the original photo of a rectified scene."""

from __future__ import annotations

import numpy as np

from keymps.text_drawing import on_text_thread
from keymps.types import Detection, Plan, SceneImage

RED = (0, 0, 255)
GREEN = (0, 200, 0)
BOX = (255, 200, 0)
OTHER_BOX = (160, 160, 160)
DOT_PX = 1.5
"""A pair whose start and end are closer than this (pixels) is drawn as a dot."""
_SHIFT = 4  # fixed-point bits for sub-pixel drawing


def _fixed(point: np.ndarray, scale: float) -> tuple[int, int]:
    # Keypoints use continuous pixel coordinates (pixel centres at +0.5); cv2 draws at indices.
    x, y = (np.asarray(point, dtype=float) * scale - 0.5) * (1 << _SHIFT)
    return int(round(x)), int(round(y))


def _as_bgr(image: np.ndarray) -> np.ndarray:
    from keymps.perception.image_io import to_bgr8

    return to_bgr8(np.asarray(image)).copy()


def draw_plan(
    image: np.ndarray, detection: Detection, plan: Plan, *, scale: float = 1.0
) -> np.ndarray:
    """The full image (BGR) with the detection box, red keypoint lines and green order numbers.

    A pair whose start and end coincide (an icing dot) is a small red circle. Lines end in an
    arrow head to show the direction. `scale` enlarges the picture (the numbers stay legible).
    """
    return on_text_thread(_draw_plan, image, detection, plan, scale)


def _draw_plan(image: np.ndarray, detection: Detection, plan: Plan, scale: float) -> np.ndarray:
    import cv2

    canvas = _as_bgr(image)
    if scale != 1.0:
        size = (round(canvas.shape[1] * scale), round(canvas.shape[0] * scale))
        canvas = cv2.resize(canvas, size, interpolation=cv2.INTER_CUBIC)
    height, width = canvas.shape[:2]
    thick = max(1, round(min(width, height) / 300))
    font = cv2.FONT_HERSHEY_SIMPLEX
    font_scale = max(0.45, min(width, height) / 700)
    if len(detection.objects) > 1:  # several objects: every box, each with its number
        for obj in detection.objects:
            _rectangle(canvas, obj.bbox_px, scale, BOX, thick)
            _object_number(canvas, obj.id, obj.bbox_px, scale, font, font_scale, thick)
    else:
        for box in detection.others_px:
            _rectangle(canvas, box, scale, OTHER_BOX, 1)
        _rectangle(canvas, detection.bbox_px, scale, BOX, thick)
    pairs = np.asarray(plan.pairs_px, dtype=float).reshape(-1, 2, 2)
    x0, y0, x1, y1 = detection.bbox_px
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2], dtype=float)
    for start, end in pairs:
        length_px = float(np.linalg.norm(end - start)) * scale
        if length_px < DOT_PX * scale:
            radius = (3 * thick) << _SHIFT
            cv2.circle(canvas, _fixed(start, scale), radius, RED, thick, cv2.LINE_AA, _SHIFT)
        else:
            tip = min(0.3, 6.0 * thick / length_px)
            cv2.arrowedLine(
                canvas, _fixed(start, scale), _fixed(end, scale), RED, thick, cv2.LINE_AA,
                _SHIFT, tip,
            )  # fmt: skip
    for number, (start, end) in enumerate(pairs, start=1):
        label = str(number)
        (text_w, text_h), _ = cv2.getTextSize(label, font, font_scale, thick)
        direction = end - start
        norm = float(np.linalg.norm(direction))
        # Put the number beside the start, away from the line.
        if norm > DOT_PX:
            away = -direction / norm
        else:  # a dot: outwards from the object's centre, so rings of dots stay readable
            outwards = start - centre
            spread = float(np.linalg.norm(outwards))
            away = outwards / spread if spread > 1.0 else np.array([0.7, -0.7])
        anchor = start * scale + away * (4 * thick + max(text_w, text_h) / 2)
        x = int(np.clip(anchor[0] - text_w / 2, 0, max(0, width - text_w)))
        y = int(np.clip(anchor[1] + text_h / 2, text_h, height - 1))
        cv2.putText(canvas, label, (x, y), font, font_scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
        cv2.putText(canvas, label, (x, y), font, font_scale, GREEN, thick, cv2.LINE_AA)
    return canvas


def _object_number(
    canvas: np.ndarray,
    number: int,
    box: tuple[int, int, int, int],
    scale: float,
    font: int,
    font_scale: float,
    thick: int,
) -> None:
    """'#N' in the box colour just above (or inside, at the image's top) the box's corner."""
    import cv2

    label = f"#{number}"
    (text_w, text_h), _ = cv2.getTextSize(label, font, font_scale, thick)
    height, width = canvas.shape[:2]
    x = int(np.clip(box[0] * scale, 0, max(0, width - text_w)))
    y = int(box[1] * scale) - 4
    y = y if y - text_h >= 0 else int(box[1] * scale) + text_h + 4
    cv2.putText(canvas, label, (x, y), font, font_scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
    cv2.putText(canvas, label, (x, y), font, font_scale, BOX, thick, cv2.LINE_AA)


def _rectangle(
    canvas: np.ndarray, box: tuple[int, int, int, int], scale: float, colour: tuple, thick: int
) -> None:
    import cv2

    x0, y0, x1, y1 = (float(v) * scale for v in box)
    top_left = (int(round(x0)), int(round(y0)))
    bottom_right = (int(round(x1)) - 1, int(round(y1)) - 1)
    cv2.rectangle(canvas, top_left, bottom_right, colour, thick, cv2.LINE_8)


def draw_plan_on_photo(scene: SceneImage, detection: Detection, plan: Plan) -> np.ndarray | None:
    """The original photo of a rectified scene with the board's outline (cyan), the object's
    outline and the keypoint pairs carried back into it, to check the rectification by eye;
    None when the scene was not rectified."""
    import cv2

    from keymps.perception.rectify import photo_points

    info = scene.rectification
    if info is None:
        return None
    canvas = _as_bgr(info.photo)
    thick = max(1, round(min(canvas.shape[:2]) / 400))

    def polyline(points: np.ndarray, colour: tuple, closed: bool) -> None:
        photo = photo_points(info, points)
        fixed = np.round((photo - 0.5) * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(canvas, [fixed], closed, colour, thick, cv2.LINE_AA, _SHIFT)

    board = np.asarray(info.board_polygon_px, float)
    edges = np.concatenate(
        [np.linspace(a, b, 32) for a, b in zip(board, np.roll(board, -1, 0), strict=True)]
    )
    polyline(edges, BOX, True)
    contour = np.asarray(detection.contour_px, float).reshape(-1, 2)
    if len(contour) >= 3:
        polyline(contour + 0.5, GREEN, True)
    for start, end in np.asarray(plan.pairs_px, dtype=float).reshape(-1, 2, 2):
        if np.linalg.norm(end - start) < DOT_PX:
            (centre,) = photo_points(info, start[None])
            point = tuple(int(v) for v in np.round((centre - 0.5) * (1 << _SHIFT)))
            cv2.circle(canvas, point, (3 * thick) << _SHIFT, RED, thick, cv2.LINE_AA, _SHIFT)
        else:
            polyline(np.linspace(start, end, 16), RED, False)
    return canvas
