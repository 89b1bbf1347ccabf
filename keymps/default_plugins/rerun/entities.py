"""How each stage's images, geometry and motion become Rerun entities (docs/rerun.md).

Every function takes the run's own RecordingStream; rerun and cv2 are imported inside. The
text documents (VLM exchange, reports, summary) are in keymps.default_plugins.rerun.text.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from keymps.run import Run
    from keymps.types import (
        Detection,
        Grounding,
        Plan,
        SceneImage,
    )


# ---------------------------------------------------------------- colours and images


def time_colors(fractions: np.ndarray, alpha: int = 255) -> np.ndarray:
    """RGBA colours red -> green -> blue for fractions 0 -> 0.5 -> 1 (the paper's convention)."""
    s = np.clip(np.asarray(fractions, dtype=float), 0.0, 1.0)
    first = s < 0.5
    u = np.where(first, s * 2.0, s * 2.0 - 1.0)
    red = np.where(first, 1.0 - u, 0.0)
    green = np.where(first, u, 1.0 - u)
    blue = np.where(first, 0.0, u)
    rgb = np.stack([red, green, blue], axis=-1) * 255.0
    alphas = np.full((len(s), 1), float(alpha))
    return np.round(np.concatenate([rgb, alphas], axis=1)).astype(np.uint8)


def _order_colors(count: int) -> np.ndarray:
    return time_colors(np.linspace(0.0, 1.0, count) if count > 1 else np.zeros(count))


def _encoded_image(rr: Any, image: np.ndarray) -> Any:
    """JPEG-encode a BGR (or grey) image: a tenth of the raw size, good enough to inspect."""
    import cv2

    ok, buffer = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 92])
    if not ok:
        return rr.Image(image, color_model="BGR" if image.ndim == 3 else "L")
    return rr.EncodedImage(contents=buffer.tobytes(), media_type="image/jpeg")


# ---------------------------------------------------------------- geometry helpers


def _image_frame(run: Run) -> Any | None:
    """keymps.perception.frames.ImageFrame for this run's image, or None when unavailable."""
    scene = run.stages.image
    if scene is None:
        return None
    try:
        from keymps.perception.frames import ImageFrame
    except ImportError:
        return None
    try:
        return ImageFrame.for_scene(run.task, scene)
    except Exception:  # a recorder must never stop the run over a drawing
        return None


def board_rectangle(run: Run) -> tuple[np.ndarray, np.ndarray]:
    """(min_xy, max_xy) of the workspace in the board frame, metres (s_env shifted by g_shift)."""
    workspace = run.task.scene.workspace
    low = np.array(workspace.shift, dtype=float)
    return low, low + np.array(workspace.size, dtype=float)


# ---------------------------------------------------------------- stage loggers


def log_world_setup(rec: Any) -> None:
    """Static facts: the board frame is right-handed, z up."""
    import rerun as rr

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)


TEXTURE_MAX_PX = 512
"""The scene image is laid on the 3D board as a texture at most this many pixels a side."""


def log_image(rec: Any, scene: SceneImage, run: Run) -> None:
    import rerun as rr

    rec.log("image", _encoded_image(rr, scene.image))
    _log_board(rec, run)
    _log_board_texture(rec, scene, run)


def _log_board_texture(rec: Any, scene: SceneImage, run: Run) -> None:
    """The scene image rectified onto the workspace: exact for the linear model and the
    calibrated homography alike (the image is warped with the same pixel -> board map)."""
    import cv2
    import rerun as rr

    frame = _image_frame(run)
    if frame is None:
        return
    low, high = board_rectangle(run)
    width_m, height_m = high - low
    if width_m >= height_m:
        size = (TEXTURE_MAX_PX, max(1, round(TEXTURE_MAX_PX * height_m / width_m)))
    else:
        size = (max(1, round(TEXTURE_MAX_PX * width_m / height_m)), TEXTURE_MAX_PX)
    board_to_texture = np.array(
        [
            [size[0] / width_m, 0.0, -low[0] * size[0] / width_m],
            [0.0, -size[1] / height_m, high[1] * size[1] / height_m],
            [0.0, 0.0, 1.0],
        ]
    )
    pixels_to_texture = board_to_texture @ np.asarray(frame.matrix, dtype=float)
    texture = cv2.warpPerspective(scene.image, pixels_to_texture, size, flags=cv2.INTER_AREA)
    conversion = cv2.COLOR_BGR2RGB if texture.ndim == 3 else cv2.COLOR_GRAY2RGB
    rgb = np.ascontiguousarray(cv2.cvtColor(texture, conversion), dtype=np.uint8)
    corners = [[low[0], high[1]], [high[0], high[1]], [high[0], low[1]], [low[0], low[1]]]
    rec.log(
        "world/board/image",
        rr.Mesh3D(
            vertex_positions=np.column_stack([corners, np.full(4, 0.0005)]),
            triangle_indices=[[0, 1, 2], [0, 2, 3]],
            vertex_texcoords=[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            albedo_texture=rgb,
        ),
    )


def _log_board(rec: Any, run: Run) -> None:
    import rerun as rr

    low, high = board_rectangle(run)
    thickness = 0.01
    center = [(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, -thickness / 2]
    half = [(high[0] - low[0]) / 2, (high[1] - low[1]) / 2, thickness / 2]
    rec.log(
        "world/board",
        rr.Boxes3D(
            centers=[center],
            half_sizes=[half],
            colors=[[205, 170, 125, 255]],
            fill_mode=rr.components.FillMode.Solid,
        ),
    )


def log_detection(rec: Any, detection: Detection, run: Run) -> None:
    import rerun as rr

    x0, y0, x1, y1 = detection.bbox_px
    rec.log(
        "image/detection",
        rr.Boxes2D(
            array=[[x0, y0, x1, y1]],
            array_format=rr.Box2DFormat.XYXY,
            labels=["object"],
            colors=[[255, 200, 0, 255]],
        ),
    )
    if detection.others_px:
        rec.log(
            "image/detection/others",
            rr.Boxes2D(
                array=np.array(detection.others_px, dtype=float),
                array_format=rr.Box2DFormat.XYXY,
                colors=[[160, 160, 160, 255]] * len(detection.others_px),
            ),
        )
    if len(detection.contour_px):
        contour = np.asarray(detection.contour_px, dtype=float).reshape(-1, 2)
        rec.log(
            "image/detection/contour",
            rr.LineStrips2D([np.vstack([contour, contour[:1]])], colors=[[255, 200, 0, 255]]),
        )
    rec.log("crop", _encoded_image(rr, detection.crop))
    _log_object(rec, detection, run)


def _log_object(rec: Any, detection: Detection, run: Run) -> None:
    import rerun as rr

    frame = _image_frame(run)
    scene = run.stages.image
    if frame is None or scene is None:
        return
    x0, y0, x1, y1 = detection.bbox_px
    corners = np.asarray(
        frame.to_board(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)),
        dtype=float,
    )
    low, high = corners.min(axis=0), corners.max(axis=0)
    height = float(run.task.scene.object_height)
    rec.log(
        "world/object",
        rr.Boxes3D(
            centers=[[(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, height / 2]],
            half_sizes=[[(high[0] - low[0]) / 2, (high[1] - low[1]) / 2, height / 2]],
            colors=[[255, 200, 0, 255]],
            labels=["object"],
        ),
    )
    if len(run.objects) > 1:
        _log_objects(rec, run)
    outline = _outline_m(run, detection, scene)
    if outline is None:  # outline is a nicety; the box above already shows the object
        return
    if len(outline) >= 2:
        ring = np.vstack([outline, outline[:1]])
        top = np.column_stack([ring, np.full(len(ring), height)])
        rec.log(
            "world/object/outline",
            rr.LineStrips3D([top], colors=[[255, 140, 0, 255]], radii=[0.001]),
        )


def _log_objects(rec: Any, run: Run) -> None:
    """Several objects: one entity each, world/objects/<id>, its footprint at its own height."""
    import rerun as rr

    for obj in run.objects:
        outline = np.asarray(obj.outline_m, dtype=float)
        if len(outline) < 2:
            continue
        ring = np.vstack([outline, outline[:1]])
        top = np.column_stack([ring, np.full(len(ring), obj.height)])
        rec.log(
            f"world/objects/{obj.id}",
            rr.LineStrips3D([top], colors=[[255, 140, 0, 255]], radii=[0.001], labels=[obj.label]),
        )


def log_plan(rec: Any, plan: Plan, run: Run) -> None:
    import rerun as rr

    count = plan.num_pairs
    labels = [str(i + 1) for i in range(count)]
    colors = _order_colors(count)
    pairs = np.asarray(plan.pairs_px, dtype=float).reshape(-1, 2, 2)
    rec.log(
        "image/pairs",
        rr.LineStrips2D(list(pairs), labels=labels, colors=colors, radii=[-2.0]),
    )
    # Order numbers on the strips and again at the start dots: radial cuts share their middle,
    # so only the start labels stay readable there. Big start and small end dots give direction.
    rec.log(
        "image/pairs/start",
        rr.Points2D(pairs[:, 0], colors=colors, radii=[-5.0], labels=labels),
    )
    rec.log("image/pairs/end", rr.Points2D(pairs[:, 1], colors=colors, radii=[-3.0]))
    crop_pairs = np.asarray(plan.pairs_crop_px, dtype=float).reshape(-1, 2, 2)
    rec.log("crop/pairs", rr.LineStrips2D(list(crop_pairs), labels=labels, colors=colors))


def log_grounding(rec: Any, grounding: Grounding) -> None:
    import rerun as rr

    segments = grounding.segments_m
    count = len(segments)
    labels = [str(i + 1) for i in range(count)]
    colors = _order_colors(count)
    rec.log(
        "world/segments",
        rr.Arrows3D(
            origins=segments[:, 0],
            vectors=segments[:, 1] - segments[:, 0],
            labels=labels,
            colors=colors,
            radii=[0.001],
        ),
    )
    rec.log("world/segments/start", rr.Points3D(segments[:, 0], colors=colors, radii=[0.003]))
    rec.log("world/segments/end", rr.Points3D(segments[:, 1], colors=colors, radii=[0.002]))


VIDEO_FRAMES_MAX = 1200
"""An executor's video is logged frame by frame up to this many frames (then every k-th)."""


def log_execution_video(rec: Any, files: tuple[str, ...], run: Run) -> None:
    """Frames of an executor's video (an .mp4 it wrote, e.g. the mujoco executor's), as an
    image stream on the `time` timeline at the video's own frame rate."""
    import cv2
    import rerun as rr

    for name in files:
        if not name.endswith(".mp4"):
            continue
        video = cv2.VideoCapture(name)
        try:
            fps = float(video.get(cv2.CAP_PROP_FPS)) or 10.0
            count = int(video.get(cv2.CAP_PROP_FRAME_COUNT))
            every = max(1, -(-count // VIDEO_FRAMES_MAX))
            index = 0
            while True:
                ok, frame = video.read()
                if not ok:
                    break
                if index % every == 0:
                    rec.set_time("time", duration=index / fps)
                    rec.log("execution/video", _encoded_image(rr, frame))
                index += 1
        finally:
            video.release()
            rec.set_time("time", duration=0.0)


def log_outcome(rec: Any, run: Run) -> None:
    """The executor's outcome image (the simulated result), when it wrote one."""
    import cv2
    import rerun as rr

    outcome = run.image_path("outcome")
    if not outcome.is_file():
        return
    image = cv2.imread(str(outcome), cv2.IMREAD_COLOR)
    if image is not None:
        rec.log("outcome", _encoded_image(rr, image))


def _outline_m(run: Run, detection: Detection, scene: SceneImage) -> np.ndarray | None:
    """The object's footprint in board metres: the engine's, or computed for a hand-made Run."""
    if run.outline_m is not None:
        return np.asarray(run.outline_m, dtype=float)
    from keymps.perception.frames import object_outline_m

    try:
        return np.asarray(object_outline_m(detection, run.task, scene), dtype=float)
    except Exception:
        return None
