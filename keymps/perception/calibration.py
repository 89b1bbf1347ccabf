"""`keymps calibrate`'s work: markers in a photo -> the scene.camera YAML block, and the sheet."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from keymps.errors import KeympsError
from keymps.perception.frames import ImageFrame
from keymps.perception.image_io import read_image
from keymps.perception.markers import (
    CORNER_NAMES,
    DICTIONARY_NAME,
    find_board_corners,
    marker_sheet,
)

MARKER_SIZE_TOLERANCE = 0.05
"""Markers measured more than 5 % off their printed size mean a wrong --board or --marker-size."""


def _marker_sides_mm(frame: ImageFrame, marker_px: np.ndarray) -> float:
    corners = frame.to_board(marker_px)
    return float(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1).mean() * 1000)


def calibration_yaml(
    image_path: Path,
    board_m: tuple[float, float],
    marker_mm: float,
    intrinsics: list[float] | None,
    distortion: list[float],
    mm_per_px: float,
) -> tuple[str, list[str]]:
    """The scene.camera block for the photo at image_path, from markers 0-3 at its corners.

    Args:
        image_path: The photo (any format OpenCV reads).
        board_m: (width, height) between the markers' touching corners, metres.
        marker_mm: The markers' printed side, millimetres (a check: each is measured).
        intrinsics: [fx, fy, cx, cy] in pixels, or None (no camera pose then).
        distortion: OpenCV's distortion coefficients (4, 5 or 8; empty: none).
        mm_per_px: The rectified image's scale the block asks for.

    Returns:
        The YAML text (comments, then `scene:`) and the warnings to show (one line each).

    Raises:
        KeympsError: For a board side outside 0-3 m, an unreadable photo, or markers missing
            or out of place.
    """
    if not all(0 < v <= 3.0 for v in board_m):
        raise KeympsError(f"--board {board_m[0]:g},{board_m[1]:g}: each side is metres, 0 to 3")
    image = read_image(image_path)
    found = find_board_corners(image, str(image_path))
    size = (int(image.shape[1]), int(image.shape[0]))
    camera = _camera(intrinsics, distortion)
    ideal = _ideal(found.corners_px, camera)
    try:
        frame = ImageFrame.from_corners(size, board_m, ideal)
    except KeympsError as error:
        raise KeympsError(f"{image_path}: the markers' corners {error}") from None
    measured = [
        _marker_sides_mm(frame, _ideal(found.marker_corners_px[marker_id], camera))
        for marker_id in range(4)
    ]
    lines = [
        f"# keymps calibrate {image_path.name}: markers 0-3 ({DICTIONARY_NAME}) in a "
        f"{size[0]} x {size[1]} px photo",
        "# markers measure "
        + ", ".join(f"{CORNER_NAMES[i]} {m:.1f}" for i, m in enumerate(measured))
        + f" mm ({marker_mm:g} mm printed)",
    ]
    if camera is not None:
        lines.append(_camera_pose_comment(ideal, board_m, camera[0]))
    lines += _scene_block(found.corners_px, board_m, mm_per_px, intrinsics, distortion)
    notes = _size_warnings(measured, marker_mm, board_m) + _ignored_warnings(found.ignored_ids)
    return "\n".join(lines) + "\n", notes


def _camera(
    intrinsics: list[float] | None, distortion: list[float]
) -> tuple[np.ndarray, np.ndarray] | None:
    """(K, distortion coefficients) from [fx, fy, cx, cy], or None without intrinsics."""
    if intrinsics is None:
        return None
    fx, fy, cx, cy = intrinsics
    matrix = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    return matrix, np.array(distortion or [0.0, 0.0, 0.0, 0.0], float)


def _ideal(points_px: np.ndarray, camera: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """Photo pixels (N, 2) as the camera without lens distortion would see them (no camera:
    as they are)."""
    from keymps.perception.rectify import undistort_points

    return points_px if camera is None else undistort_points(points_px, *camera)


def _camera_pose_comment(
    ideal_corners_px: np.ndarray, board_m: tuple[float, float], matrix: np.ndarray
) -> str:
    """The comment line with the camera's position (board frame) and its axis' tilt."""
    from keymps.perception.rectify import board_pose

    board = np.array([[0, 0], [board_m[0], 0], [board_m[0], board_m[1]], [0, board_m[1]]])
    rotation, translation = board_pose(ideal_corners_px, board, matrix)
    centre = -rotation.T @ translation
    tilt = np.degrees(np.arccos(np.clip(rotation[2] @ [0, 0, -1.0], -1, 1)))
    return (
        f"# camera at ({centre[0]:.3f}, {centre[1]:.3f}, {centre[2]:.3f}) m in the board "
        f"frame, its axis {tilt:.0f} degrees from straight down"
    )


def _scene_block(
    corners_px: np.ndarray,
    board_m: tuple[float, float],
    mm_per_px: float,
    intrinsics: list[float] | None,
    distortion: list[float],
) -> list[str]:
    """The YAML lines from `scene:` on: the workspace and the camera as the task file has them."""
    shown = ", ".join(f"[{x:.2f}, {y:.2f}]" for x, y in corners_px)
    lines = [
        "scene:",
        f"  workspace: {{size: [{board_m[0]:g}, {board_m[1]:g}]}}",
        "  camera:",
        f"    board_corners_px: [{shown}]   # bottom-left, bottom-right, top-right, top-left",
        f"    mm_per_px: {mm_per_px:g}",
    ]
    if intrinsics is not None:
        fx, fy, cx, cy = intrinsics
        given = f", distortion: [{', '.join(f'{v:g}' for v in distortion)}]" if distortion else ""
        lines.append(f"    intrinsics: {{fx: {fx:g}, fy: {fy:g}, cx: {cx:g}, cy: {cy:g}{given}}}")
    return lines


def _size_warnings(
    measured_mm: list[float], marker_mm: float, board_m: tuple[float, float]
) -> list[str]:
    """A warning when a marker measures more than MARKER_SIZE_TOLERANCE off its printed size."""
    if max(abs(m / marker_mm - 1) for m in measured_mm) <= MARKER_SIZE_TOLERANCE:
        return []
    return [
        f"the markers measure {', '.join(f'{m:.1f}' for m in measured_mm)} mm on a "
        f"{board_m[0]:g} x {board_m[1]:g} m board, not {marker_mm:g} mm: check --board "
        "(the distance between the markers' touching corners) and --marker-size"
    ]


def _ignored_warnings(ignored_ids: tuple[int, ...]) -> list[str]:
    """A warning naming the markers that are not corner markers, if any."""
    if not ignored_ids:
        return []
    return [f"markers {list(ignored_ids)} are not corner markers (0-3) and were ignored"]


def write_marker_sheet(path: Path, marker_mm: float) -> str:
    """Write the printable sheet; the line to show the user."""
    import cv2

    if path.suffix.lower() != ".png":
        raise KeympsError(
            f"--print-markers {path}: the sheet is written as PNG (end the name in .png)"
        )
    page = marker_sheet(marker_mm)
    if not cv2.imwrite(str(path), page):
        raise KeympsError(f"--print-markers {path}: cannot write the file")
    return (
        f"wrote {path}: markers 0-3 ({DICTIONARY_NAME}), {marker_mm:g} mm squares on an A4 page at "
        "300 dpi; print at 100 % and check one square with a ruler"
    )
