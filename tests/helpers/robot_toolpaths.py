"""Hand-built tool paths for the robot tests (the shapes the shipped tasks produce)."""

from __future__ import annotations

import math

import numpy as np

from keymps.types import Piece, ToolPath

HOME = np.array([0.15, 0.09, 0.13])


def polyline(corners: list[np.ndarray], spacing: float) -> np.ndarray:
    """Points along straight lines through `corners`, at most `spacing` apart."""
    points = [np.asarray(corners[0], dtype=float)]
    for a, b in zip(corners[:-1], corners[1:], strict=True):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        count = max(1, math.ceil(np.linalg.norm(b - a) / spacing))
        for s in np.linspace(0, 1, count + 1)[1:]:
            points.append(a + s * (b - a))
    return np.array(points)


def travel(
    a: np.ndarray,
    b: np.ndarray,
    top: float,
    pair: int,
    yaw_a: float,
    yaw_b: float,
    speed: float = 0.15,
    spacing: float = 0.01,
) -> Piece:
    """Rise to `top`, move over, descend: sharp corners, sparse points."""
    corners = [a, np.array([a[0], a[1], top]), np.array([b[0], b[1], top]), b]
    corners = [c for i, c in enumerate(corners) if i == 0 or np.linalg.norm(c - corners[i - 1]) > 0]
    points = polyline(corners, spacing)
    yaw = np.linspace(yaw_a, yaw_b, len(points))
    return Piece("travel", pair, points, yaw, speed)


def assemble(
    works: list[tuple[np.ndarray, np.ndarray]],
    top: float,
    keyword: str,
    work_speed: float,
    home: np.ndarray = HOME,
) -> ToolPath:
    """home -> (travel, work) per work piece -> home."""
    pieces: list[Piece] = []
    here, here_yaw = home, 0.0
    for pair, (points, yaw) in enumerate(works):
        pieces.append(travel(here, points[0], top, pair, here_yaw, float(yaw[0])))
        pieces.append(Piece("work", pair, points, yaw, work_speed))
        here, here_yaw = points[-1], float(yaw[-1])
    pieces.append(travel(here, home, top, len(works) - 1, here_yaw, 0.0))
    return ToolPath(tuple(pieces), keyword)


def ring_of_dots(
    count: int = 15,
    center: tuple[float, float] = (0.15, 0.09),
    radius: float = 0.045,
    surface: float = 0.065,
) -> ToolPath:
    """Icing: `count` small rosettes (2 mm circles at 1 mm spacing) on a ring."""
    works = []
    for i in range(count):
        angle = 2 * math.pi * i / count
        cx, cy = center[0] + radius * math.cos(angle), center[1] + radius * math.sin(angle)
        s = np.linspace(0, 2 * math.pi, 14)
        points = np.stack(
            [cx + 0.002 * (np.cos(s) - 1), cy + 0.002 * np.sin(s), np.full_like(s, surface)], 1
        )
        works.append((points, np.zeros(len(points))))
    return assemble(works, surface + 0.03, "line", 0.03)


def radial_cuts(
    count: int = 8,
    center: tuple[float, float] = (0.15, 0.09),
    radius: float = 0.085,
    top: float = 0.025,
) -> ToolPath:
    """Cutting: `count` straight cuts from the centre outwards, descending to the board."""
    works = []
    for i in range(count):
        angle = 2 * math.pi * i / count
        direction = np.array([math.cos(angle), math.sin(angle), 0.0])
        start = np.array([center[0], center[1], top])
        goal = np.array([center[0], center[1], 0.0]) + radius * direction
        points = polyline([start, goal], 0.001)
        works.append((points, np.full(len(points), angle)))
    return assemble(works, top + 0.03, "straight", 0.02)
