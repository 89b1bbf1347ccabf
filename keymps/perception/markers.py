"""Four ArUco markers at the board's corners -> scene.camera.board_corners_px.

Markers 0, 1, 2, 3 of OpenCV's DICT_4X4_50 lie on the table just outside the board's
bottom-left, bottom-right, top-right and top-left corners (as seen in the photo), each with one
corner of its black square touching the board's corner. That touching corner is the one nearest
the middle of the four markers, so a marker may be turned any way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from keymps.errors import KeympsError

DICTIONARY_NAME = "DICT_4X4_50"
CORNER_NAMES = ("bottom-left", "bottom-right", "top-right", "top-left")
"""Marker id -> the board corner it marks."""


def _dictionary():  # type: ignore[no-untyped-def]
    import cv2

    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY_NAME))


@dataclass(frozen=True)
class FoundMarkers:
    corners_px: np.ndarray
    """(4, 2) board corners, bottom-left first, continuous pixel coordinates."""
    marker_corners_px: dict[int, np.ndarray]
    """Marker id -> its four corners (ArUco order), continuous pixel coordinates."""
    ignored_ids: tuple[int, ...]
    """Markers seen that are not 0-3."""


MAX_REFINE_PX = 1.5
"""A sub-pixel corner further than this from the fitted lines' corner has wandered."""


def _detect(gray: np.ndarray, refinement: int) -> dict[int, list[np.ndarray]]:
    """Marker id -> each detection's four corners (continuous pixel coordinates)."""
    import cv2

    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = refinement
    found, ids, _ = cv2.aruco.ArucoDetector(_dictionary(), parameters).detectMarkers(gray)
    seen: dict[int, list[np.ndarray]] = {}
    for corners, marker_id in zip(found, [] if ids is None else ids.ravel(), strict=True):
        seen.setdefault(int(marker_id), []).append(corners.reshape(4, 2).astype(float) + 0.5)
    return seen


def find_board_corners(image: np.ndarray, source: str = "the image") -> FoundMarkers:
    """The board's corners from markers 0-3; a clear error when one is missing or doubled."""
    import cv2

    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    seen = _detect(gray, cv2.aruco.CORNER_REFINE_SUBPIX)
    # lines fitted to the sides of each black square and intersected: robust where the corner
    # touching the board has board, not paper, around it; sub-pixel corners unless they wandered
    lines = _detect(gray, cv2.aruco.CORNER_REFINE_CONTOUR)
    for marker_id, found in seen.items():
        robust = lines.get(marker_id, [])
        if len(found) == 1 and len(robust) == 1:
            far = np.linalg.norm(found[0] - robust[0], axis=1) > MAX_REFINE_PX
            found[0][far] = robust[0][far]
    doubled = [i for i in range(4) if len(seen.get(i, [])) > 1]
    if doubled:
        where = "; ".join(
            f"marker {i} ({CORNER_NAMES[i]}) at "
            + " and ".join(f"({c.mean(0)[0]:.0f}, {c.mean(0)[1]:.0f})" for c in seen[i])
            for i in doubled
        )
        raise KeympsError(
            f"{source}: {where}: each of markers 0-3 must appear once; cover or remove the extra"
        )
    missing = [i for i in range(4) if i not in seen]
    if missing:
        names = ", ".join(f"{i} ({CORNER_NAMES[i]})" for i in missing)
        present = ", ".join(str(i) for i in sorted(seen)) or "none"
        raise KeympsError(
            f"{source}: marker {names} not found (found: {present}); every corner of the board "
            f"needs its {DICTIONARY_NAME} marker in view, flat, unoccluded and well lit "
            "(`keymps calibrate --print-markers FILE.png` prints them)"
        )
    markers = {i: seen[i][0] for i in range(4)}
    _refuse_out_of_order(markers, source)
    inner = np.array([_touching_corner(i, markers) for i in range(4)])
    ignored = tuple(sorted(i for i in seen if i > 3))
    return FoundMarkers(inner, markers, ignored)


def _refuse_out_of_order(markers: dict[int, np.ndarray], source: str) -> None:
    """Markers 0, 1, 2, 3 must go round the board as its bottom-left, bottom-right, top-right
    and top-left corners (clockwise on screen); the printed sheet itself, or markers swapped,
    would otherwise end in a 'non-convex quadrilateral' that names no marker."""
    centres = np.array([markers[i].mean(axis=0) for i in range(4)])
    edges = np.roll(centres, -1, axis=0) - centres
    following = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * following[:, 1] - edges[:, 1] * following[:, 0]
    if np.all(cross < 0):  # y down: that order turns clockwise on screen
        return
    middle = centres.mean(axis=0)
    seen_at = [
        f"{i} ({CORNER_NAMES[i]}) is at the {'top' if y < middle[1] else 'bottom'}"
        f"-{'left' if x < middle[0] else 'right'}"
        for i, (x, y) in enumerate(centres)
    ]
    raise KeympsError(
        f"{source}: markers 0-3 are out of order: {'; '.join(seen_at)}. Place marker 0 at the "
        "board's bottom-left corner, 1 bottom-right, 2 top-right and 3 top-left, as seen in the "
        "photo (a photo of the printed sheet itself is no board: cut the markers out)"
    )


def _touching_corner(marker_id: int, markers: dict[int, np.ndarray]) -> np.ndarray:
    """The corner of this marker nearest the middle of the four, judged on the board plane
    (the marker's own square fixes that plane's metric up to scale, whatever the perspective)."""
    import cv2

    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    to_plane = cv2.getPerspectiveTransform(
        markers[marker_id].astype(np.float32), square.astype(np.float32)
    )
    centres = [
        cv2.perspectiveTransform(markers[i].reshape(-1, 1, 2), to_plane).reshape(-1, 2).mean(axis=0)
        for i in range(4)
    ]
    middle = np.mean(centres, axis=0)
    return markers[marker_id][int(np.argmin(np.linalg.norm(square - middle, axis=1)))]


def marker_image(marker_id: int, side_px: int) -> np.ndarray:
    """The marker's black-and-white square (side_px x side_px, uint8)."""
    import cv2

    return np.asarray(cv2.aruco.generateImageMarker(_dictionary(), marker_id, side_px))


def marker_sheet(marker_mm: float, dpi: int = 300) -> np.ndarray:
    """A printable page (A4 portrait at dpi) of markers 0-3, each labelled with its corner."""
    import cv2

    px_per_mm = dpi / 25.4
    page = np.full((round(297 * px_per_mm), round(210 * px_per_mm)), 255, np.uint8)
    side = round(marker_mm * px_per_mm)
    if 2 * side + round(60 * px_per_mm) > page.shape[1]:
        raise KeympsError(
            f"--marker-size {marker_mm:g} mm: two markers do not fit across an A4 page"
        )
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.9 * dpi / 300
    thick = max(1, round(2 * dpi / 300))
    margin = round(20 * px_per_mm)
    gap_x = page.shape[1] - 2 * margin - 2 * side
    for marker_id in range(4):
        row, col = divmod(marker_id, 2)
        x = margin + col * (side + gap_x)
        y = margin + round(25 * px_per_mm) + row * (side + round(45 * px_per_mm))
        page[y : y + side, x : x + side] = marker_image(marker_id, side)
        label = f"{marker_id}: {CORNER_NAMES[marker_id]}"
        cv2.putText(page, label, (x, y - round(4 * px_per_mm)), font, scale, 0, thick, cv2.LINE_AA)
    lines = [
        f"keymps markers {DICTIONARY_NAME}, each {marker_mm:g} mm square: print at 100 % (no fit-to-page)",
        "Cut them out; lay each flat just outside its corner of the board,",
        "one corner of its black square touching the board's corner.",
    ]
    y = page.shape[0] - margin - round(12 * px_per_mm) * len(lines)
    for line in lines:
        cv2.putText(page, line, (margin, y), font, 0.8 * scale, 0, thick, cv2.LINE_AA)
        y += round(12 * px_per_mm)
    return page
