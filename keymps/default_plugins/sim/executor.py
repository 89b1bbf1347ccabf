"""The `sim` executor: a kinematic replay of the validated trajectory, and outcome.png.

The joints follow the commanded samples exactly, interpolated linearly between samples as a UR
controller's servoJ does; forward kinematics gives where the tool went. It reports how far the
tool strayed from the planned tool path (tracking error), any contact below the board, and
draws what the tool did on the scene image: cuts where the tool went below the object's top
surface, icing strokes and dots where it worked on or above it. Icing is counted as it was
piped: each work piece is one stroke from the nozzle going down to its lifting (icing lines
that meet are one work piece: keymps.motion.chains), a dot where it stayed within
DOT_EXTENT_M. Dynamics are not simulated.

A knife cuts with its whole edge, not only its tip: the edge is a horizontal segment at the tip's
height, `blade_length` long, from the tip along the tool's -x axis (where the wrist turned it:
the edge trails the tip when the tool x axis points along the cut). A cut is the union of the
edge's positions while it was below the object's top, inside the object's footprint. A knife's
work that stays above the food cuts nothing (it is no icing); a tool without a blade (a piping
bag) marks with its tip. The report's `measured` holds each cut's length and depth in the form
the outcome stage predicts (keymps.types.Effect).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from keymps.outcome.cut_sweep import Footprint, covered_length, edge_segments
from keymps.plugin import RegisterExecutor, hookimpl, parse_options, require_validated
from keymps.robot.safety_geometry import distance_to_polylines, row_norms
from keymps.sorted_values import distinct
from keymps.text_drawing import on_text_thread
from keymps.types import (
    CutEffect,
    Effect,
    ExecutionReport,
    SceneImage,
    ToolPath,
    ValidatedTrajectory,
)

if TYPE_CHECKING:
    from pathlib import Path

    from keymps.config.task import Task
    from keymps.run import Run
    from keymps.types import Trajectory

BOARD_CONTACT_M = 0.0005
TRACKING_LIMIT_M = 0.0005
DOT_EXTENT_M = 0.004
"""An icing stroke whose extent is below this is drawn and counted as a dot (a rosette)."""

CUT_COLOUR = (20, 20, 20)  # BGR: a dark cut with a light edge shows on any food
CUT_EDGE = (235, 235, 235)
ICING_COLOUR = (250, 250, 250)
ICING_EDGE = (120, 120, 120)
TRAVEL_COLOUR = (200, 160, 60)
CONTACT_COLOUR = (0, 0, 255)


class SimOptions(BaseModel):
    """The executor section of a task file for `sim` (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    replay_rate_hz: float = Field(1000.0, ge=10, le=10_000)
    """Forward kinematics is evaluated this often (joints interpolated between samples)."""
    image: bool = True
    """Render outcome.png into the run folder."""
    show_travel: bool = True
    """Draw travel moves as thin lines in outcome.png."""
    icing_width_m: float = Field(0.004, gt=0, le=0.05)
    cut_width_m: float = Field(0.0015, gt=0, le=0.05)


@dataclass(frozen=True)
class Replay:
    """What the tool did: tool positions at the replay rate, their piece and kind."""

    t: np.ndarray
    tool_xyz: np.ndarray
    planned_xyz: np.ndarray
    piece_index: np.ndarray
    kind: np.ndarray
    tool_x: np.ndarray | None = None
    """(n, 2) the tool x axis (a blade's direction) on the board, unit length; None: unknown."""


REPLAY_CHUNK = 4096
"""Replayed samples computed at a time: temporaries that stay in cache and out of fresh memory
(which costs a page fault per 4 kB here, more than the arithmetic)."""


def replay(model: Any, trajectory: Trajectory, rate_hz: float) -> Replay:
    """Joints interpolated linearly between samples at `rate_hz`, through forward kinematics."""
    from keymps.robot.batch_fk import interpolated_cos_sin

    substeps = max(1, math.ceil(rate_hz / trajectory.rate_hz))
    fractions = np.arange(substeps) / substeps

    def between(values: np.ndarray) -> np.ndarray:
        """Each sample and the substeps after it towards the next, then the last sample."""
        values = np.asarray(values, dtype=float)
        inner = values[:-1, None] + fractions[:, None] * (values[1:] - values[:-1])[:, None]
        return np.concatenate([inner.reshape(-1, values.shape[1]), values[-1:]])

    q = np.asarray(trajectory.q, dtype=float)
    n = len(q)
    positions, tool_x = np.empty(((n - 1) * substeps + 1, 3)), np.empty(((n - 1) * substeps + 1, 2))
    batched = getattr(model, "batch", None) is not None
    per_chunk = max(1, (REPLAY_CHUNK - 1) // substeps)  # with its end: one chunk of batch FK
    # Chunks share their end samples (computed alike in both: the same numbers).
    for first in range(0, max(n - 1, 1), per_chunk):
        last = min(first + per_chunk, n - 1)
        joints = q[first : last + 1]
        cos_sin = interpolated_cos_sin(joints, substeps) if batched else None
        chunk_positions, x_axes = model.tool_positions_and_x_axes(between(joints), cos_sin)
        done = slice(first * substeps, last * substeps + 1)
        positions[done] = chunk_positions
        tool_x[done] = _unit(x_axes[:, :2])
    t = np.concatenate(
        [(np.asarray(trajectory.t[:-1])[:, None] + fractions / trajectory.rate_hz).ravel(),
         np.asarray(trajectory.t[-1:], dtype=float)]
    )  # fmt: skip
    return Replay(
        t,
        positions,
        between(trajectory.tool_xyz),
        _spread(np.asarray(trajectory.piece_index), substeps),
        _spread(np.asarray(trajectory.kind), substeps),
        tool_x,
    )


def _spread(values: np.ndarray, substeps: int) -> np.ndarray:
    """Each sample's value for it and its substeps, then the last sample's."""
    return np.concatenate([np.repeat(values[:-1], substeps), values[-1:]])


def _unit(vectors: np.ndarray) -> np.ndarray:
    norms = row_norms(vectors)[:, None]
    return np.divide(vectors, norms, out=np.zeros_like(vectors), where=norms > 1e-9)


def tracking_errors(result: Replay, tool_path: ToolPath | None) -> np.ndarray:
    """Distance of each replayed tool position to its piece of the tool path (or the plan)."""
    if tool_path is None:
        return row_norms(result.tool_xyz - result.planned_xyz)
    polylines = [np.asarray(piece.points) for piece in tool_path.pieces]
    return distance_to_polylines(result.tool_xyz, result.piece_index, polylines)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index ranges where mask is True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


@dataclass(frozen=True)
class Marks:
    """What the tool left behind, in board metres."""

    cuts: list[np.ndarray]
    """Per cut, the tip's path (n, 2) while below the object's top."""
    strokes: list[np.ndarray]
    dots: list[np.ndarray]
    travel: list[np.ndarray]
    contacts: np.ndarray
    sweeps: list[np.ndarray] = field(default_factory=list)
    """Per cut, (k, 2, 2) board segments the cutting edge covered: the blade at each of its
    positions below the top (tip first), or the tip's path step by step for a tool without one."""
    cut_pieces: list[int] = field(default_factory=list)
    """Per cut, the tool path piece it was made by."""
    cut_lowest: list[float] = field(default_factory=list)
    """Per cut, the tip's lowest height, metres."""


def marks(
    result: Replay, object_top: float | np.ndarray, blade_length: float = 0.0, knife: bool = False
) -> Marks:
    """Cuts where a work piece went below its object's top (one height, or one per replayed
    sample), icing where work stayed on it (not with a `knife`: it leaves no icing)."""
    work = result.kind == "work"
    below_top = result.tool_xyz[:, 2] < object_top - 1e-4
    cutting_pieces = distinct(result.piece_index[work & below_top])
    cutting = work & np.isin(result.piece_index, cutting_pieces)
    cut_runs = [(a, b) for a, b in _runs(cutting & below_top) if b - a >= 2]
    cuts = [result.tool_xyz[a:b, :2] for a, b in cut_runs]
    sweeps = [_sweep(result, a, b, blade_length) for a, b in cut_runs]
    strokes, dots = [], []
    for a, b in _runs(work & ~cutting & (not knife)):
        for _, mine in _by_piece(result.piece_index[a:b]):
            xy = result.tool_xyz[a:b, :2] if mine is None else result.tool_xyz[a:b][mine, :2]
            if np.ptp(xy, axis=0).max() < DOT_EXTENT_M:
                dots.append(xy.mean(axis=0))
            else:
                strokes.append(xy)
    travel = [result.tool_xyz[a:b, :2] for a, b in _runs(~work) if b - a >= 2]
    contacts = result.tool_xyz[result.tool_xyz[:, 2] < -BOARD_CONTACT_M, :2]
    lowest = [float(result.tool_xyz[a:b, 2].min()) for a, b in cut_runs]
    pieces = [int(result.piece_index[a]) for a, _ in cut_runs]
    return Marks(cuts, strokes, dots, travel, contacts, sweeps, pieces, lowest)


def _sweep(result: Replay, start: int, end: int, blade_length: float) -> np.ndarray:
    """(k, 2, 2) segments covered by the cutting edge over samples [start, end): the edge
    reaches from the tip along the tool's -x axis, wherever the wrist turned it."""
    backwards = None if result.tool_x is None else -result.tool_x[start:end]
    return edge_segments(result.tool_xyz[start:end], backwards, blade_length)


def _by_piece(pieces: np.ndarray) -> list[tuple[int, np.ndarray | None]]:
    """Each piece among `pieces` (ascending) with the mask of its samples; None for the mask
    when there is one piece only (the common case: no copies needed)."""
    if len(pieces) and (pieces == pieces[0]).all():
        return [(int(pieces[0]), None)]
    return [(int(piece), pieces == piece) for piece in distinct(pieces)]


def render_outcome(
    task: Task,
    scene: np.ndarray | None,
    found: Marks,
    options: SimOptions,
    footprint: np.ndarray | list[np.ndarray] | None = None,
    *,
    rectified: bool = False,
) -> Any:
    """The scene image with what the tool did drawn where it did it (BGR uint8); cuts only
    inside the `footprint` polygon(s) (board metres) when given; with several footprints each
    object's number is written beside it (as in plan.png). `rectified`: the scene is the photo
    rectified to the workspace (it spans it exactly, Appendix B)."""
    import cv2

    from keymps.perception.frames import ImageFrame

    if scene is None:  # no scene image: a plain board at 2 px per mm
        width, height = task.scene.workspace.size
        scene = np.full((round(height * 2000), round(width * 2000), 3), 235, np.uint8)
    image = np.ascontiguousarray(scene.copy())
    size = (int(image.shape[1]), int(image.shape[0]))
    workspace = task.scene.workspace
    frame = (
        ImageFrame.linear(size, workspace.size, workspace.shift)
        if rectified
        else ImageFrame.from_task(task, size)
    )
    per_metre = 1.0 / frame.metres_per_pixel()
    shift = 4  # sub-pixel drawing: coordinates in 1/16 pixel

    def pixels(xy: np.ndarray) -> np.ndarray:
        return np.round(frame.to_pixels(np.asarray(xy).reshape(-1, 2)) * (1 << shift)).astype(
            np.int32
        )

    def width_px(metres: float) -> int:
        return max(1, round(metres * per_metre))

    if options.show_travel:
        for line in found.travel:
            cv2.polylines(image, [pixels(line)], False, TRAVEL_COLOUR, 1, cv2.LINE_AA, shift)
    icing = width_px(options.icing_width_m)
    for line in found.strokes:
        cv2.polylines(image, [pixels(line)], False, ICING_EDGE, icing + 2, cv2.LINE_AA, shift)
        cv2.polylines(image, [pixels(line)], False, ICING_COLOUR, icing, cv2.LINE_AA, shift)
    for dot in found.dots:
        centre = tuple(int(v) for v in pixels(dot)[0])
        radius = icing << shift
        cv2.circle(image, centre, radius + (1 << shift), ICING_EDGE, -1, cv2.LINE_AA, shift)
        cv2.circle(image, centre, radius, ICING_COLOUR, -1, cv2.LINE_AA, shift)
    if found.sweeps:
        _paint_cuts(image, found.sweeps, footprint, pixels, width_px(options.cut_width_m), shift)
    for point in found.contacts:
        centre = tuple(int(v) for v in pixels(point)[0])
        cv2.circle(image, centre, 6 << shift, CONTACT_COLOUR, 2, cv2.LINE_AA, shift)
    if isinstance(footprint, list) and len(footprint) > 1:
        _number_objects(image, [frame.to_pixels(p) for p in footprint])
    return image


def _number_objects(image: np.ndarray, outlines_px: list[np.ndarray]) -> None:
    """Write 1, 2, ... (the object ids, in order) above each outline's top-left corner."""
    on_text_thread(_write_numbers, image, outlines_px)


def _write_numbers(image: np.ndarray, outlines_px: list[np.ndarray]) -> None:
    import cv2

    height, width = image.shape[:2]
    scale = max(0.45, min(width, height) / 700)
    thick = max(1, round(min(width, height) / 300))
    for number, outline in enumerate(outlines_px, start=1):
        label = str(number)
        (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        x0, y0 = outline.min(axis=0)
        x = int(np.clip(x0, 0, max(0, width - tw)))
        y = int(np.clip(y0 - 4, th, height - 1))
        for colour, extra in (((0, 0, 0), 2), ((255, 255, 255), 0)):
            cv2.putText(
                image, label, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick + extra,
                cv2.LINE_AA,
            )  # fmt: skip


def _paint_cuts(
    image: np.ndarray,
    sweeps: list[np.ndarray],
    footprint: np.ndarray | list[np.ndarray] | None,
    pixels: Any,
    width: int,
    shift: int,
) -> None:
    """Darken the union of the swept segments, clipped to the footprint(s), in place."""
    import cv2

    covered = np.zeros(image.shape[:2], np.uint8)
    for sweep in sweeps:
        segments = pixels(sweep.reshape(-1, 2)).reshape(-1, 2, 2)
        cv2.polylines(covered, list(segments), False, 255, width, cv2.LINE_AA, shift)
    # Only the covered pixels change (elsewhere the blend gives the pixel back exactly).
    rows, cols = np.nonzero(covered)
    alpha = covered[rows, cols].astype(np.float32) / 255.0
    if footprint is not None:
        inside = np.zeros(image.shape[:2], np.uint8)
        polygons = footprint if isinstance(footprint, list) else [footprint]
        cv2.fillPoly(inside, [pixels(p) for p in polygons], 255, cv2.LINE_AA, shift)
        alpha *= inside[rows, cols].astype(np.float32) / 255.0
    alpha = alpha[:, None]
    pixel = image[rows, cols]
    image[rows, cols] = np.round(pixel * (1.0 - alpha) + np.array(CUT_COLOUR) * alpha).astype(
        np.uint8
    )


class SimExecutor:
    """Kinematic replay with forward kinematics; writes outcome.png."""

    name = "sim"

    def __init__(self, options: SimOptions):
        self.options = options

    def execute(self, validated: ValidatedTrajectory, run: Run) -> ExecutionReport:
        from keymps.robot.model import RobotModel

        trajectory = require_validated(validated, self.name)
        task = run.task
        model = run.robot if run.robot is not None else RobotModel.from_task(task)
        tool_path = run.stages.compose
        result = replay(model, trajectory, self.options.replay_rate_hz)
        errors = tracking_errors(result, tool_path if isinstance(tool_path, ToolPath) else None)
        outline = _footprint(run)
        # Without the object's footprint a blade's reach cannot be clipped: cut with the tip.
        blade_length = model.tool.blade_length if outline is not None else 0.0
        tops = _object_tops(run, result)
        found = marks(result, tops, blade_length, knife=model.tool.blade_length > 0)
        clip = Footprint(outline) if outline is not None else None
        lengths = [covered_length(sweep, clip) for sweep in found.sweeps]
        figures = _figures(trajectory, result, errors, found, blade_length, lengths)
        files = [str(self._write_outcome(run, found, outline))] if self.options.image else []
        problems = _problems(found, figures)
        message = "; ".join(problems) if problems else _summary(found, trajectory, figures)
        measured = _measured(found, clip, tops, tool_path, result)
        return ExecutionReport(
            self.name, not problems, message, tuple(files), figures, measured=measured
        )

    def _write_outcome(self, run: Run, found: Marks, outline: list[np.ndarray] | None) -> Path:
        """outcome.png: the marks drawn on the run's picture, clipped to the objects' footprints."""
        scene = run.stages.image
        picture = scene.image if isinstance(scene, SceneImage) else None
        return run.write_image(
            "outcome",
            render_outcome(
                run.task,
                picture,
                found,
                self.options,
                outline,
                rectified=isinstance(scene, SceneImage) and scene.rectification is not None,
            ),
        )


def _figures(
    trajectory: Trajectory,
    result: Replay,
    errors: np.ndarray,
    found: Marks,
    blade_length: float,
    lengths: list[float],
) -> dict[str, float]:
    """The report's figures: duration, tracking error, depth, and what the tool left."""
    period = float(np.diff(result.t).mean()) if len(result.t) > 1 else 0.0
    return {
        "duration_s": trajectory.duration_s,
        "max_tracking_error_mm": float(errors.max() * 1000),
        "rms_tracking_error_mm": float(np.sqrt(np.mean(errors**2)) * 1000),
        "min_tool_z_mm": float(result.tool_xyz[:, 2].min() * 1000),
        "below_board_s": float(len(found.contacts) * period),
        "cuts": float(len(found.cuts)),
        "blade_length_mm": float(blade_length * 1000),
        "cut_length_mm": round(sum(lengths) * 1000, 1),
        **{f"cut_{k + 1}_length_mm": round(v * 1000, 1) for k, v in enumerate(lengths)},
        "icing_strokes": float(len(found.strokes)),
        "icing_length_mm": _length_mm(found.strokes),
        "icing_dots": float(len(found.dots)),
    }


def _summary(found: Marks, trajectory: Trajectory, figures: dict[str, float]) -> str:
    """One line for a replay without problems: what it made and its tracking error."""
    counts = [
        _count(len(found.cuts), "cut"),
        _count(len(found.strokes), "icing stroke"),
        _count(len(found.dots), "dot"),
    ]
    made = ", ".join(c for c in counts if not c.startswith("0 ")) or "no cut, stroke or dot"
    return (
        f"simulated {trajectory.duration_s:.1f} s: {made}; max tracking error "
        f"{figures['max_tracking_error_mm']:.3f} mm"
    )


def _problems(found: Marks, figures: dict[str, float]) -> list[str]:
    """What makes the replay fail: contact below the board, tracking error."""
    problems = []
    if len(found.contacts):
        problems.append(
            f"the tool touched below the board for {figures['below_board_s']:.3f} s "
            f"(lowest {figures['min_tool_z_mm']:.1f} mm)"
        )
    if figures["max_tracking_error_mm"] > TRACKING_LIMIT_M * 1000:
        problems.append(
            f"tracking error {figures['max_tracking_error_mm']:.2f} mm exceeds "
            f"{TRACKING_LIMIT_M * 1000:.1f} mm"
        )
    return problems


def _measured(
    found: Marks,
    clip: Footprint | None,
    tops: float | np.ndarray,
    tool_path: ToolPath | None,
    result: Replay,
) -> Effect:
    """Each cut's length through the food and depth, by the keypoint pair it was made for (a
    cut longer than the blade is two strokes of one pair: the length they cover together)."""
    made: dict[int, tuple[int, list[np.ndarray], float]] = {}
    for piece, sweep, lowest in zip(found.cut_pieces, found.sweeps, found.cut_lowest, strict=True):
        where = np.flatnonzero(result.piece_index == piece)[0]
        top = float(np.broadcast_to(np.asarray(tops, dtype=float), result.piece_index.shape)[where])
        owner = tool_path.pieces[piece] if isinstance(tool_path, ToolPath) else None
        pair = owner.pair_index if owner is not None else len(made)
        _, sweeps, deepest = made.get(pair, (1, [], 0.0))
        depth = float(np.clip(top - lowest, 0.0, top))
        object_id = owner.object_id if owner is not None else 1
        made[pair] = (object_id, [*sweeps, sweep], max(deepest, depth))
    cuts = [
        CutEffect(
            pair_index=pair,
            object_id=object_id,
            length_m=covered_length(np.concatenate(sweeps), clip),
            depth_m=depth,
        )
        for pair, (object_id, sweeps, depth) in made.items()
    ]
    return Effect(cuts=tuple(cuts))


def _count(number: int, noun: str) -> str:
    """'1 cut', '3 cuts'."""
    return f"{number} {noun}" if number == 1 else f"{number} {noun}s"


def _footprint(run: Run) -> list[np.ndarray] | None:
    """Every object's footprint in board metres, or None without a detection."""
    from keymps.perception.frames import object_outline_m
    from keymps.types import Detection

    if run.objects:
        return [np.asarray(o.outline_m, float) for o in run.objects]
    if run.outline_m is not None:
        return [run.outline_m]
    detection, scene = run.stages.detect, run.stages.image
    if not isinstance(detection, Detection) or not isinstance(scene, SceneImage):
        return None
    return [object_outline_m(detection, run.task, scene)]


def _object_tops(run: Run, result: Replay) -> float | np.ndarray:
    """The top of the object each replayed sample works on (scene.object_height without a
    grounding that knows the objects)."""
    tool_path = run.stages.compose
    if not run.objects or not isinstance(tool_path, ToolPath):
        return float(run.task.scene.object_height)
    heights = {o.id: o.height for o in run.objects}
    tallest = max(heights.values())
    per_piece = np.array([heights.get(p.object_id, tallest) for p in tool_path.pieces])
    index = np.clip(np.asarray(result.piece_index, dtype=int), 0, len(per_piece) - 1)
    return per_piece[index]


def _length_mm(lines: list[np.ndarray]) -> float:
    return float(sum(np.linalg.norm(np.diff(line, axis=0), axis=1).sum() for line in lines) * 1000)


def make_sim_executor(options: dict[str, Any]) -> SimExecutor:
    return SimExecutor(parse_options(SimOptions, options, "executor sim"))


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    register("sim", make_sim_executor)
