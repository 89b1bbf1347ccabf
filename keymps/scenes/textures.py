"""Colours and textures of the synthetic scenes: the wooden board and each kind of food.

Every painter gets the local coordinates of the pixel centres of its object's box (u along the
object's length, v across it, metres) and returns BGR colours; keymps.scenes.render does the geometry.
The colours keep every object's outer edge at least 35 grey levels away from the board's ~126 so
that the Appendix A detector separates them (see docs/perception.md).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from keymps.scenes.objects import ObjectSpec, Shape


def centre_line(u: np.ndarray, length: float, bend: float) -> np.ndarray:
    """Sag of a long body's centre line (v), zero at both ends, bend * length in the middle."""
    return bend * length * (1.0 - (2.0 * u / length) ** 2)


def smooth_noise(shape: tuple[int, int], cell_px: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth random field of unit standard deviation; features about cell_px pixels wide."""
    import cv2

    height, width = shape
    grid_h = max(2, int(np.ceil(height / max(cell_px, 1.0))) + 2)
    grid_w = max(2, int(np.ceil(width / max(cell_px, 1.0))) + 2)
    coarse = rng.standard_normal((grid_h, grid_w)).astype(np.float32)
    field_ = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    return (field_ - field_.mean()) / max(float(field_.std()), 1e-6)


@dataclass
class Paint:
    """What a painter sees: local coordinates of the pixel centres of the object's box."""

    u: np.ndarray
    v: np.ndarray
    obj: ObjectSpec
    rng: np.random.Generator
    px_per_m: float
    shape: Shape

    def noise(self, cell_m: float) -> np.ndarray:
        return smooth_noise(self.u.shape, cell_m * self.px_per_m, self.rng)

    @property
    def radius(self) -> np.ndarray:
        """Normalized radius (1 at the edge of a disk)."""
        return np.hypot(self.u / (self.obj.length / 2), self.v / (self.obj.width / 2))

    @property
    def theta(self) -> np.ndarray:
        return np.arctan2(self.v, self.u)

    def along(self) -> tuple[np.ndarray, np.ndarray]:
        """(t in [0, 1] along the body, s in [-1, 1] across it) for profile bodies."""
        shape = self.shape
        t = np.clip(self.u / self.obj.length + 0.5, 0.0, 1.0)
        centre = centre_line(self.u, self.obj.length, shape.bend)
        half = self.obj.width / 2 * (shape.profile(t) if shape.profile else np.ones_like(t))
        return t, (self.v - centre) / np.maximum(half, 1e-6)


def _mix(base: np.ndarray, colour: Sequence[float], weight: np.ndarray) -> np.ndarray:
    weight = np.clip(weight, 0.0, 1.0)[..., None]
    return base * (1 - weight) + np.asarray(colour, dtype=np.float32) * weight


def _fill(p: Paint, colour: Sequence[float]) -> np.ndarray:
    return np.broadcast_to(np.asarray(colour, np.float32), (*p.u.shape, 3)).copy()


def _shade(image: np.ndarray, amount: np.ndarray) -> np.ndarray:
    return image * (1.0 + amount)[..., None]


def _spots(p: Paint, count: int, radius_m: float, within: float) -> np.ndarray:
    """Weights of `count` round spots (1 inside) scattered inside the normalized radius."""
    weight = np.zeros(p.u.shape, np.float32)
    for _ in range(count):
        angle, distance = p.rng.uniform(0, 2 * np.pi), within * np.sqrt(p.rng.uniform())
        cu = distance * np.cos(angle) * p.obj.length / 2
        cv = distance * np.sin(angle) * p.obj.width / 2
        size = radius_m * p.rng.uniform(0.8, 1.2)
        d = np.hypot(p.u - cu, p.v - cv)
        weight = np.maximum(weight, np.clip((size - d) * p.px_per_m + 0.5, 0, 1))
    return weight


def paint_round_cake(p: Paint) -> np.ndarray:
    r = p.radius
    image = _fill(p, (214, 234, 246))
    image = _mix(image, (160, 196, 222), (r - 0.84) / 0.1)  # the darker rim
    piping = 0.5 + 0.5 * np.cos(28 * p.theta)
    image = _mix(image, (190, 220, 240), piping * ((r > 0.9) & (r < 0.97)) * 0.6)
    return _shade(image, 0.03 * p.noise(0.02) - 0.04 * r**2)


def paint_square_cake(p: Paint) -> np.ndarray:
    edge = np.minimum(p.obj.length / 2 - np.abs(p.u), p.obj.width / 2 - np.abs(p.v))
    image = _fill(p, (42, 62, 98))
    image = _mix(image, (28, 42, 68), 1 - edge / 0.008)
    return _shade(image, 0.06 * p.noise(0.01) + 0.04 * p.noise(0.003))


def paint_round_pizza(p: Paint) -> np.ndarray:
    r = p.radius
    image = _fill(p, (48, 62, 188))  # tomato sauce
    cheese = p.noise(0.012) > -0.2
    image = _mix(image, (150, 214, 240), cheese * np.clip((0.84 - r) / 0.03, 0, 1))
    image = _mix(image, (44, 44, 150), _spots(p, 9, 0.011, 0.7))  # pepperoni
    basil = _spots(p, 5, 0.005, 0.72)
    image = _mix(image, (45, 110, 55), basil)
    crust = np.clip((r - 0.83) / 0.03, 0, 1)
    image = _mix(image, (122, 196, 236), crust)
    image = _mix(image, (108, 182, 225), crust * (p.noise(0.008) > 1.0))  # browned bubbles
    return _shade(image, 0.04 * p.noise(0.02))


def paint_cabbage(p: Paint) -> np.ndarray:
    r = p.radius
    image = _fill(p, (150, 222, 192))
    ring = np.abs(np.sin(9 * r + 0.8 * p.noise(0.03)))
    image = _mix(image, (118, 204, 166), (ring < 0.25) * 0.7)  # leaf folds
    veins = np.abs(np.sin(5 * p.theta + 1.5 * r + 0.3 * p.noise(0.04)))
    image = _mix(image, (205, 238, 228), (veins < 0.12) * np.clip(r * 1.5, 0, 1))
    image = _mix(image, (130, 215, 178), (r - 0.82) / 0.1)  # outer leaves
    return _shade(image, 0.04 * p.noise(0.015))


def paint_eggplant(p: Paint) -> np.ndarray:
    t, s = p.along()
    image = _fill(p, (78, 30, 66))
    image = _mix(image, (118, 64, 104), np.exp(-(((s - 0.35) / 0.18) ** 2)) * (t < 0.72))
    sepals = t > 0.73 + 0.05 * np.abs(np.cos(3 * np.pi * s))
    image = _mix(image, (36, 96, 46), sepals)
    image = _mix(image, (46, 86, 66), t > 0.9)  # stem
    return _shade(image, 0.05 * p.noise(0.02))


def paint_baguette(p: Paint) -> np.ndarray:
    t, s = p.along()
    image = _fill(p, (92, 176, 226))
    image = _mix(image, (95, 182, 232), np.abs(s) ** 3)
    slash = np.abs(np.sin(np.pi * (5 * t + 0.9 * s)))
    image = _mix(
        image, (152, 212, 236), (slash < 0.22) * (np.abs(s) < 0.55) * (t > 0.1) * (t < 0.9)
    )
    return _shade(image, 0.04 * p.noise(0.01))


def paint_banana_bread(p: Paint) -> np.ndarray:
    image = _fill(p, (36, 62, 108))
    crack = np.abs(p.v / (p.obj.width / 2) - 0.15 * p.noise(0.03))
    image = _mix(image, (26, 46, 82), (crack < 0.12) * (np.abs(p.u) < 0.4 * p.obj.length))
    return _shade(image, 0.05 * p.noise(0.008) + 0.03 * p.noise(0.03))


def paint_chiffon_cake(p: Paint) -> np.ndarray:
    r = p.radius
    image = _fill(p, (112, 190, 230))
    image = _mix(image, (115, 192, 230), (r - 0.85) / 0.1)
    cracks = np.abs(np.sin(7 * p.theta + 2 * p.noise(0.05)))
    image = _mix(image, (92, 172, 216), (cracks < 0.08) * (r > 0.4) * (r < 0.85))
    return _shade(image, 0.04 * p.noise(0.015))


def paint_baumkuchen(p: Paint) -> np.ndarray:
    r = p.radius
    layers = 0.5 + 0.5 * np.sin(2 * np.pi * r * 9 + 0.4 * p.noise(0.05))
    image = _mix(_fill(p, (120, 200, 235)), (82, 166, 215), layers)
    image = _mix(image, (226, 238, 245), (r - 0.9) / 0.03)  # sugar glaze
    return _shade(image, 0.02 * p.noise(0.02))


def paint_meat_loaf(p: Paint) -> np.ndarray:
    image = _fill(p, (40, 58, 96))
    image = _mix(image, (38, 46, 124), (p.noise(0.02) > 0.3) * 0.8)  # glaze
    return _shade(image, 0.06 * p.noise(0.004) + 0.04 * p.noise(0.02))


def paint_cucumber(p: Paint) -> np.ndarray:
    t, s = p.along()
    image = _fill(p, (42, 86, 46))
    stripes = 0.5 + 0.5 * np.sin(7 * s + 0.5 * p.noise(0.04))
    image = _mix(image, (52, 106, 66), stripes * 0.6 * (np.abs(s) < 0.7))
    image = _mix(
        image,
        (90, 150, 118),
        _spots(p, 40, 0.0012, 0.55) * 0.8 * (np.abs(s) < 0.45) * (np.abs(t - 0.5) < 0.4),
    )
    return _shade(image, 0.05 * p.noise(0.01))


def paint_potato(p: Paint) -> np.ndarray:
    image = _fill(p, (128, 184, 212))
    image = _mix(image, (124, 180, 209), (p.noise(0.01) > 0.8) * 0.7)  # mottled skin
    image = _mix(image, (72, 112, 142), _spots(p, 6, 0.0025, 0.5))  # eyes
    return _shade(image, 0.02 * p.noise(0.02) - 0.03 * np.clip(p.radius, 0, 1) ** 2)


def paint_banana(p: Paint) -> np.ndarray:
    t, s = p.along()
    image = _fill(p, (52, 206, 236))
    image = _mix(image, (42, 186, 222), (np.abs(np.abs(s) - 0.35) < 0.06) * 0.8)  # ridges
    ends = np.clip((np.abs(t - 0.5) - 0.4) / 0.06, 0, 1)
    image = _mix(image, (70, 190, 225), ends)
    freckles = _spots(p, 12, 0.0015, 0.5) * (np.abs(s) < 0.5) * (np.abs(t - 0.5) < 0.35)
    image = _mix(image, (60, 160, 205), freckles * 0.6)
    return _shade(image, 0.03 * p.noise(0.02))


PAINTERS: dict[str, Callable[[Paint], np.ndarray]] = {
    name.removeprefix("paint_"): painter
    for name, painter in list(globals().items())
    if name.startswith("paint_")
}
"""Object kind -> the function that colours it."""


BOARD_SPARE = 0.15
"""The board is this much longer and wider than the image: each seed sees its own part of it."""
CACHED_PIXELS = 4_000_000
"""Boards and noise fields of images up to this size are computed once per process."""


def board_texture(
    size_px: tuple[int, int], px_per_m: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Wood under the objects, as (1 + its shade) (H x W) and its BGR colour: the part of one
    board (the same for every scene of this size and resolution, as in a lab) that the seed
    picks, in a tint the seed varies a little."""
    width, height = size_px
    spare_x, spare_y = int(BOARD_SPARE * width), int(BOARD_SPARE * height)
    shade = _cached(_wood, (width + spare_x, height + spare_y), px_per_m)
    x0, y0 = int(rng.integers(0, spare_x + 1)), int(rng.integers(0, spare_y + 1))
    base = np.array([70, 118, 162], np.float32) * np.float32(rng.uniform(0.98, 1.02))
    return shade[y0 : y0 + height, x0 : x0 + width] + np.float32(1.0), base


def coloured(factor: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """An H x W x 3 float32 image: `factor` (H x W) times a BGR colour."""
    import cv2

    # one plane per channel, then interleaved: a tenth of numpy's broadcast over the last axis
    return np.asarray(cv2.merge([factor * channel for channel in colour]))


def _wood(size_px: tuple[int, int], px_per_m: float) -> np.ndarray:
    """Shade of the board: grain running along x, slow colour changes, a little fibre texture."""
    rng = np.random.default_rng([0, 2])
    width, height = size_px
    rows = np.arange(height, dtype=np.float32)[:, None] / px_per_m
    warp = smooth_noise((height, width), 0.05 * px_per_m, rng)
    period = rng.uniform(0.006, 0.009)
    grain = np.sin(2 * np.pi * (rows / period + 0.6 * warp))
    fibres = smooth_noise((height, width), 1.0, rng)
    fibres = fibres.mean(axis=1, keepdims=True) * 0.5 + 0.5 * smooth_noise((height, width), 2, rng)
    return np.asarray(
        0.035 * grain
        + 0.012 * fibres
        + 0.015 * smooth_noise((height, width), 0.08 * px_per_m, rng),
        dtype=np.float32,
    )


def sensor_noise(size_px: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Camera noise (standard deviation 2 grey levels) for a BGR image: the seed picks where in
    one larger noise field its image lies (drawing fresh noise costs more than the rest)."""
    width, height = size_px
    spare = 64
    field_ = _cached(_noise, (width + spare, height + spare))
    x0, y0 = int(rng.integers(0, spare + 1)), int(rng.integers(0, spare + 1))
    return field_[y0 : y0 + height, x0 : x0 + width]


def _noise(size_px: tuple[int, int]) -> np.ndarray:
    width, height = size_px
    rng = np.random.default_rng([0, 3])
    return rng.normal(0.0, 2.0, size=(height, width, 3)).astype(np.float32)


_FIELDS: dict[tuple[Any, ...], np.ndarray] = {}
_FIELDS_LOCK = threading.Lock()


def _cached(make: Callable[..., np.ndarray], *args: Any) -> np.ndarray:
    """make(*args), read-only, remembered when small (the last few); a pure function of args."""
    key = (make.__name__, *args)
    with _FIELDS_LOCK:
        found = _FIELDS.get(key)
    if found is None:
        found = make(*args)
        found.flags.writeable = False
        if found.size <= 3 * CACHED_PIXELS:
            with _FIELDS_LOCK:
                while len(_FIELDS) >= 6:
                    _FIELDS.pop(next(iter(_FIELDS)))
                _FIELDS[key] = found
    return found


def lighting(size_px: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A brightness gradient of +-3 % across the image, in a direction the seed picks."""
    width, height = size_px
    direction = rng.uniform(0, 2 * np.pi)
    x = np.linspace(-0.5, 0.5, width, dtype=np.float32)[None, :]
    y = np.linspace(-0.5, 0.5, height, dtype=np.float32)[:, None]
    return 1.0 + 0.06 * (np.cos(direction) * x + np.sin(direction) * y)
