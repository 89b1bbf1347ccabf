"""A photo at an angle -> a metric top-down image of the board, before anything is detected.

With `scene.camera.board_corners_px` the photo is warped so that the board fills the image at
`scene.camera.mm_per_px` (0.5 mm per pixel by default): the image then spans the workspace
exactly, Appendix B holds, and detection, planning and grounding measure true millimetres.

With `scene.camera.intrinsics` as well, the photo is undistorted and the camera's position is
recovered from the four corners (cv2.solvePnP). The object's top (z = scene.object_height)
then appears in the rectified image scaled by k = Cz / (Cz - h) about the camera's foot point
(the board point under the camera): ImageFrame.for_scene grounds pixels on that plane
(undoing the scale) instead of shifting them by height x tan(view angle), and `top_surface`
removes the object's visible sides from a detection (see its docstring).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from keymps.errors import DetectionError, KeympsError
from keymps.perception.frames import ImageFrame, homography
from keymps.types import DetectedObject, Detection, Rectification, SceneImage

if TYPE_CHECKING:
    from keymps.config.task import Task


def camera_matrix(task: Task) -> tuple[np.ndarray, np.ndarray] | None:
    """(K, distortion) from scene.camera.intrinsics, or None."""
    given = task.scene.camera.intrinsics
    if given is None:
        return None
    matrix = np.array([[given.fx, 0, given.cx], [0, given.fy, given.cy], [0, 0, 1.0]])
    return matrix, np.array(given.distortion or (0.0, 0.0, 0.0, 0.0), dtype=float)


def undistort_points(
    points_px: np.ndarray, matrix: np.ndarray, distortion: np.ndarray
) -> np.ndarray:
    """Continuous photo pixels -> the pixels an ideal (distortion-free) camera K would see."""
    import cv2

    index = np.asarray(points_px, float).reshape(-1, 1, 2) - 0.5
    ideal = cv2.undistortPoints(index, matrix, distortion, P=matrix)
    return ideal.reshape(-1, 2) + 0.5


def distort_points(points_px: np.ndarray, matrix: np.ndarray, distortion: np.ndarray) -> np.ndarray:
    """The inverse of undistort_points: ideal continuous pixels -> photo pixels."""
    import cv2

    index = np.asarray(points_px, float).reshape(-1, 2) - 0.5
    normalized = (index - matrix[:2, 2]) / np.diag(matrix)[:2]
    rays = np.hstack([normalized, np.ones((len(normalized), 1))]).reshape(-1, 1, 3)
    projected, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), matrix, distortion)
    return projected.reshape(-1, 2) + 0.5


def board_pose(
    corners_px: np.ndarray, board_m: np.ndarray, matrix: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of the board frame in the camera frame from the ideal corner pixels (IPPE)."""
    import cv2

    objects = np.hstack([board_m, np.zeros((4, 1))]).astype(np.float64)
    found, rvec, tvec = cv2.solvePnP(
        objects, corners_px.reshape(-1, 1, 2) - 0.5, matrix, None, flags=cv2.SOLVEPNP_IPPE
    )
    if not found:
        raise KeympsError("scene.camera: the camera's pose cannot be found from the board corners")
    rotation, _ = cv2.Rodrigues(rvec)
    return rotation, tvec.reshape(3)


def rectify_scene(scene: SceneImage, task: Task) -> SceneImage:
    """The scene as the stages see it: rectified when the task gives board corners.

    Args:
        scene: The photo as loaded.
        task: The task; its scene.camera says where the board's corners are in the photo,
            the rectified image's mm per pixel and, optionally, the camera's intrinsics.

    Returns:
        `scene` itself without board corners; else the board seen from straight above at
        scene.camera.mm_per_px, spanning the workspace, with how it was made.

    Raises:
        KeympsError: For a rectified image over scene.max_image_pixels, corners that are not
            a board, or a camera the corners put below the object's top.
    """
    import cv2

    camera = task.scene.camera
    if camera.board_corners_px is None:
        return scene
    workspace = task.scene.workspace
    size = _rectified_size(task)
    corners = np.asarray(camera.board_corners_px, float)
    ImageFrame.from_corners(scene.size_px, workspace.size, corners, workspace.shift)  # checks
    frame = ImageFrame.linear(size, workspace.size, workspace.shift)
    board_polygon = np.array([[0, size[1]], [size[0], size[1]], [size[0], 0], [0, 0]], float)
    board_m = frame.to_board(board_polygon)
    intrinsics = camera_matrix(task)
    ideal, position = corners, None
    if intrinsics is not None:
        ideal = undistort_points(corners, *intrinsics)
        position = _camera_position(ideal, board_m, intrinsics[0], task.scene.object_height)
    to_photo = homography(board_m, ideal) @ frame.matrix
    map_x, map_y = _remap_grid(to_photo, size, intrinsics)
    rectified = cv2.remap(
        scene.image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
    )
    info = Rectification(
        photo=scene.image,
        mm_per_px=float(camera.mm_per_px),
        plane_z=0.0 if position is None else float(task.scene.object_height),
        to_photo=to_photo,
        board_polygon_px=board_polygon,
        camera_matrix=None if intrinsics is None else intrinsics[0],
        distortion=None if intrinsics is None else intrinsics[1],
        camera_position_m=position,
        camera_foot_px=None
        if position is None
        else _point(frame.to_pixels(np.array(position[:2]))),
    )
    return SceneImage(rectified, f"{scene.source} (rectified)", truth=None, rectification=info)


def _rectified_size(task: Task) -> tuple[int, int]:
    """(width, height) pixels of the workspace at scene.camera.mm_per_px, refused over
    scene.max_image_pixels."""
    mm_per_px = task.scene.camera.mm_per_px
    scale = mm_per_px / 1000.0
    width, height = task.scene.workspace.size
    size = (round(width / scale), round(height / scale))
    if size[0] * size[1] > task.scene.max_image_pixels:
        raise KeympsError(
            f"scene.camera.mm_per_px: {mm_per_px:g} mm per pixel makes the rectified "
            f"board {size[0]} x {size[1]} px, over scene.max_image_pixels; choose a larger value"
        )
    return size


def _camera_position(
    ideal: np.ndarray, board_m: np.ndarray, matrix: np.ndarray, object_height: float
) -> tuple[float, float, float]:
    """The camera's centre in the board frame, metres, from the ideal (undistorted) pixels
    (4, 2) of the board's corners board_m (4, 2) metres; refused unless it is above the
    object's top at `object_height` metres."""
    rotation, translation = board_pose(ideal, board_m, matrix)
    centre = -rotation.T @ translation
    height = float(object_height)
    if centre[2] > 0.05 and centre[2] <= height + 0.01:
        raise KeympsError(
            f"scene.object_height: {height:g} m is not below the camera, which the board "
            f"corners and intrinsics put {centre[2]:.3f} m above the board: the unit is metres"
        )
    if centre[2] <= height + 0.01:
        raise KeympsError(
            f"scene.camera: the camera found from the board corners is {centre[2]:.3f} m "
            "above the board, not above the object: check the corners' order "
            "(bottom-left, bottom-right, top-right, top-left) and the intrinsics"
        )
    return float(centre[0]), float(centre[1]), float(centre[2])


def _point(points: np.ndarray) -> tuple[float, float]:
    x, y = (float(v) for v in np.asarray(points, float).reshape(-1, 2)[0])
    return x, y


def _remap_grid(
    to_photo: np.ndarray,
    size: tuple[int, int],
    intrinsics: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray]:
    width, height = size
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    points = np.c_[cols.ravel(), rows.ravel(), np.ones(cols.size)] @ to_photo.T
    photo = points[:, :2] / points[:, 2:3]
    if intrinsics is not None and np.any(intrinsics[1]):
        photo = distort_points(photo, *intrinsics)
    photo = (photo - 0.5).astype(np.float32)
    return photo[:, 0].reshape(height, width), photo[:, 1].reshape(height, width)


def photo_points(rectification: Rectification, points_px: np.ndarray) -> np.ndarray:
    """Rectified pixels (N, 2) -> the photo's own pixels (distortion applied)."""
    points = np.asarray(points_px, float).reshape(-1, 2)
    mapped = np.c_[points, np.ones(len(points))] @ rectification.to_photo.T
    photo = mapped[:, :2] / mapped[:, 2:3]
    matrix, distortion = rectification.camera_matrix, rectification.distortion
    if matrix is not None and distortion is not None and np.any(distortion):
        photo = distort_points(photo, matrix, distortion)
    return photo


def top_surface(detection: Detection, scene: SceneImage) -> Detection:
    """The detection of the object's top alone. In the rectified board image, the footprint F
    is at true scale and the top at F scaled by k = Cz / (Cz - h) about the camera's foot c;
    the sides fill the band between, so the silhouette S is the union of F scaled by 1 to k.
    The top is what lies in S *and* in S scaled by k about c: exact for a prism, a close bound
    for a rounded object."""
    info = scene.rectification
    if info is None or info.camera_position_m is None or info.plane_z <= 0:
        return detection
    cz = info.camera_position_m[2]
    grow = cz / (cz - info.plane_z)
    assert info.camera_foot_px is not None
    scaling = _scaling_about(info.camera_foot_px, grow)
    top = _top_mask(detection.mask, scaling, scene.size_px)
    if top is None:
        raise DetectionError(
            f"the object (box {list(detection.bbox_px)}) has no top surface once its sides are "
            f"removed for scene.object_height {info.plane_z:g} m: is the height right?",
        )
    bbox, contour = _box_and_contour(top)
    x0, y0, x1, y1 = _padded_crop(bbox, detection, scene.size_px)
    report = dict(detection.report)
    report["top_surface"] = {
        "camera_position_m": [round(v, 4) for v in info.camera_position_m],
        "silhouette_bbox_px": list(detection.bbox_px),
        "top_bbox_px": list(bbox),
        "why": f"sides removed: the silhouette intersected with itself grown x{grow:.4f} "
        "about the camera's foot point",
    }
    return dataclasses.replace(
        detection,
        bbox_px=bbox,
        crop=np.ascontiguousarray(scene.image[y0:y1, x0:x1]),
        crop_origin_px=(x0, y0),
        contour_px=contour,
        mask=top,
        objects=_top_objects(detection.objects, scaling, scene.size_px),
        report=report,
    )


def _scaling_about(point_px: tuple[float, float], factor: float) -> np.ndarray:
    """(2, 3) the affine map of pixel indices that scales by `factor` about a point given in
    continuous pixels."""
    centre = np.asarray(point_px, float) - 0.5  # warpAffine works in pixel indices
    return np.array([[factor, 0, centre[0] * (1 - factor)], [0, factor, centre[1] * (1 - factor)]])


def _top_mask(
    mask: np.ndarray | None, scaling: np.ndarray, size_px: tuple[int, int]
) -> np.ndarray | None:
    """The largest region of the silhouette `mask` (H, W bool) that its copy moved by
    `scaling` also covers, filled; None without a mask or when nothing is left."""
    import cv2

    if mask is None:
        return None
    grown = cv2.warpAffine(mask.astype(np.uint8), scaling, size_px, flags=cv2.INTER_NEAREST)
    top = (mask & (grown > 0)).astype(np.uint8)
    contours, _ = cv2.findContours(top, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    largest = max(contours, key=cv2.contourArea)
    filled = np.zeros_like(top)
    cv2.drawContours(filled, [largest], -1, 1, cv2.FILLED)
    return filled > 0


def _padded_crop(
    bbox: tuple[int, int, int, int], detection: Detection, size_px: tuple[int, int]
) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of a crop around bbox with the detection's own padding, in the image."""
    width, height = size_px
    pad_x = max(0, detection.bbox_px[0] - detection.crop_origin_px[0])
    pad_y = max(0, detection.bbox_px[1] - detection.crop_origin_px[1])
    pad = max(pad_x, pad_y)
    return (
        max(0, bbox[0] - pad),
        max(0, bbox[1] - pad),
        min(width, bbox[2] + pad),
        min(height, bbox[3] + pad),
    )


def _top_objects(
    objects: tuple[DetectedObject, ...], scaling: np.ndarray, size_px: tuple[int, int]
) -> tuple[DetectedObject, ...]:
    """Each object's top (`_top_mask` of its mask); an object with none is left out."""
    tops = []
    for item in objects:
        top = _top_mask(item.mask, scaling, size_px)
        if top is None:
            continue
        box, outline = _box_and_contour(top)
        tops.append(DetectedObject(item.id, box, outline, float(top.sum()), top))
    return tuple(tops)


def _box_and_contour(mask: np.ndarray) -> tuple[tuple[int, int, int, int], np.ndarray]:
    import cv2

    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    largest = max(contours, key=cv2.contourArea)
    x, y, w, h = cv2.boundingRect(largest)
    return (x, y, x + w, y + h), largest.reshape(-1, 2).astype(float)
