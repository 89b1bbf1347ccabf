"""plan_outcome.png: the predicted result drawn on the scene, so a cook sees it before the
robot moves: the pieces coloured with their areas and shares, the cuts through the food, the
icing deposits, and the verdict."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.outcome.deposits import merges
from keymps.text_drawing import on_text_thread
from keymps.types import Outcome, SceneImage

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.outcome.predict import Food

PALETTE = (
    (230, 159, 0), (86, 180, 233), (0, 158, 115), (240, 228, 66),
    (0, 114, 178), (213, 94, 0), (204, 121, 167), (120, 120, 220),
)  # fmt: skip
"""Piece colours (BGR of the Okabe-Ito palette, distinguishable with colour blindness)."""
PIECE_ALPHA = 0.45
CUT = (20, 20, 20)
ICING = (250, 250, 250)
ICING_EDGE = (110, 110, 110)
WRONG = (0, 0, 230)
PASS = (0, 150, 0)
SHIFT = 4  # sub-pixel drawing: coordinates in 1/16 pixel


def draw_outcome(scene: SceneImage, task: Task, foods: Sequence[Food], outcome: Outcome) -> Any:
    """The scene image (BGR uint8) with the predicted pieces, cuts and deposits and the verdict."""
    from keymps.perception.frames import ImageFrame

    frame = ImageFrame.for_scene(task, scene)
    return on_text_thread(_draw, np.ascontiguousarray(scene.image.copy()), frame, outcome)


def _draw(image: np.ndarray, frame: Any, outcome: Outcome) -> np.ndarray:
    import cv2

    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    per_metre = 1.0 / frame.metres_per_pixel()

    def pixels(xy: np.ndarray) -> np.ndarray:
        points = frame.to_pixels(np.asarray(xy, float).reshape(-1, 2))
        return np.round(points * (1 << SHIFT)).astype(np.int32)

    predicted = outcome.predicted
    if predicted.pieces:
        layer = image.copy()
        for k, piece in enumerate(predicted.pieces):
            colour = PALETTE[k % len(PALETTE)]
            cv2.fillPoly(layer, [pixels(piece.outline_m)], colour, cv2.LINE_AA, SHIFT)
        image = cv2.addWeighted(layer, PIECE_ALPHA, image, 1 - PIECE_ALPHA, 0)
    for cut in predicted.cuts:
        for stretch in cut.severed_m:
            cv2.polylines(image, [pixels(stretch)], False, CUT, 2, cv2.LINE_AA, SHIFT)
    _draw_deposits(image, outcome, pixels, per_metre)
    for piece in predicted.pieces:
        centre = frame.to_pixels(np.asarray(piece.outline_m, float).mean(axis=0, keepdims=True))[0]
        _label(image, (int(centre[0]), int(centre[1])), f"{1e4 * piece.area_m2:.1f} cm2",
               f"{100 * piece.share:.0f} %")  # fmt: skip
    _verdict(image, outcome)
    return image


def _draw_deposits(image: np.ndarray, outcome: Outcome, pixels: Any, per_metre: float) -> None:
    import cv2

    deposits = outcome.predicted.deposits
    if not deposits:
        return
    line_width = (
        min(d.width_m for d in deposits if d.kind == "line")
        if any(d.kind == "line" for d in deposits)
        else deposits[0].width_m / 2
    )
    merged = {k for m in merges(deposits, line_width) for k in (m.first, m.second)}
    for k, deposit in enumerate(deposits):
        width = max(1, round(deposit.width_m * per_metre))
        wrong = k in merged or not deposit.on_top
        edge = WRONG if wrong else ICING_EDGE
        if deposit.kind == "dot":
            centre = tuple(int(v) for v in pixels(deposit.path_m)[0])
            radius = max(1, round(width / 2)) << SHIFT
            cv2.circle(image, centre, radius + (1 << SHIFT), edge, -1, cv2.LINE_AA, SHIFT)
            cv2.circle(image, centre, radius, ICING, -1, cv2.LINE_AA, SHIFT)
        else:
            path = [pixels(deposit.path_m)]
            cv2.polylines(image, path, False, edge, width + 2, cv2.LINE_AA, SHIFT)
            cv2.polylines(image, path, False, ICING, width, cv2.LINE_AA, SHIFT)


def _label(image: np.ndarray, at: tuple[int, int], *lines: str) -> None:
    """Lines of small text centred on `at`, dark on a light halo."""
    import cv2

    font, scale = cv2.FONT_HERSHEY_SIMPLEX, max(0.35, min(image.shape[:2]) / 1000)
    height = cv2.getTextSize("0", font, scale, 1)[0][1] + 4
    top = at[1] - height * (len(lines) - 1) // 2
    for k, text in enumerate(lines):
        width = cv2.getTextSize(text, font, scale, 1)[0][0]
        origin = (at[0] - width // 2, top + k * height)
        cv2.putText(image, text, origin, font, scale, (255, 255, 255), 3, cv2.LINE_AA)
        cv2.putText(image, text, origin, font, scale, (0, 0, 0), 1, cv2.LINE_AA)


def _verdict(image: np.ndarray, outcome: Outcome) -> None:
    """The verdict in the top-left corner: pass, or the first problem."""
    import cv2

    if outcome.verdict == "pass":
        text, colour = "predicted outcome: as intended", PASS
    else:
        text, colour = f"predicted outcome {outcome.verdict.upper()}: {outcome.problems[0]}", WRONG
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, max(0.35, min(image.shape[:2]) / 1000)
    limit = image.shape[1] - 10
    while len(text) > 20 and cv2.getTextSize(text, font, scale, 1)[0][0] > limit:
        text = text[: len(text) - 8] + "..."
    cv2.putText(image, text, (5, 15), font, scale, (255, 255, 255), 3, cv2.LINE_AA)
    cv2.putText(image, text, (5, 15), font, scale, colour, 1, cv2.LINE_AA)
