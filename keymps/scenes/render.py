"""Synthetic top-down scenes: a wooden cutting board with food on it, and the true geometry.

Every scene is a pure function of its SceneSpec (object kinds, sizes, seed, board, resolution):
the same spec renders the same pixels. The image spans the board exactly (Appendix B), so board
metres map to pixels with keymps.perception.frames.ImageFrame.linear. The JSON sidecar written next to
the PNG holds, per object, its centre, dimensions, rotation, outline (metres and pixels) and the
box of the pixels at least half covered by the object. The kinds of object and their footprints
are in keymps.scenes.objects, their colours in keymps.scenes.textures.
"""

from __future__ import annotations

import functools
import json
import pickle
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from keymps.errors import KeympsError
from keymps.scenes.objects import (
    KINDS,
    ObjectKind,
    ObjectSpec,
    Shape,
    body_ends_local,
    canonical_kind,
    check_kinds,
    outline_local,
    to_board_frame,
)
from keymps.scenes.textures import (
    PAINTERS,
    Paint,
    board_texture,
    coloured,
    lighting,
    sensor_noise,
)

__all__ = [
    "KINDS",
    "ObjectKind",
    "ObjectSpec",
    "RenderedScene",
    "SceneSpec",
    "Shape",
    "canonical_kind",
    "check_kinds",
    "render_scene",
]

SIDECAR_SCHEMA_VERSION = 1
MARGIN_M = 0.004
"""Objects keep at least this distance from the board's edges."""
RENDER_CACHE_SIZE = 16
"""Scenes render_scene_cached remembers (about 0.7 MB each at the default resolution)."""


@dataclass(frozen=True)
class SceneSpec:
    objects: tuple[ObjectSpec, ...]
    seed: int = 0
    board_size: tuple[float, float] = (0.30, 0.18)
    px_per_m: float = 2000.0

    @classmethod
    def from_kinds(
        cls,
        kinds: Sequence[str],
        *,
        seed: int = 0,
        length: float | None = None,
        width: float | None = None,
        height: float | None = None,
        rotation: float | None = None,
        board_size: tuple[float, float] | Sequence[float] = (0.30, 0.18),
        px_per_m: float = 2000.0,
    ) -> SceneSpec:
        """Objects of these kinds; sizes not given are the kind's defaults varied by the seed."""
        rng = np.random.default_rng([seed, 7])
        objects = []
        for name in check_kinds(kinds):
            kind = KINDS[name]
            jitter = rng.uniform(0.96, 1.04, size=3)
            obj_length = length if length is not None else kind.length * jitter[0]
            if kind.round:
                obj_width = width if width is not None else obj_length
            else:
                obj_width = width if width is not None else kind.width * jitter[1]
            obj_height = height if height is not None else kind.height * jitter[2]
            if rotation is not None:
                angle = rotation
            elif kind.round:
                angle = rng.uniform(0, 360)
            else:
                angle = rng.uniform(-3.0, 3.0)
            objects.append(
                ObjectSpec(name, float(obj_length), float(obj_width), float(obj_height), angle)
            )
        w, h = (float(v) for v in board_size)
        return cls(tuple(objects), int(seed), (w, h), float(px_per_m))

    @property
    def image_size_px(self) -> tuple[int, int]:
        return (
            int(round(self.board_size[0] * self.px_per_m)),
            int(round(self.board_size[1] * self.px_per_m)),
        )


@dataclass(frozen=True)
class RenderedScene:
    image: np.ndarray
    """BGR uint8."""
    truth: dict[str, Any] = field(default_factory=dict)
    """The sidecar: true geometry of every object (see module docstring)."""

    def save(self, path: str | Path) -> tuple[Path, Path]:
        """Write the PNG and its JSON sidecar (same name, .json); return both paths."""
        import cv2

        png = Path(path)
        if png.suffix.lower() != ".png":
            raise KeympsError(f"scene images are written as PNG: {png} does not end in .png")
        png.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(png), self.image):
            raise KeympsError(f"cannot write {png}")
        sidecar = png.with_suffix(".json")
        sidecar.write_text(sidecar_json(self.truth), encoding="utf-8")
        return png, sidecar


def sidecar_json(truth: dict[str, Any]) -> str:
    """Indented JSON with every list of numbers (or of number pairs) on one line."""
    text = json.dumps(truth, indent=1)
    number_list = re.compile(r"\[[\s\d.,eE+-]*\]")
    text = number_list.sub(
        lambda m: "[" + ", ".join(m.group(0)[1:-1].split()).replace(",,", ",") + "]", text
    )
    pairs = re.compile(r"\[\s*((?:\[[^\[\]]*\],?\s*)+)\]")
    return pairs.sub(lambda m: "[" + " ".join(m.group(1).split()) + "]", text) + "\n"


def _place(spec: SceneSpec, rng: np.random.Generator) -> list[tuple[float, float]]:
    """Centres: given ones kept; others centred (one) or left to right (several)."""
    board_w, board_h = spec.board_size
    footprints = []
    for obj in spec.objects:
        outline, _ = outline_local(obj, np.random.default_rng(0))
        rotated = to_board_frame(outline, obj, (0.0, 0.0))
        footprints.append((rotated.min(axis=0), rotated.max(axis=0)))
    free = [i for i, obj in enumerate(spec.objects) if obj.centre is None]
    centres: list[tuple[float, float]] = [obj.centre or (0.0, 0.0) for obj in spec.objects]
    widths = [footprints[i][1][0] - footprints[i][0][0] for i in free]
    gap = (board_w - 2 * MARGIN_M - sum(widths)) / (len(free) + 1) if free else 0.0
    x = MARGIN_M + gap
    for i, width in zip(free, widths, strict=True):
        low, high = footprints[i]
        slack_x = max(0.0, min(gap, 0.01)) if len(free) > 1 else 0.0
        cx = x - low[0] + rng.uniform(-0.4, 0.4) * slack_x
        if len(free) == 1:
            cx = board_w / 2 - (low[0] + high[0]) / 2 + rng.uniform(-1, 1) * min(0.01, gap * 0.8)
        room_y = (board_h - 2 * MARGIN_M - (high[1] - low[1])) / 2
        cy = (
            board_h / 2
            - (low[1] + high[1]) / 2
            + rng.uniform(-1, 1) * min(0.01, max(room_y, 0) * 0.8)
        )
        centres[i] = (float(cx), float(cy))
        x += width + gap
    for obj, (low, high), centre in zip(spec.objects, footprints, centres, strict=True):
        lo, hi = np.asarray(centre) + low, np.asarray(centre) + high
        if lo[0] < 0 or lo[1] < 0 or hi[0] > board_w or hi[1] > board_h or gap < 0:
            raise KeympsError(
                f"the {obj.kind} ({obj.length:.3f} x {obj.width:.3f} m) does not fit on the "
                f"{board_w:g} x {board_h:g} m board; make the board larger (--board W,H)"
            )
    return centres


def pixel_coverage(
    polygon_px: np.ndarray, hole_px: np.ndarray | None, box: tuple[int, int, int, int]
) -> np.ndarray:
    """Fraction of each pixel of the box inside the polygon (4x4 supersampling).

    Args:
        polygon_px: (n, 2) the outline, image pixels.
        hole_px: (m, 2) a hole inside it, image pixels, or None.
        box: (x0, y0, x1, y1) the pixels to cover, x1 and y1 excluded.

    Returns:
        (y1 - y0, x1 - x0) floats from 0 to 1.
    """
    import cv2

    x0, y0, x1, y1 = box
    factor, bits = 4, 4
    canvas = np.zeros(((y1 - y0) * factor, (x1 - x0) * factor), np.uint8)

    def fixed(points: np.ndarray) -> np.ndarray:
        # Supersample s covers [s/f, (s+1)/f): its centre is at (s + 0.5)/f image pixels.
        scaled = (points - (x0, y0)) * factor - 0.5
        return np.round(scaled * (1 << bits)).astype(np.int32).reshape(-1, 1, 2)

    cv2.fillPoly(canvas, [fixed(polygon_px)], 255, lineType=cv2.LINE_8, shift=bits)
    if hole_px is not None:
        cv2.fillPoly(canvas, [fixed(hole_px)], 0, lineType=cv2.LINE_8, shift=bits)
    small = cv2.resize(canvas, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    return small.astype(np.float32) / 255.0


def half_covered_box(alpha: np.ndarray, origin: tuple[int, int]) -> list[int]:
    """[x0, y0, x1, y1] (exclusive) of the pixels at least half covered by the object."""
    rows, cols = np.nonzero(alpha >= 0.5)
    if len(rows) == 0:
        return [origin[0], origin[1], origin[0], origin[1]]
    x0, y0 = origin
    return [
        int(x0 + cols.min()),
        int(y0 + rows.min()),
        int(x0 + cols.max() + 1),
        int(y0 + rows.max() + 1),
    ]


def render_scene(spec: SceneSpec) -> RenderedScene:
    """The image and the true geometry of a scene; the same spec gives the same pixels."""
    import cv2

    from keymps._version import __version__
    from keymps.perception.frames import ImageFrame

    if not spec.objects:
        raise KeympsError("a scene needs at least one object")
    width, height = spec.image_size_px
    if not (32 <= width <= 8000 and 32 <= height <= 8000):
        raise KeympsError(
            f"scene image would be {width} x {height} px; choose --px-per-m so that both sides "
            "are between 32 and 8000 px"
        )
    rng = np.random.default_rng([spec.seed, 1])
    frame = ImageFrame.linear((width, height), spec.board_size)
    centres = _place(spec, rng)
    wood, wood_colour = board_texture((width, height), spec.px_per_m, rng)
    light = lighting((width, height), rng)
    image = coloured(wood * light, wood_colour)
    objects_truth = []
    for index, (obj, centre) in enumerate(zip(spec.objects, centres, strict=True)):
        object_rng = np.random.default_rng([spec.seed, 100 + index])
        footprint, hole_local = outline_local(obj, object_rng)
        outline_m = to_board_frame(footprint, obj, centre)
        hole_m = to_board_frame(hole_local, obj, centre) if hole_local is not None else None
        outline_px = frame.to_pixels(outline_m)
        hole_px = frame.to_pixels(hole_m) if hole_m is not None else None
        bx0, by0 = np.floor(outline_px.min(axis=0)).astype(int) - 1
        bx1, by1 = np.ceil(outline_px.max(axis=0)).astype(int) + 1
        box = (max(bx0, 0), max(by0, 0), min(bx1, width), min(by1, height))
        alpha = pixel_coverage(outline_px, hole_px, box)
        u, v = _local_coordinates(frame, box, centre, obj.rotation_deg)
        colour = PAINTERS[obj.kind](
            Paint(u, v, obj, object_rng, spec.px_per_m, KINDS[obj.kind].shape)
        )
        colour *= light[box[1] : box[3], box[0] : box[2], None]
        region = image[box[1] : box[3], box[0] : box[2]]
        image[box[1] : box[3], box[0] : box[2]] = (
            region * (1 - alpha[..., None]) + colour * alpha[..., None]
        )
        objects_truth.append(
            _object_truth(obj, centre, outline_m, hole_m, outline_px, index)
            | {"bbox_px": half_covered_box(alpha, (box[0], box[1]))}
        )
    # rounded to the nearest (ties to even) and saturated, as np.clip(np.rint(...)), in one pass
    pixels = cv2.add(image, sensor_noise((width, height), rng), dtype=cv2.CV_8U)
    truth = {
        "schema_version": SIDECAR_SCHEMA_VERSION,
        "generator": f"keymps {__version__} keymps.scenes.render",
        "seed": spec.seed,
        "board_size_m": list(spec.board_size),
        "image_size_px": [width, height],
        "px_per_m": [width / spec.board_size[0], height / spec.board_size[1]],
        "frame": "board metres: origin bottom-left of the image, x right, y up; pixels: x right, y down",
        "objects": objects_truth,
    }
    return RenderedScene(pixels, truth)


def render_scene_cached(spec: SceneSpec) -> RenderedScene:
    """render_scene(spec), remembered for the last RENDER_CACHE_SIZE specs (a private copy).

    Rendering costs about 15 ms of CPU (600 x 360 px); `keymps eval` renders the same scene for
    every method it compares and again for the ground truth.
    """
    image, truth = _render_remembered(spec)
    return RenderedScene(image.copy(), pickle.loads(truth))


@functools.lru_cache(maxsize=RENDER_CACHE_SIZE)
def _render_remembered(spec: SceneSpec) -> tuple[np.ndarray, bytes]:
    # the sidecar kept pickled: unpickling is a private copy ten times faster than deepcopy
    scene = render_scene(spec)
    return scene.image, pickle.dumps(scene.truth, protocol=pickle.HIGHEST_PROTOCOL)


def _local_coordinates(
    frame: Any, box: tuple[int, int, int, int], centre: tuple[float, float], rotation_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Object coordinates (u along its length, v across, metres) of the box's pixel centres.

    The frame is linear (Appendix B), so they are affine in the pixel indices: three points
    give the map, and two broadcast sums fill the box (instead of mapping every pixel)."""
    x0, y0, x1, y1 = box
    corner = np.array([[x0, y0], [x0 + 1, y0], [x0, y0 + 1]], dtype=float) + 0.5
    local = (frame.to_board(corner) - np.asarray(centre)) @ _rotation(rotation_deg)
    step_x, step_y = local[1] - local[0], local[2] - local[0]
    i = np.arange(x1 - x0, dtype=float)[None, :]
    j = np.arange(y1 - y0, dtype=float)[:, None]
    u = (local[0, 0] + step_x[0] * i + step_y[0] * j).astype(np.float32)
    v = (local[0, 1] + step_x[1] * i + step_y[1] * j).astype(np.float32)
    return u, v


def _rotation(degrees: float) -> np.ndarray:
    angle = np.radians(degrees)
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def _object_truth(
    obj: ObjectSpec,
    centre: tuple[float, float],
    outline_m: np.ndarray,
    hole_m: np.ndarray | None,
    outline_px: np.ndarray,
    index: int,
) -> dict[str, Any]:
    from keymps.perception.frames import polygon_area

    return {
        "index": index,
        "kind": obj.kind,
        "description": KINDS[obj.kind].description,
        "centre_m": [round(c, 6) for c in centre],
        "length_m": round(obj.length, 6),
        "width_m": round(obj.width, 6),
        "height_m": round(obj.height, 6),
        "rotation_deg": round(obj.rotation_deg, 4),
        "area_m2": round(
            abs(polygon_area(outline_m))
            - (abs(polygon_area(hole_m)) if hole_m is not None else 0.0),
            8,
        ),
        "bbox_m": [round(float(v), 6) for v in (*outline_m.min(axis=0), *outline_m.max(axis=0))],
        "outline_m": np.round(outline_m, 6).tolist(),
        "hole_m": np.round(hole_m, 6).tolist() if hole_m is not None else None,
        "outline_px": np.round(outline_px, 3).tolist(),
    } | _body_truth(obj, centre)


def _body_truth(obj: ObjectSpec, centre: tuple[float, float]) -> dict[str, Any]:
    """{'body_m': [[x, y], [x, y]]}: where the body a cook slices begins and ends on the centre
    line (board metres), for kinds with a cap or stem beyond it; else nothing."""
    ends = body_ends_local(obj)
    if ends is None:
        return {}
    return {"body_m": np.round(to_board_frame(ends, obj, centre), 6).tolist()}
