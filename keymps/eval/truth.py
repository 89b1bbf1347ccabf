"""Ground truth of a suite case: its cut lines on the true outline, then 3D by the primitive.

The cut lines are computed from the synthetic scene's sidecar geometry (the true outline,
centre and rotation in board metres), never from the detector. Each line becomes 3D as the
paper does: the ground-truth primitive re-targeted to (start, goal), whose heights come from
the task's height mode (Appendix C) with the object's true height.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError

if TYPE_CHECKING:
    from keymps.eval.suites import Case, GroundTruth, ParallelCuts, RadialCuts, Suite, TipCuts


def line_hits(polygon: np.ndarray, point: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Sorted parameters t where point + t * direction crosses the polygon's edges."""
    a = np.asarray(polygon, dtype=float)
    edge = np.roll(a, -1, axis=0) - a
    denom = direction[0] * edge[:, 1] - direction[1] * edge[:, 0]
    ok = np.abs(denom) > 1e-15
    safe = np.where(ok, denom, 1.0)
    diff = a - point
    t = (diff[:, 0] * edge[:, 1] - diff[:, 1] * edge[:, 0]) / safe
    u = (diff[:, 0] * direction[1] - diff[:, 1] * direction[0]) / safe
    hit = ok & (u >= 0.0) & (u < 1.0)
    return np.sort(t[hit])


def _unit(degrees: float) -> np.ndarray:
    return np.array([math.cos(math.radians(degrees)), math.sin(math.radians(degrees))])


def _slicing_direction(along: str, rotation_deg: float) -> np.ndarray:
    if along == "x":
        return np.array([1.0, 0.0])
    if along == "y":
        return np.array([0.0, 1.0])
    # the long axis, pointed to the right of the image so that "from the low end" is the left
    return _unit(math.remainder(rotation_deg, 180.0))


def _chord(
    polygon: np.ndarray, point: np.ndarray, direction: np.ndarray, overshoot: float
) -> np.ndarray | None:
    hits = line_hits(polygon, point, direction)
    if len(hits) < 2:
        return None
    return np.array(
        [point + (hits[0] - overshoot) * direction, point + (hits[-1] + overshoot) * direction]
    )


def _parallel_positions(
    cuts: ParallelCuts | TipCuts, extent: float, capped: tuple[bool, bool] = (False, False)
) -> np.ndarray:
    if cuts.pattern == "tips":
        cap = cuts.inset if cuts.cap_inset is None else cuts.cap_inset
        low, high = (cap if c else cuts.inset for c in capped)
        return np.array([low, extent - high])
    if cuts.parts is not None:
        return np.arange(1, cuts.parts) * extent / cuts.parts
    if cuts.fractions is not None:
        return np.asarray(cuts.fractions) * extent
    assert cuts.spacing is not None
    if cuts.count is not None:
        return np.arange(1, cuts.count + 1) * cuts.spacing
    positions = np.arange(1, int(extent / cuts.spacing) + 2) * cuts.spacing
    return positions[positions <= extent - cuts.spacing / 2]


def parallel_cut_lines(
    cuts: ParallelCuts | TipCuts,
    outline: np.ndarray,
    rotation_deg: float,
    overshoot: float,
    body: np.ndarray | None = None,
) -> np.ndarray:
    """(K, 2, 2) cuts perpendicular to the slicing direction, each running from its start to
    its end: the slicing direction turned 90 degrees clockwise (vertical cuts top to bottom,
    horizontal cuts left to right). Positions are measured on the body (`body`: where it begins
    and ends on the centre line, board metres) when the object has a cap or stem beyond it."""
    u = _slicing_direction(cuts.along, rotation_deg)
    v = np.array([u[1], -u[0]])
    projected = outline @ u
    low, high = float(projected.min()), float(projected.max())
    capped = (False, False)
    if body is not None:  # the body's ends replace the outline's where a cap or stem lies
        first, last = sorted(float(e) for e in np.asarray(body, dtype=float) @ u)
        capped = (first > low + 0.001, last < high - 0.001)
        low, high = (first if capped[0] else low), (last if capped[1] else high)
    across = float((outline @ v).mean())
    lines = []
    for position in _parallel_positions(cuts, high - low, capped):
        point = (low + position) * u + across * v
        chord = _chord(outline, point, v, overshoot)
        if chord is not None:
            lines.append(chord)
    return np.array(lines, dtype=float).reshape(-1, 2, 2)


def radial_cut_lines(
    cuts: RadialCuts, outline: np.ndarray, centre: np.ndarray, overshoot: float
) -> np.ndarray:
    """(K, 2, 2) equal-angle cuts: through the centre (even parts) or from it outwards (odd)."""
    step = 360.0 / cuts.parts
    lines = []
    if cuts.parts % 2 == 0:
        for i in range(cuts.parts // 2):
            chord = _chord(outline, centre, _unit(cuts.first_deg + i * step), overshoot)
            if chord is not None:
                lines.append(chord)
    else:
        for i in range(cuts.parts):
            d = _unit(cuts.first_deg + 180.0 + i * step)
            ahead = line_hits(outline, centre, d)
            reach = float(ahead.max()) if len(ahead) else 0.0
            lines.append(np.array([centre, centre + (reach + overshoot) * d]))
    return np.array(lines, dtype=float).reshape(-1, 2, 2)


def cut_lines(truth: GroundTruth, scene_object: dict[str, Any]) -> np.ndarray:
    """The ground-truth cuts (K, 2, 2) in board metres, from one object of a scene sidecar."""
    outline = np.asarray(scene_object["outline_m"], dtype=float)
    cuts = truth.cuts
    if cuts.pattern == "dots_ring":
        centre = np.asarray(scene_object["centre_m"], dtype=float)
        radius = cuts.fraction * float(scene_object["length_m"]) / 2
        angles = np.radians(cuts.first_deg) + 2 * np.pi * np.arange(cuts.count) / cuts.count
        dots = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
        return np.stack([dots, dots], axis=1)
    if cuts.pattern == "radial":
        centre = np.asarray(scene_object["centre_m"], dtype=float)
        return radial_cut_lines(cuts, outline, centre, truth.overshoot)
    return parallel_cut_lines(
        cuts,
        outline,
        float(scene_object["rotation_deg"]),
        truth.overshoot,
        scene_object.get("body_m"),
    )


@dataclass(frozen=True)
class CaseTruth:
    """Everything known about one case's scene and what should be done to it."""

    scene: dict[str, Any]
    """The scene's sidecar (true geometry of every object)."""
    lines_m: np.ndarray | None
    """(K, 2, 2) ground-truth cut lines, board metres (None without a ground truth)."""
    pieces: tuple[np.ndarray, ...]
    """The ground-truth work pieces in 3D (empty without a ground truth)."""
    object_pieces: tuple[tuple[np.ndarray, ...], ...] = ()
    """Several objects: the pieces of each object, left to right (pieces is all of them)."""


def height_pair(task_data: dict[str, Any], object_height: float) -> tuple[float, float]:
    """Appendix C heights (start z, goal z) for the task's height mode and margin."""
    from keymps.config.task import Height

    height = Height.model_validate(task_data.get("height", {}))
    top = object_height + height.margin
    return {"both": (top, top), "start": (top, 0.0), "end": (0.0, top)}[height.mode]


def ground_truth_pieces(
    lines_m: np.ndarray, primitive_name: str, z: tuple[float, float], search_dirs: list[Path]
) -> tuple[np.ndarray, ...]:
    """Each cut line scaled into 3D by the primitive (re-targeted to its start and goal)."""
    from keymps.primitives.dictionary import load_primitives

    primitive = load_primitives([primitive_name], search_dirs)[primitive_name]
    pieces = []
    for start, goal in lines_m:
        rollout = primitive.rollout([*start, z[0]], [*goal, z[1]], spacing=0.001)
        pieces.append(np.asarray(rollout.y))
    return tuple(pieces)


def case_truth(
    suite: Suite, case: Case, seed: int, sidecar: dict[str, Any] | None = None
) -> CaseTruth:
    """The case's ground truth for `seed` (if it has one), on its scene's true geometry: the
    given sidecar of that scene, or the scene rendered again."""
    from keymps.eval.tasks import case_scene, case_task_data
    from keymps.primitives.dictionary import default_search_dirs
    from keymps.scenes.render import render_scene_cached

    if sidecar is None:
        sidecar = render_scene_cached(case_scene(suite, case, seed).spec()).truth
    if case.ground_truths:
        return _objects_truth(suite, case, seed, sidecar)
    if case.ground_truth is None:
        return CaseTruth(scene=sidecar, lines_m=None, pieces=())
    scene_object = sidecar["objects"][0]
    lines = cut_lines(case.ground_truth, scene_object)
    if len(lines) == 0:
        raise KeympsError(f"case {case.id}: the ground-truth design has no cut on the object")
    task_data = case_task_data(suite, case, seed)
    z = height_pair(task_data, float(scene_object["height_m"]))
    pieces = ground_truth_pieces(
        lines, case.ground_truth.primitive, z, default_search_dirs(suite.folder)
    )
    return CaseTruth(scene=sidecar, lines_m=lines, pieces=pieces)


def objects_left_to_right(sidecar: dict[str, Any]) -> list[dict[str, Any]]:
    """The sidecar's objects in the order keymps numbers them (left to right by box centre)."""
    return sorted(sidecar["objects"], key=lambda o: (o["bbox_m"][0] + o["bbox_m"][2]) / 2)


def _objects_truth(suite: Suite, case: Case, seed: int, sidecar: dict[str, Any]) -> CaseTruth:
    """Per object, its own design on its true outline at its true height."""
    from keymps.eval.tasks import case_task_data
    from keymps.primitives.dictionary import default_search_dirs

    assert case.ground_truths is not None
    task_data = case_task_data(suite, case, seed)
    lines_all: list[np.ndarray] = []
    per_object: list[tuple[np.ndarray, ...]] = []
    for number, (truth, scene_object) in enumerate(
        zip(case.ground_truths, objects_left_to_right(sidecar), strict=True), start=1
    ):
        if truth is None:
            per_object.append(())
            continue
        lines = cut_lines(truth, scene_object)
        if len(lines) == 0:
            raise KeympsError(f"case {case.id}: the ground truth of object {number} is empty")
        z = height_pair(task_data, float(scene_object["height_m"]))
        per_object.append(
            ground_truth_pieces(lines, truth.primitive, z, default_search_dirs(suite.folder))
        )
        lines_all.append(lines)
    pieces = tuple(p for mine in per_object for p in mine)
    return CaseTruth(
        scene=sidecar,
        lines_m=np.concatenate(lines_all) if lines_all else None,
        pieces=pieces,
        object_pieces=tuple(per_object),
    )
