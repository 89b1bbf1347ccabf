"""Scenes for the perception benchmark: what a kitchen varies, with the true answer.

`flat_case` draws one top-down board (Appendix B: the image spans it) with a random board
colour and texture, an object of random colour, texture, shape and coverage (5-60 % of the
board, sometimes near an edge), optionally a second smaller object, crumbs, a soft shadow,
a lighting gradient up to +-15 %, vignetting, sensor noise and JPEG compression; or an empty
board. `hue_only` objects have the board's lightness and differ in hue alone. The truth is the
box of the pixels at least half covered by the largest object (as the scene sidecar's bbox_px).

`photo_case` puts such a board (with an object of real height) in front of a pinhole camera
tilted 20-45 degrees from straight down: the board plane and every height of the object (its
sides, then its top) are drawn through their own homographies, with lens distortion, and with or
without four ArUco markers outside the board's corners (keymps.perception.markers).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from keymps.scenes.render import half_covered_box, pixel_coverage
from keymps.scenes.textures import smooth_noise

BOARD_M = (0.30, 0.18)
PHOTO_SIZE_PX = (960, 720)
MARKER_M = 0.04
"""Side of the ArUco markers outside the board's corners (the default printed size)."""
PX_PER_M = 2000.0
BOARDS: dict[str, tuple[float, float, float]] = {
    "light wood": (62.0, 6.0, 24.0),
    "dark wood": (42.0, 10.0, 22.0),
    "white plastic": (88.0, -1.0, 3.0),
    "green plastic": (55.0, -30.0, 18.0),
    "blue plastic": (50.0, 0.0, -32.0),
    "slate": (32.0, 0.0, -3.0),
    "bamboo": (70.0, 4.0, 30.0),
}
"""Board colours, CIE Lab."""


@dataclass(frozen=True)
class FlatScene:
    image: np.ndarray
    """BGR uint8, the board seen from straight above."""
    truth_bbox: tuple[int, int, int, int] | None
    """Box of the largest object (None: an empty board)."""
    board: np.ndarray
    """Float BGR 0-255 of the board alone (lighting and shadow applied), for photo_case."""
    object_alpha: np.ndarray | None
    """Coverage of the objects (0-1, H x W)."""
    object_colour: np.ndarray | None
    """Float BGR of the objects where they are."""
    variation: dict[str, Any] = field(default_factory=dict)


def lab_to_bgr(lab: np.ndarray) -> np.ndarray:
    """Float Lab (..., 3) -> float BGR 0-255."""
    import cv2

    from keymps.perception.board_model import lab_tables_ready

    lab_tables_ready()  # a board detector made before may be building OpenCV's Lab tables
    lab = np.asarray(lab, np.float32).reshape(-1, 1, 3)
    return np.clip(cv2.cvtColor(lab, cv2.COLOR_Lab2BGR).reshape(-1, 3) * 255.0, 0, 255)


def _object_lab(rng: np.random.Generator, board: np.ndarray, hue_only: bool) -> np.ndarray:
    if hue_only:
        chroma = rng.uniform(35, 55)
        angle = np.arctan2(board[2], board[1]) + rng.uniform(0.6 * np.pi, 1.4 * np.pi)
        lightness = np.clip(board[0] + rng.uniform(-3, 3), 35, 75)
        return np.array([lightness, chroma * np.cos(angle), chroma * np.sin(angle)])
    while True:
        colour = np.array([rng.uniform(15, 95), rng.uniform(-40, 60), rng.uniform(-40, 70)])
        if np.linalg.norm(colour - board) >= 25:
            return colour


def _outline(
    rng: np.random.Generator, area_px: float, room: tuple[float, float], round_only: bool = False
) -> tuple[np.ndarray, str, float]:
    """A closed polygon (N, 2) about the origin of about area_px pixels, fitting in room; its
    shape (ellipse, rounded, blob) and aspect ratio."""
    shape = "ellipse" if round_only else rng.choice(["ellipse", "rounded", "blob"])
    aspect = rng.uniform(1.0, 1.15 if round_only else 1.8)
    theta = np.linspace(0, 2 * np.pi, 240, endpoint=False)
    if shape == "rounded":
        power = rng.uniform(3, 6)
        c, s = np.cos(theta), np.sin(theta)
        unit = np.c_[np.sign(c) * np.abs(c) ** (2 / power), np.sign(s) * np.abs(s) ** (2 / power)]
    else:
        unit = np.c_[np.cos(theta), np.sin(theta)]
        if shape == "blob":
            wobble = np.zeros_like(theta)
            for k in range(2, 6):
                wobble += rng.normal(0, 0.05) * np.cos(k * theta + rng.uniform(0, 6.3))
            unit = unit * (1 + wobble)[:, None]
    unit = unit * np.array([aspect, 1.0])
    angle = rng.uniform(0, np.pi)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    unit = unit @ rotation.T
    x, y = unit.T
    unit_area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    polygon = unit * np.sqrt(area_px / unit_area)
    extent = polygon.max(axis=0) - polygon.min(axis=0)
    fit = min(1.0, room[0] / extent[0], room[1] / extent[1])
    return polygon * fit, str(shape), float(aspect)


def _texture(rng: np.random.Generator, shape: tuple[int, int], kind: str) -> np.ndarray:
    """A multiplicative texture (1 + t) of the given kind."""
    if kind == "plain":
        return np.ones(shape, np.float32)
    if kind == "grain":
        rows = np.arange(shape[0], dtype=np.float32)[:, None]
        warp = smooth_noise(shape, 60, rng)
        grain = np.sin(2 * np.pi * (rows / rng.uniform(10, 20) + 0.6 * warp))
        return (1 + rng.uniform(0.015, 0.04) * grain).astype(np.float32)
    if kind == "mottled":
        return (1 + rng.uniform(0.01, 0.03) * smooth_noise(shape, 25, rng)).astype(np.float32)
    return (1 + rng.uniform(0.01, 0.03) * smooth_noise(shape, 2, rng)).astype(np.float32)


def _place(
    rng: np.random.Generator, polygon: np.ndarray, size: tuple[int, int], near_edge: bool,
    keep_out: list[tuple[float, float, float, float]], gap: float,
) -> np.ndarray | None:  # fmt: skip
    width, height = size
    low, high = polygon.min(axis=0), polygon.max(axis=0)
    for _ in range(200):
        if near_edge:
            side = rng.integers(4)
            offset = rng.uniform(6, 14)
            cx = rng.uniform(gap - low[0], width - gap - high[0])
            cy = rng.uniform(gap - low[1], height - gap - high[1])
            if side == 0:
                cx = offset - low[0]
            elif side == 1:
                cx = width - offset - high[0]
            elif side == 2:
                cy = offset - low[1]
            else:
                cy = height - offset - high[1]
        else:
            cx = rng.uniform(gap - low[0], width - gap - high[0])
            cy = rng.uniform(gap - low[1], height - gap - high[1])
        box = (cx + low[0], cy + low[1], cx + high[0], cy + high[1])
        if box[0] < 5 or box[1] < 5 or box[2] > width - 5 or box[3] > height - 5:
            continue
        if all(
            box[2] + gap < k[0] or k[2] + gap < box[0] or box[3] + gap < k[1] or k[3] + gap < box[1]
            for k in keep_out
        ):
            return polygon + (cx, cy)
    return None


def _box(box: list[int]) -> tuple[float, float, float, float]:
    x0, y0, x1, y1 = (float(v) for v in box)
    return x0, y0, x1, y1


def _alpha(polygon_px: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, list[int]]:
    width, height = size
    alpha = np.zeros((height, width), np.float32)
    x0, y0 = np.maximum(np.floor(polygon_px.min(axis=0)).astype(int) - 1, 0)
    x1, y1 = np.ceil(polygon_px.max(axis=0)).astype(int) + 1
    x1, y1 = min(x1, width), min(y1, height)
    part = pixel_coverage(polygon_px, None, (x0, y0, x1, y1))
    alpha[y0:y1, x0:x1] = part
    return alpha, half_covered_box(part, (x0, y0))


@dataclass(frozen=True)
class _Objects:
    """What lies on a board: coverage (H, W) 0-1, colour (H, W, 3) float BGR where covered, the
    largest object's box and every object's box (px)."""

    alpha: np.ndarray
    colour: np.ndarray
    truth: tuple[int, int, int, int] | None
    boxes: list[tuple[float, float, float, float]]


def flat_case(
    seed: int,
    *,
    empty: bool = False,
    hue_only: bool = False,
    size_px: tuple[int, int] = (600, 360),
    coverage: float | None = None,
    jpeg: bool | None = None,
    finish: bool = True,
    round_cake: bool = False,
) -> FlatScene:
    """One random board, with its true box (see the module docstring). `round_cake`: one
    round object (aspect at most 1.15), nothing else on the board."""
    rng = np.random.default_rng([seed, 17])
    width, height = size_px
    board_lab, board, variation = _random_board(rng, size_px)
    objects = _Objects(
        np.zeros((height, width), np.float32), np.zeros((height, width, 3), np.float32), None, []
    )
    if not empty:
        share = coverage if coverage is not None else float(rng.uniform(0.05, 0.6))
        objects = _main_object(rng, board_lab, size_px, share, hue_only, round_cake, variation)
        if rng.random() < 0.3 and not round_cake:  # drawn first: each seed keeps its scene
            objects = _with_second_object(
                rng, objects, board_lab, size_px, share, hue_only, variation
            )
    if rng.random() < 0.35:
        board = _with_crumbs(rng, board, board_lab, objects.boxes, variation)
    if not empty and rng.random() < 0.4:
        board = _with_shadow(rng, board, objects.alpha, variation)
    image = board * (1 - objects.alpha[..., None]) + objects.colour * objects.alpha[..., None]
    light = _lighting(rng, size_px, variation)
    image = image * light[..., None]
    pixels = (
        _finish(rng, image, variation, jpeg)
        if finish
        else np.clip(np.rint(image), 0, 255).astype(np.uint8)
    )
    return FlatScene(
        pixels, objects.truth, board * light[..., None], None if empty else objects.alpha,
        None if empty else objects.colour * light[..., None], variation,
    )  # fmt: skip


def _random_board(
    rng: np.random.Generator, size_px: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """A board colour (Lab, one of BOARDS varied), the textured board (H, W, 3 float BGR 0-255)
    and the variation entries that name them."""
    width, height = size_px
    board_name = str(rng.choice(list(BOARDS)))
    board_lab = np.array(BOARDS[board_name]) + rng.normal(0, [4, 2, 3])
    texture_kind = str(rng.choice(["plain", "grain", "mottled", "speckle"]))
    board = (
        lab_to_bgr(board_lab)[0][None, None, :]
        * _texture(rng, (height, width), texture_kind)[..., None]
    )
    return board_lab, board, {"board": board_name, "board_texture": texture_kind}


def _main_object(
    rng: np.random.Generator, board_lab: np.ndarray, size_px: tuple[int, int], share: float,
    hue_only: bool, round_cake: bool, variation: dict[str, Any],
) -> _Objects:  # fmt: skip
    """The largest object: `share` of the board's area, 30 % of the time near an edge."""
    width, height = size_px
    near_edge = bool(rng.random() < 0.3)
    polygon, shape, aspect = _outline(
        rng, share * width * height, (width - 24, height - 24), round_cake
    )
    placed = _place(rng, polygon, size_px, near_edge, [], 6)
    if placed is None:
        placed = polygon - polygon.mean(axis=0) + (width / 2, height / 2)
    alpha, box = _alpha(placed, size_px)
    object_lab = _object_lab(rng, board_lab, hue_only)
    colour = _paint_object(rng, object_lab, (height, width), board_lab)
    variation |= {"coverage": round(float(alpha.sum()) / (width * height), 3),
                  "shape": shape, "aspect": round(aspect, 3),
                  "near_edge": near_edge, "hue_only": hue_only,
                  "object_lab": np.round(object_lab, 1).tolist()}  # fmt: skip
    return _Objects(alpha, colour, (box[0], box[1], box[2], box[3]), [_box(box)])


def _with_second_object(
    rng: np.random.Generator, objects: _Objects, board_lab: np.ndarray, size_px: tuple[int, int],
    share: float, hue_only: bool, variation: dict[str, Any],
) -> _Objects:  # fmt: skip
    """The objects and a second, 10-40 % the size of the first, clear of it (when one fits)."""
    width, height = size_px
    second, _, _ = _outline(
        rng, share * width * height * rng.uniform(0.1, 0.4), (width / 3, height / 2)
    )
    spot = _place(rng, second, size_px, False, objects.boxes, 14)
    if spot is None:
        return objects
    alpha, box = _alpha(spot, size_px)
    colour = _paint_object(rng, _object_lab(rng, board_lab, hue_only), (height, width), board_lab)
    variation["second_object"] = box
    return _Objects(
        np.maximum(objects.alpha, alpha),
        np.where(alpha[..., None] > 0, colour, objects.colour),
        objects.truth,
        [*objects.boxes, _box(box)],
    )


def _with_crumbs(
    rng: np.random.Generator, board: np.ndarray, board_lab: np.ndarray,
    boxes: list[tuple[float, float, float, float]], variation: dict[str, Any],
) -> np.ndarray:  # fmt: skip
    """The board with 5-30 crumbs (specks of a few pixels) away from the objects' boxes."""
    import cv2

    height, width = board.shape[:2]
    count = int(rng.integers(5, 30))
    crumb_colour = lab_to_bgr(_object_lab(rng, board_lab, False))[0]
    crumbs = np.zeros((height, width), np.uint8)
    for _ in range(count):
        x, y = rng.uniform(4, width - 4), rng.uniform(4, height - 4)
        if any(k[0] - 10 < x < k[2] + 10 and k[1] - 10 < y < k[3] + 10 for k in boxes):
            continue
        cv2.circle(crumbs, (int(x), int(y)), int(rng.integers(1, 4)), 255, -1, cv2.LINE_AA)
    weight = crumbs.astype(np.float32)[..., None] / 255.0
    variation["crumbs"] = count
    return board * (1 - weight) + crumb_colour * weight


def _with_shadow(
    rng: np.random.Generator, board: np.ndarray, alpha: np.ndarray, variation: dict[str, Any]
) -> np.ndarray:
    """The board darkened 15-35 % by the objects' coverage `alpha`, shifted 3-8 px and
    blurred."""
    import cv2

    height, width = alpha.shape
    shift = rng.uniform(3, 8) * np.array([np.cos(a := rng.uniform(0, 6.3)), np.sin(a)])
    moved = cv2.warpAffine(alpha, np.array([[1, 0, shift[0]], [0, 1, shift[1]]]), (width, height))
    sigma = rng.uniform(3, 6)
    soft = cv2.GaussianBlur(moved, (0, 0), sigma)
    darkness = rng.uniform(0.15, 0.35)
    variation["shadow"] = {"darkness": round(darkness, 2), "sigma_px": round(sigma, 1)}
    return board * (1 - darkness * soft)[..., None]


def _paint_object(
    rng: np.random.Generator, lab: np.ndarray, shape: tuple[int, int], board_lab: np.ndarray
) -> np.ndarray:
    kind = str(rng.choice(["plain", "mottled", "speckle", "spots"]))
    base = (
        lab_to_bgr(lab)[0][None, None, :]
        * _texture(rng, shape, "plain" if kind == "spots" else kind)[..., None]
    )
    if kind == "spots":  # toppings of a second colour, at least 15 from the board
        spots = (smooth_noise(shape, 8, rng) > 1.2).astype(np.float32)
        while True:
            second = lab + rng.normal(0, 12, 3)
            if np.linalg.norm(second - board_lab) > 15:
                break
        base = base * (1 - spots[..., None]) + lab_to_bgr(second)[0] * spots[..., None]
    return base.astype(np.float32)


def _lighting(
    rng: np.random.Generator, size: tuple[int, int], variation: dict[str, Any]
) -> np.ndarray:
    width, height = size
    x = np.linspace(-1, 1, width, dtype=np.float32)[None, :]
    y = np.linspace(-1, 1, height, dtype=np.float32)[:, None]
    gradient = float(rng.uniform(0, 0.15))
    angle = rng.uniform(0, 2 * np.pi)
    ramp = (np.cos(angle) * x + np.sin(angle) * y) / max(
        abs(np.cos(angle)) + abs(np.sin(angle)), 1e-6
    )
    vignette = float(rng.uniform(0, 0.25)) if rng.random() < 0.5 else 0.0
    variation |= {"gradient": round(gradient, 3), "vignetting": round(vignette, 3)}
    return ((1 + gradient * ramp) * (1 - vignette * (x * x + y * y) / 2)).astype(np.float32)


def _finish(
    rng: np.random.Generator, image: np.ndarray, variation: dict[str, Any], jpeg: bool | None
) -> np.ndarray:
    import cv2

    noisy = image + rng.normal(0, rng.uniform(1.0, 3.0), image.shape).astype(np.float32)
    pixels = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    if jpeg if jpeg is not None else rng.random() < 0.5:
        quality = int(rng.integers(60, 96))
        ok, data = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, quality])
        pixels = cv2.imdecode(data, cv2.IMREAD_COLOR)
        variation["jpeg_quality"] = quality
    return pixels


@dataclass(frozen=True)
class PhotoCase:
    """A board photographed at an angle, with what a calibration would give."""

    photo: np.ndarray
    """BGR uint8 as the camera saw it (distortion included)."""
    flat: FlatScene
    """The same board seen from straight above (board px = metres x PX_PER_M)."""
    corners_px: np.ndarray
    """(4, 2) true board corners in the photo, bottom-left first (continuous pixels)."""
    intrinsics: dict[str, Any]
    """fx, fy, cx, cy, distortion: what scene.camera.intrinsics would hold."""
    object_height: float
    tilt_deg: float
    markers: bool


def _look_at(
    target: np.ndarray, tilt: float, azimuth: float, distance: float
) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of a camera `distance` from target, tilted from straight down, near side at the
    bottom of its image."""
    back = np.array([np.sin(tilt) * np.sin(azimuth), -np.sin(tilt) * np.cos(azimuth), np.cos(tilt)])
    forward = -back
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.array([right, down, forward])
    centre = target + distance * back
    return rotation, -rotation @ centre


TABLE_MARGIN_M = 0.06
"""The table seen around the board on each side of a photo case, metres."""


@dataclass(frozen=True)
class _Camera:
    """A pinhole camera looking at the board: K, lens distortion (OpenCV's k1, k2, p1, p2, k3)
    and the board frame in the camera frame (x_cam = rotation @ x_board + translation)."""

    focal: float
    """Pixels, the same along x and y."""
    matrix: np.ndarray
    distortion: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    tilt_deg: float
    """The optical axis from straight down, degrees."""

    @property
    def centre(self) -> np.ndarray:
        """(3,) the camera's position in the board frame, metres."""
        return -self.rotation.T @ self.translation

    def plane_to_photo(self, z: float) -> np.ndarray:
        """(3, 3) board metres (x, y) on the plane at height z -> ideal photo pixel indices."""
        rotation = self.rotation
        return (
            self.matrix
            @ np.c_[rotation[:, 0], rotation[:, 1], self.translation + z * rotation[:, 2]]
        )


def photo_case(seed: int, *, markers: bool, flat_object: bool = False) -> PhotoCase:
    """A board with one object photographed from 20-45 degrees (see the module docstring)."""
    rng = np.random.default_rng([seed, 29])
    height_m = 0.0 if flat_object else float(rng.uniform(0.02, 0.06))
    camera = _random_camera(rng)
    flat = _photo_board(seed, camera.centre, height_m)
    canvas = _table_canvas(rng, flat.board)
    if markers:
        _paste_markers(rng, canvas, flat.board)
    photo = _photograph_board(camera, canvas)
    if flat.object_alpha is not None and flat.object_colour is not None:
        photo = _photograph_object(camera, flat.object_alpha, flat.object_colour, height_m, photo)
    variation = dict(flat.variation)
    pixels = _finish(rng, _through_lens(camera, photo), variation, None)
    intrinsics = {"fx": camera.focal, "fy": camera.focal,
                  "cx": float(camera.matrix[0, 2]), "cy": float(camera.matrix[1, 2]),
                  "distortion": [float(v) for v in camera.distortion]}  # fmt: skip
    return PhotoCase(
        pixels, replace(flat, variation=variation), _board_corners_in_photo(camera), intrinsics,
        height_m, camera.tilt_deg, markers,
    )  # fmt: skip


def _random_camera(rng: np.random.Generator) -> _Camera:
    """A camera 0.5-0.6 m from the board's centre, tilted 20-45 degrees from straight down and
    turned up to 20 degrees about the vertical; focal length 750-900 px, its principal point
    within 12 px of the centre of a PHOTO_SIZE_PX image, a mild radial distortion."""
    focal = float(rng.uniform(750, 900))
    matrix = np.array(
        [
            [focal, 0, 479.5 + rng.uniform(-12, 12)],
            [0, focal, 359.5 + rng.uniform(-12, 12)],
            [0, 0, 1],
        ]
    )
    distortion = np.array([rng.uniform(-0.12, 0.08), rng.uniform(-0.05, 0.05), 0, 0, 0])
    tilt = float(rng.uniform(20, 45))
    rotation, translation = _look_at(
        np.array([BOARD_M[0] / 2, BOARD_M[1] / 2, 0.0]), np.radians(tilt),
        np.radians(rng.uniform(-20, 20)), float(rng.uniform(0.5, 0.6)),
    )  # fmt: skip
    return _Camera(focal, matrix, distortion, rotation, translation, tilt)


def _table_canvas(rng: np.random.Generator, board: np.ndarray) -> np.ndarray:
    """The board (float BGR, PX_PER_M) on a dark mottled table TABLE_MARGIN_M wider each side."""
    canvas_px = (
        round((BOARD_M[0] + 2 * TABLE_MARGIN_M) * PX_PER_M),
        round((BOARD_M[1] + 2 * TABLE_MARGIN_M) * PX_PER_M),
    )
    table_lab = np.array([rng.uniform(20, 45), rng.uniform(-5, 10), rng.uniform(-10, 15)])
    canvas = np.broadcast_to(lab_to_bgr(table_lab)[0], (canvas_px[1], canvas_px[0], 3)).astype(
        np.float32
    )
    canvas = canvas * _texture(rng, (canvas_px[1], canvas_px[0]), "mottled")[..., None]
    off = round(TABLE_MARGIN_M * PX_PER_M)
    canvas[off : off + board.shape[0], off : off + board.shape[1]] = board
    return canvas


def _paste_markers(rng: np.random.Generator, canvas: np.ndarray, board: np.ndarray) -> None:
    """ArUco markers 0-3 (each turned at random) on white quiet zones outside the board's
    corners, bottom-left first, drawn into `canvas`."""
    from keymps.perception.markers import marker_image

    off = round(TABLE_MARGIN_M * PX_PER_M)
    side = round(MARKER_M * PX_PER_M)
    quiet = round(0.006 * PX_PER_M)
    bh, bw = board.shape[:2]
    corners = [(off, off + bh, -1, 1), (off + bw, off + bh, 1, 1), (off + bw, off, 1, -1),
               (off, off, -1, -1)]  # fmt: skip
    for marker_id, (cx, cy, sx, sy) in enumerate(corners):
        square = np.rot90(marker_image(marker_id, side), int(rng.integers(4))).astype(np.float32)
        x0 = cx if sx > 0 else cx - side
        y0 = cy if sy > 0 else cy - side
        canvas[max(y0 - quiet, 0) : y0 + side + quiet, max(x0 - quiet, 0) : x0 + side + quiet] = 235
        canvas[y0 : y0 + side, x0 : x0 + side] = square[..., None] * (235.0 / 255.0)
    # the board keeps its corners: the quiet zones stay on the table's side
    canvas[off : off + bh, off : off + bw] = board


def _index_to_continuous() -> np.ndarray:
    """OpenCV pixel indices -> continuous pixels (the first pixel's centre at 0.5)."""
    return np.linalg.inv(np.array([[1.0, 0, -0.5], [0, 1, -0.5], [0, 0, 1]]))


def _photograph_board(camera: _Camera, canvas: np.ndarray) -> np.ndarray:
    """The table canvas as the ideal (distortion-free) camera sees it, float BGR."""
    import cv2

    scale = 1.0 / PX_PER_M
    canvas_to_board = np.array(
        [[scale, 0, -TABLE_MARGIN_M], [0, -scale, BOARD_M[1] + TABLE_MARGIN_M], [0, 0, 1]]
    )
    to_photo = camera.plane_to_photo(0.0) @ canvas_to_board @ _index_to_continuous()
    return cv2.warpPerspective(canvas, to_photo, PHOTO_SIZE_PX, flags=cv2.INTER_AREA)


def _photograph_object(
    camera: _Camera, alpha: np.ndarray, colour: np.ndarray, height_m: float, photo: np.ndarray
) -> np.ndarray:
    """The photo with the object (coverage `alpha` and `colour` of the top-down board) over it:
    one slice per height from the board to the top, the sides shaded, the top last."""
    import cv2

    scale = 1.0 / PX_PER_M
    board_to_m = np.array([[scale, 0, 0], [0, -scale, BOARD_M[1]], [0, 0, 1]])
    # slices at most about 2 px apart in the photo, so that the sides show no gaps
    top_px = camera.focal * height_m * np.tan(np.radians(camera.tilt_deg)) / 0.5
    levels = np.linspace(0.0, height_m, max(2, int(np.ceil(top_px / 2.0)) + 1))
    for z in levels:
        warp = camera.plane_to_photo(float(z)) @ board_to_m @ _index_to_continuous()
        seen = cv2.warpPerspective(alpha, warp, PHOTO_SIZE_PX, flags=cv2.INTER_LINEAR)
        painted = cv2.warpPerspective(colour, warp, PHOTO_SIZE_PX, flags=cv2.INTER_LINEAR)
        shade = 1.0 if z == levels[-1] else 0.72
        photo = photo * (1 - seen[..., None]) + painted * shade * seen[..., None]
    return photo


def _through_lens(camera: _Camera, photo: np.ndarray) -> np.ndarray:
    """The ideal photo as the camera's lens distorts it (float32 BGR): each photo pixel shows
    the ideal pixel its ray would reach, found on a grid every 4 px and interpolated (the
    distortion is smooth)."""
    import cv2

    size, step = PHOTO_SIZE_PX, 4
    cols, rows = np.arange(0, size[0] + step, step), np.arange(0, size[1] + step, step)
    grid = np.stack(np.meshgrid(cols, rows), -1).reshape(-1, 1, 2).astype(np.float64)
    coarse = cv2.undistortPoints(grid, camera.matrix, camera.distortion, P=camera.matrix)
    fine = cv2.resize(
        coarse.reshape(len(rows), len(cols), 2).astype(np.float32),
        (len(cols) * step, len(rows) * step),
        interpolation=cv2.INTER_LINEAR,
    )
    shift = (step - 1) / 2  # resize aligns pixel centres: coarse sample k sits at k*step + shift
    fine = cv2.warpAffine(
        fine,
        np.array([[1, 0, -shift], [0, 1, -shift]]),
        fine.shape[1::-1],
        borderMode=cv2.BORDER_REPLICATE,
    )
    ideal = fine[: size[1], : size[0]]
    return cv2.remap(photo.astype(np.float32), ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR)


def _board_corners_in_photo(camera: _Camera) -> np.ndarray:
    """(4, 2) the board's corners in the photo (distortion included, continuous pixels),
    bottom-left first."""
    import cv2

    corners_m = np.array(
        [[0, 0], [BOARD_M[0], 0], [BOARD_M[0], BOARD_M[1]], [0, BOARD_M[1]]], float
    )
    projected, _ = cv2.projectPoints(
        np.c_[corners_m, np.zeros(4)], cv2.Rodrigues(camera.rotation)[0], camera.translation,
        camera.matrix, camera.distortion,
    )  # fmt: skip
    return projected.reshape(4, 2) + 0.5


def _photo_board(seed: int, camera: np.ndarray, height_m: float) -> FlatScene:
    """A top-down board with one round cake whose whole silhouette the camera sees on the board
    (its top, seen scaled by Cz / (Cz - h) about the camera's foot, stays 3 mm inside)."""
    grow = camera[2] / (camera[2] - height_m)
    for attempt in range(200):
        # a round cake: the offline planner's ring of dots is well defined on it
        coverage = float(np.random.default_rng([seed, attempt]).uniform(0.05, 0.3))
        scene = flat_case(
            seed * 1000 + attempt, coverage=coverage, jpeg=False, finish=False, round_cake=True
        )
        if scene.truth_bbox is None:
            continue
        x0, y0, x1, y1 = scene.truth_bbox
        box_m = (
            np.array([[x0, BOARD_M[1] * PX_PER_M - y1], [x1, BOARD_M[1] * PX_PER_M - y0]])
            / PX_PER_M
        )
        seen = camera[:2] + (box_m - camera[:2]) * grow
        if np.all(seen >= 0.003) and np.all(seen <= np.array(BOARD_M) - 0.003):
            return scene
    raise RuntimeError("no board fits")  # pragma: no cover
