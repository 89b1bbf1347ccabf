"""The kinds of object a synthetic scene can hold, and their footprints in metres."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from keymps.errors import KeympsError
from keymps.scenes.textures import centre_line


@dataclass(frozen=True)
class Shape:
    """How an object's footprint is built, in its local frame (u along its length, metres)."""

    family: str
    """disk | ring | rrect | profile"""
    corner: float = 0.15
    """rrect: corner radius as a fraction of the width."""
    hole: float = 0.0
    """ring: hole diameter as a fraction of the outer diameter."""
    wobble: float = 0.0
    """disk/ring/profile: relative amplitude of the irregular edge."""
    bend: float = 0.0
    """profile: sag of the centre line as a fraction of the length."""
    profile: Callable[[np.ndarray], np.ndarray] | None = None
    """profile: half-width (max 1) along t in [0, 1] from one end to the other."""


@dataclass(frozen=True)
class ObjectKind:
    name: str
    description: str
    length: float
    width: float
    height: float
    shape: Shape
    round: bool = False
    """Length and width are one diameter; any rotation looks alike."""
    body: tuple[float, float] = (0.0, 1.0)
    """Where the body a cook slices lies along the length (0 one end, 1 the other): an
    eggplant's green cap and stem begin at 0.73 (keymps.scenes.textures.paint_eggplant)."""


def _superellipse(power: float) -> Callable[[np.ndarray], np.ndarray]:
    def profile(t: np.ndarray) -> np.ndarray:
        return np.clip(1.0 - np.abs(2.0 * t - 1.0) ** power, 0.0, 1.0) ** (1.0 / power)

    return profile


def _eggplant_profile(t: np.ndarray) -> np.ndarray:
    body_t = np.clip(t / 0.9, 0.0, 1.0)
    body = np.clip(np.sin(np.pi * body_t**0.72), 0.0, 1.0) ** 0.55 * (1.0 - 0.38 * body_t)
    stem = np.where((t > 0.8) & (t < 1.0), 0.13 * np.sqrt(np.clip((1.0 - t) / 0.012, 0, 1)), 0.0)
    values = np.maximum(body, stem)
    return values / 0.86


def _banana_profile(t: np.ndarray) -> np.ndarray:
    body = np.clip(1.0 - np.abs(2.0 * t - 1.0) ** 2.5, 0.0, 1.0) ** 0.55
    stem = np.where(t > 0.9, 0.3 * np.sqrt(np.clip((1.0 - t) / 0.01, 0, 1)), 0.0)
    return np.maximum(body, stem)


KINDS: dict[str, ObjectKind] = {
    kind.name: kind
    for kind in [
        ObjectKind("round_cake", "cream-iced round cake", 0.12, 0.12, 0.06, Shape("disk"), True),
        ObjectKind("square_cake", "chocolate square cake", 0.12, 0.12, 0.06, Shape("rrect", 0.06)),
        ObjectKind("round_pizza", "pizza with toppings", 0.15, 0.15, 0.02, Shape("disk", wobble=0.012), True),
        ObjectKind("cabbage", "head of cabbage", 0.14, 0.13, 0.11, Shape("disk", wobble=0.03), True),
        ObjectKind(
            "eggplant", "purple eggplant, green cap", 0.20, 0.065, 0.06,
            Shape("profile", bend=0.04, profile=_eggplant_profile), body=(0.0, 0.73),
        ),
        ObjectKind(
            "baguette", "baguette", 0.26, 0.06, 0.05, Shape("profile", profile=_superellipse(4.0))
        ),
        ObjectKind("banana_bread", "banana bread loaf", 0.18, 0.09, 0.08, Shape("rrect", 0.18)),
        ObjectKind("chiffon_cake", "chiffon cake (ring)", 0.15, 0.15, 0.09, Shape("ring", hole=0.22), True),
        ObjectKind("baumkuchen", "baumkuchen (ring)", 0.12, 0.12, 0.05, Shape("ring", hole=0.25), True),
        ObjectKind("meat_loaf", "meat loaf", 0.16, 0.08, 0.06, Shape("rrect", 0.3)),
        ObjectKind(
            "cucumber", "cucumber", 0.20, 0.032, 0.032,
            Shape("profile", bend=0.03, profile=_superellipse(3.0)),
        ),
        ObjectKind(
            "potato", "potato", 0.09, 0.062, 0.05,
            Shape("profile", wobble=0.04, profile=_superellipse(2.2)),
        ),
        ObjectKind(
            "banana", "banana", 0.18, 0.036, 0.035,
            Shape("profile", bend=0.12, profile=_banana_profile),
        ),
    ]
}  # fmt: skip


def canonical_kind(name: str) -> str:
    return name.strip().lower().replace("-", "_").replace(" ", "_")


def check_kinds(kinds: Sequence[str], where: str = "object") -> list[str]:
    """The canonical names, or a KeympsError naming the unknown one and listing the choices."""
    names = []
    for kind in kinds:
        name = canonical_kind(kind)
        if name not in KINDS:
            raise KeympsError(
                f"{where}: unknown object {kind!r} (available: {', '.join(sorted(KINDS))})"
            )
        names.append(name)
    if not names:
        raise KeympsError(f"{where}: no object given")
    return names


@dataclass(frozen=True)
class ObjectSpec:
    kind: str
    length: float
    width: float
    height: float
    rotation_deg: float = 0.0
    """Counter-clockwise angle of the object's length axis from the board's x axis."""
    centre: tuple[float, float] | None = None
    """Board metres; None places it (centred, or left to right when there are several)."""


def outline_local(
    obj: ObjectSpec, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray | None]:
    """Outer polygon (N, 2) and optional hole polygon, in the object's frame (u, v) metres."""
    shape = KINDS[obj.kind].shape
    half_l, half_w = obj.length / 2, obj.width / 2
    if shape.family in ("disk", "ring"):
        theta = np.linspace(0, 2 * np.pi, 360, endpoint=False)
        radius = 1.0 + _wobble(theta, shape.wobble, rng)
        outer = np.c_[half_l * radius * np.cos(theta), half_w * radius * np.sin(theta)]
        hole = None
        if shape.family == "ring":
            r = shape.hole / 2
            hole = np.c_[obj.length * r * np.cos(theta), obj.width * r * np.sin(theta)]
        return outer, hole
    if shape.family == "rrect":
        corner = min(shape.corner * obj.width, half_w, half_l)
        arcs = []
        for cx, cy, start in (
            (half_l - corner, half_w - corner, 0.0),
            (-half_l + corner, half_w - corner, 90.0),
            (-half_l + corner, -half_w + corner, 180.0),
            (half_l - corner, -half_w + corner, 270.0),
        ):
            angles = np.radians(start + np.linspace(0, 90, 24))
            arcs.append(np.c_[cx + corner * np.cos(angles), cy + corner * np.sin(angles)])
        return np.concatenate(arcs), None
    assert shape.profile is not None
    t = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, 200))  # dense near the ends
    u = (t - 0.5) * obj.length
    half = half_w * shape.profile(t) * (1.0 + _wobble(t * 2 * np.pi, shape.wobble, rng))
    centre = centre_line(u, obj.length, shape.bend)
    upper = np.c_[u, centre + half]
    lower = np.c_[u, centre - half][::-1]
    return np.concatenate([upper, lower]), None


def _wobble(theta: np.ndarray, amplitude: float, rng: np.random.Generator) -> np.ndarray:
    if amplitude <= 0:
        return np.zeros_like(theta)
    total = np.zeros_like(theta)
    for harmonic in range(2, 9):
        total += rng.normal(0, 1) / harmonic * np.cos(harmonic * theta + rng.uniform(0, 2 * np.pi))
    return amplitude * total / max(np.abs(total).max(), 1e-9)


def body_ends_local(obj: ObjectSpec) -> np.ndarray | None:
    """(2, 2) the centre line's points where the body begins and ends, in the object's frame
    (u, v metres); None when the body is the whole object."""
    kind = KINDS[obj.kind]
    if kind.body == (0.0, 1.0):
        return None
    u = (np.asarray(kind.body) - 0.5) * obj.length
    return np.stack([u, centre_line(u, obj.length, kind.shape.bend)], axis=1)


def to_board_frame(points: np.ndarray, obj: ObjectSpec, centre: tuple[float, float]) -> np.ndarray:
    angle = np.radians(obj.rotation_deg)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return points @ rotation.T + np.asarray(centre)
