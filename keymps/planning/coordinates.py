"""Coordinates in the model's own convention, and the image size a provider accepts.

Some model families are trained to point in normalized coordinates: Google documents Gemini's
points and boxes as [y, x] normalized to 0-1000. Others answer in pixels of the image they see.
`planner.coordinates: auto` picks by model family (AUTO_CONVENTIONS); the prompt's coordinate
paragraph, its examples and the answer schema follow the convention, and answers are converted
exactly to pixels of the crop. Crops larger than a provider accepts are downscaled before
sending (a provider would do it anyway, and the model would then answer in pixels of an image
keymps never saw); answers are mapped back by the same factors.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from keymps.planning.backend_choice import model_provider

Convention = Literal["pixels", "xy_1000", "yx_1000"]
CONVENTIONS: tuple[str, ...] = ("pixels", "xy_1000", "yx_1000")
SCALE = 1000.0
"""The range of the normalized conventions: 0 is one edge of the image, 1000 the other."""

AUTO_CONVENTIONS: tuple[tuple[str, Convention], ...] = (("gemini", "yx_1000"),)
"""(substring of the model string, convention) for `auto`, first match wins; others: pixels."""

MAX_IMAGE: dict[str, tuple[int, int | None]] = {
    "openai": (2048, 768),
    "azure": (2048, 768),
    "anthropic": (1568, None),
    "bedrock": (1568, None),
    "gemini": (3072, None),
    "vertex_ai": (3072, None),
}
"""Provider -> (longest side, shortest side) it sends the model; larger images are scaled down
first (OpenAI: fit 2048 x 2048, then the short side to 768; Anthropic: long edge 1568)."""


def resolve(setting: str, model: str | None) -> Convention:
    """The convention for `planner.coordinates` (auto picks by model family)."""
    if setting != "auto":
        return setting  # type: ignore[return-value]
    name = (model or "").lower()
    for fragment, convention in AUTO_CONVENTIONS:
        if fragment in name:
            return convention
    return "pixels"


def sent_size(crop_size: tuple[int, int], model: str | None) -> tuple[int, int]:
    """(width, height) of the image sent for `model`: the crop, scaled down to what its
    provider accepts (aspect kept; never scaled up)."""
    width, height = crop_size
    if not model:
        return width, height
    limits = MAX_IMAGE.get(model_provider(model))
    if limits is None:
        return width, height
    longest, shortest = limits
    factor = min(1.0, longest / max(width, height))
    if shortest is not None:
        factor = min(factor, shortest / min(width, height))
    if factor >= 1.0:
        return width, height
    return max(1, int(math.floor(width * factor + 1e-6))), max(
        1, int(math.floor(height * factor + 1e-6))
    )


def limits(convention: Convention, size: tuple[int, int]) -> tuple[float, float]:
    """The largest first and second coordinate of a point in this convention."""
    if convention == "pixels":
        return float(size[0]), float(size[1])
    return SCALE, SCALE


def to_pixels(points: np.ndarray, convention: Convention, size: tuple[int, int]) -> np.ndarray:
    """Points (..., 2) in `convention` to [x, y] pixels of an image of `size` (width, height)."""
    values = np.asarray(points, dtype=float)
    if convention == "pixels":
        return values.copy()
    if convention == "yx_1000":
        values = values[..., ::-1]
    return values / SCALE * np.asarray(size, dtype=float)


def from_pixels(points: np.ndarray, convention: Convention, size: tuple[int, int]) -> np.ndarray:
    """[x, y] pixels of an image of `size` to points in `convention` (the inverse of to_pixels)."""
    values = np.asarray(points, dtype=float)
    if convention == "pixels":
        return values.copy()
    values = values / np.asarray(size, dtype=float) * SCALE
    return values[..., ::-1] if convention == "yx_1000" else values


def rescale(points: np.ndarray, from_size: tuple[int, int], to_size: tuple[int, int]) -> np.ndarray:
    """Pixels of an image of `from_size` to pixels of the same image at `to_size`."""
    factor = np.asarray(to_size, dtype=float) / np.asarray(from_size, dtype=float)
    return np.asarray(points, dtype=float) * factor


def point_text(x: float, y: float, convention: Convention, size: tuple[int, int]) -> str:
    """A pixel point written as the model must write it: '[x, y]' or '[y, x]', rounded."""
    a, b = from_pixels(np.array([x, y]), convention, size)
    return f"[{a:.0f}, {b:.0f}]"


def paragraph(convention: Convention, size: tuple[int, int]) -> str:
    """The prompt's coordinate paragraph for this convention and sent image size."""
    width, height = size
    if convention == "pixels":
        return (
            f"Coordinates: pixels of the image you are given, {width} x {height} pixels. The "
            "origin is the top-left corner of the image, x grows to the right, y grows downwards. "
            f"A point is written [x, y]. Every point must lie inside the image: 0 <= x <= {width}, "
            f"0 <= y <= {height}. Use pixel coordinates, not fractions of the image and not a "
            "0-1000 scale."
        )
    order = "[y, x]" if convention == "yx_1000" else "[x, y]"
    return (
        f"Coordinates: normalized to 0-1000, written {order}. The origin is the top-left corner "
        "of the image; x = 0 is its left edge and x = 1000 its right edge, y = 0 its top edge "
        f"and y = 1000 its bottom edge, whatever the image's size ({width} x {height} pixels). "
        f"A point is written {order}. Every value must lie in 0..1000. Do not use pixels."
    )
