"""Re-targeting maps: the one linear map S that carries a demonstration onto a segment."""

from __future__ import annotations

import math

import numpy as np

from keymps.primitives.system import DmpError

RETARGET_MODES: tuple[str, ...] = ("similarity", "axial", "blade", "translate")
"""How a demonstration is carried onto a segment (see `retarget_map`)."""
ZERO_LENGTH_M = 1e-9
"""Segments and demonstrations shorter than this are treated as zero-length (dots)."""
BLADE_MIN_SLOPE = 0.1
"""`blade` needs a demonstration whose vertical travel is at least this fraction of its length
(about 6 degrees). It divides the horizontal mismatch by the demo's depth: a draw along the
board, or a logged stroke whose height only drifts by sensor noise, would be thrown metres away.
Flatter demos re-target as `axial`."""


def blade_applies(demo_delta: np.ndarray) -> bool:
    """Whether a demonstration descends (or rises) enough for `blade` re-targeting."""
    length = float(np.linalg.norm(demo_delta))
    return length >= ZERO_LENGTH_M and abs(float(demo_delta[2])) >= BLADE_MIN_SLOPE * length


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotation taking unit vector a to unit vector b (pi about the most vertical axis
    perpendicular to a when they are opposite), accurate to rounding in every direction."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    cos = a0 * b0 + a1 * b1 + a2 * b2
    k0, k1, k2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    sin = math.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
    if cos >= 0.0:  # I + [k]x + [k]x^2 / (1 + cos), k = a x b: exact near parallel vectors
        skew = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
        return np.eye(3) + skew + (skew @ skew) / (1.0 + cos)
    if sin > 1e-3:  # Rodrigues with the unit axis: error ~ rounding / sin
        skew = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]]) / sin
        return np.eye(3) + sin * skew + (1.0 - cos) * (skew @ skew)
    # (Nearly) opposite: half a turn about the most vertical axis perpendicular to a, then the
    # tiny rest of the way.
    axis = np.array([-a2 * a0, -a2 * a1, 1.0 - a2 * a2])  # world z minus its part along a
    if np.linalg.norm(axis) < 1e-6:
        axis = np.array([1.0 - a0 * a0, -a0 * a1, -a0 * a2])  # a is vertical: turn about x
    axis = axis / np.linalg.norm(axis)
    half_turn = 2.0 * np.outer(axis, axis) - np.eye(3)
    return _rotation_between(half_turn @ np.asarray(a, dtype=float), b) @ half_turn


def _rotation_about_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def heading_rotation(
    demo_dir: np.ndarray, target_dir: np.ndarray, heading: float | None = None
) -> np.ndarray:
    """Rotation taking unit vector demo_dir to target_dir: first about world z (heading), then a
    tilt in the vertical plane. Horizontal stays horizontal and "down" stays down; it equals the
    minimal rotation whenever either vector is vertical or both are horizontal. For a vertical
    target, `heading` (radians about z), when given, is where the demo's heading turns to."""
    horizontal = 1e-9
    if math.hypot(demo_dir[0], demo_dir[1]) < horizontal:
        return _rotation_between(demo_dir, target_dir)
    if math.hypot(target_dir[0], target_dir[1]) < horizontal:
        if heading is None:
            return _rotation_between(demo_dir, target_dir)
        turn = _rotation_about_z(heading - math.atan2(demo_dir[1], demo_dir[0]))
        return _rotation_between(turn @ demo_dir, target_dir) @ turn
    yaw = math.atan2(target_dir[1], target_dir[0]) - math.atan2(demo_dir[1], demo_dir[0])
    turn = _rotation_about_z(yaw)
    return _rotation_between(turn @ demo_dir, target_dir) @ turn


def retarget_map(
    demo_delta: np.ndarray,
    delta: np.ndarray,
    mode: str = "similarity",
    heading: float | None = None,
) -> np.ndarray:
    """The 3x3 map S applied to the demonstration so that S demo_delta = delta (when possible).

    similarity: |delta|/|demo_delta| times the heading rotation; axial: the heading rotation
    after stretching only along demo_delta (a zero-length delta collapses the demo's travel along
    its own direction and keeps the rest: a dot); blade: see `blade_map` (as axial for a demo
    flatter than BLADE_MIN_SLOPE); translate: identity.
    Zero-length demos, and zero-length deltas in similarity mode, use the identity (the demo is
    replayed translated).

    Args:
        demo_delta: (3,) the demonstration's goal minus its start, metres.
        delta: (3,) the segment's goal minus its start, metres.
        mode: One of RETARGET_MODES.
        heading: Radians about z: where the demo's heading turns to when `delta` is vertical
            (e.g. the blade's current yaw); None keeps the minimal rotation.

    Returns:
        (3, 3) S; a re-targeted rollout is y(t) = start + S (y_demo(t) - demo_start).

    Raises:
        DmpError: For an unknown mode.
    """
    demo_delta = np.asarray(demo_delta, dtype=float)
    delta = np.asarray(delta, dtype=float)
    if mode not in RETARGET_MODES:
        raise DmpError(f"unknown re-target mode {mode!r}; use one of {', '.join(RETARGET_MODES)}")
    demo_len = float(np.linalg.norm(demo_delta))
    target_len = float(np.linalg.norm(delta))
    if mode == "translate" or demo_len < ZERO_LENGTH_M:
        return np.eye(3)
    if mode == "blade" and blade_applies(demo_delta):
        return blade_map(demo_delta, delta, heading)
    demo_dir = demo_delta / demo_len
    if target_len < ZERO_LENGTH_M:
        if mode in ("axial", "blade"):
            return np.eye(3) - np.outer(demo_dir, demo_dir)
        return np.eye(3)
    rotation = heading_rotation(demo_dir, delta / target_len, heading)
    ratio = target_len / demo_len
    if mode == "similarity":
        return ratio * rotation
    stretch = np.eye(3) + (ratio - 1.0) * np.outer(demo_dir, demo_dir)
    return rotation @ stretch


def blade_map(
    demo_delta: np.ndarray, delta: np.ndarray, heading: float | None = None
) -> np.ndarray:
    """For cutting: turn about z to the segment's heading, keep horizontal motion as it was
    demonstrated (strokes along the blade keep their length and stay level), scale the depth by
    delta_z / demo_z, and spread the remaining horizontal difference in proportion to the depth
    reached. The cut therefore never goes below the goal when the demo never went below its own.

        S = [[R, c], [0, k]],   R: 2x2 turn,   k = delta_z / demo_z,
        c = (delta_xy - R demo_xy) / demo_z   (so that S demo_delta = delta)

    The demo's vertical travel must be at least BLADE_MIN_SLOPE of its length. A demo without
    horizontal travel is taken to point along +x; a segment without any takes `heading` (or the
    demo's own)."""
    demo_delta = np.asarray(demo_delta, dtype=float)
    delta = np.asarray(delta, dtype=float)
    if not blade_applies(demo_delta):
        raise DmpError(
            f"blade re-targeting needs a demonstration whose vertical travel is at least "
            f"{BLADE_MIN_SLOPE:.0%} of its length; this one moves {demo_delta.tolist()} m"
        )
    level = 1e-9
    demo_heading = (
        math.atan2(demo_delta[1], demo_delta[0])
        if math.hypot(demo_delta[0], demo_delta[1]) >= level
        else 0.0
    )
    if math.hypot(delta[0], delta[1]) >= level:
        target_heading = math.atan2(delta[1], delta[0])
    else:
        target_heading = demo_heading if heading is None else heading
    turn = _rotation_about_z(target_heading - demo_heading)
    result = turn.copy()
    result[:2, 2] = (delta[:2] - turn[:2, :2] @ demo_delta[:2]) / demo_delta[2]
    result[2, 2] = delta[2] / demo_delta[2]
    return result
