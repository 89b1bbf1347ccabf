"""What the tool leaves on the food: cut lines and icing, painted into the tops' texture.

The texture spans the workspace exactly as the task's image does, so a board point maps to a
texture pixel with the same linear frame. A knife darkens the segment its edge covers while the
edge is below an object's top, inside that object's footprint; a nozzle deposits icing (a
painted disc plus a small sphere drawn in 3D) where it moves close above a surface.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

CUT_RGB = (25, 22, 20)
ICING_RGB = (250, 250, 247)
ICING_EDGE_RGB = (150, 150, 150)
DEPOSIT_STEP_M = 0.0015
"""A new icing deposit each time the nozzle has moved this far."""
LENGTH_BIN_M = 0.0005
"""Resolution of the measured cut lengths."""
MAX_SPHERES = 2500
"""Icing spheres drawn in 3D at most (the painted icing has no limit)."""


@dataclass
class Painter:
    """Paints marks into an RGB texture spanning the workspace (row 0 at the board's top)."""

    base_rgb: np.ndarray
    size_m: tuple[float, float]
    shift_m: tuple[float, float]
    footprints: list[np.ndarray]
    """Per object, a boolean mask over the texture."""
    cut_width_m: float = 0.0015
    icing_radius_m: float = 0.003
    cut_mask: np.ndarray = field(init=False)
    icing_mask: np.ndarray = field(init=False)
    spheres: list[tuple[float, float, float]] = field(default_factory=list)
    cut_bins: dict[int, set[int]] = field(default_factory=dict)
    """Per cut, the LENGTH_BIN_M bins along its line that the edge covered inside the food."""
    changed: bool = False
    _last_deposit: np.ndarray | None = None

    def __post_init__(self) -> None:
        height, width = self.base_rgb.shape[:2]
        self.cut_mask = np.zeros((height, width), np.uint8)
        self.icing_mask = np.zeros((height, width), np.uint8)

    @property
    def px_per_m(self) -> float:
        return self.base_rgb.shape[1] / self.size_m[0]

    def pixels(self, xy: np.ndarray) -> np.ndarray:
        """Board metres (n, 2) -> texture pixels (n, 2), 1/16 px fixed point for OpenCV."""
        points = np.asarray(xy, dtype=float).reshape(-1, 2)
        height = self.base_rgb.shape[0]
        u = (points[:, 0] - self.shift_m[0]) * self.px_per_m
        v = height - (points[:, 1] - self.shift_m[1]) * self.px_per_m
        return np.round(np.column_stack([u, v]) * 16).astype(np.int32)

    def cut(
        self,
        tip_xy: np.ndarray,
        far_xy: np.ndarray,
        cut: int,
        origin: np.ndarray,
        axis: np.ndarray | None = None,
    ) -> None:
        """The knife's edge from its tip to its far end is in the food: mark the segment, and
        count the length it covers inside a footprint along cut `cut`'s line (from `origin`,
        along `axis` (2,), a unit vector; the edge's own direction when None). Cuts measured
        on the same origin and axis add up in `cut_length_m`."""
        import cv2

        a, b = self.pixels(np.array([tip_xy, far_xy]))
        width = max(1, round(self.cut_width_m * self.px_per_m))
        cv2.line(self.cut_mask, tuple(map(int, a)), tuple(map(int, b)), 255, width, cv2.LINE_AA, 4)
        self.changed = True
        edge = np.asarray(far_xy, dtype=float) - np.asarray(tip_xy, dtype=float)
        length = float(np.linalg.norm(edge))
        if length < 1e-9:
            return
        steps = np.arange(0.0, length + 1e-12, LENGTH_BIN_M / 2)
        points = np.asarray(tip_xy, dtype=float) + steps[:, None] * (edge / length)
        inside = self._inside(points)
        along = (points[inside] - origin) @ (edge / length if axis is None else axis)
        self.cut_bins.setdefault(cut, set()).update(np.floor(along / LENGTH_BIN_M).astype(int))

    def _inside(self, xy: np.ndarray) -> np.ndarray:
        """Whether each board point lies in an object's footprint."""
        height, width = self.cut_mask.shape
        u = ((xy[:, 0] - self.shift_m[0]) * self.px_per_m).astype(int)
        v = (height - (xy[:, 1] - self.shift_m[1]) * self.px_per_m).astype(int)
        ok = (u >= 0) & (u < width) & (v >= 0) & (v < height)
        inside = np.zeros(len(xy), bool)
        for mask in self.footprints:
            inside[ok] |= mask[v[ok], u[ok]]
        return inside

    def cut_length_m(self, *cuts: int) -> float:
        """How long a stretch of the cuts' line the edge covered inside the food (several cuts:
        the strokes of one line, measured on one origin and axis, together)."""
        covered: set[int] = set().union(*(self.cut_bins.get(cut, set()) for cut in cuts))
        return len(covered) * LENGTH_BIN_M

    def deposit(self, xyz: np.ndarray) -> bool:
        """The nozzle is at xyz just above a surface: icing there (once per DEPOSIT_STEP_M)."""
        import cv2

        point = np.asarray(xyz, dtype=float)
        if (
            self._last_deposit is not None
            and np.linalg.norm(point[:2] - self._last_deposit[:2]) < DEPOSIT_STEP_M
        ):
            return False
        self._last_deposit = point
        centre = tuple(map(int, self.pixels(point[:2])[0]))
        radius = max(1, round(self.icing_radius_m * self.px_per_m * 16))
        cv2.circle(self.icing_mask, centre, radius, 255, -1, cv2.LINE_AA, 4)
        if len(self.spheres) < MAX_SPHERES:
            self.spheres.append((float(point[0]), float(point[1]), float(point[2])))
        self.changed = True
        return True

    def texture(self) -> np.ndarray:
        """The base image with the cuts (inside the footprints) and the icing on it."""
        image: np.ndarray = self.base_rgb.astype(np.float32)
        inside = np.zeros(self.cut_mask.shape, bool)
        for mask in self.footprints:
            inside |= mask
        cut = (self.cut_mask.astype(np.float32) / 255.0) * inside
        image = image * (1 - cut[..., None]) + np.array(CUT_RGB, np.float32) * cut[..., None]
        if self.icing_mask.any():
            import cv2

            edge = cv2.dilate(self.icing_mask, np.ones((3, 3), np.uint8)).astype(np.float32) / 255
            image = (
                image * (1 - edge[..., None])
                + np.array(ICING_EDGE_RGB, np.float32) * edge[..., None]
            )
            icing = self.icing_mask.astype(np.float32)[..., None] / 255.0
            image = image * (1 - icing) + np.array(ICING_RGB, np.float32) * icing
        self.changed = False
        return np.clip(np.round(image), 0, 255).astype(np.uint8)

    def cut_pixels(self) -> int:
        """Texture pixels darkened by cuts (inside the footprints)."""
        inside = np.zeros(self.cut_mask.shape, bool)
        for mask in self.footprints:
            inside |= mask
        return int(((self.cut_mask > 127) & inside).sum())


def add_spheres(scene: Any, spheres: list[tuple[float, float, float]], radius: float) -> None:
    """Draw the icing deposits as small white spheres (decoration geoms of an MjvScene)."""
    import mujoco

    identity = np.eye(3).ravel()
    size = np.array([radius, radius, radius])
    rgba = np.array([0.98, 0.98, 0.96, 1.0], np.float32)
    for point in spheres:
        if scene.ngeom >= scene.maxgeom:
            return
        mujoco.mjv_initGeom(
            scene.geoms[scene.ngeom],
            mujoco.mjtGeom.mjGEOM_SPHERE,
            size,
            np.array(point),
            identity,
            rgba,
        )
        scene.ngeom += 1
