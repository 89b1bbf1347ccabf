"""What a timed trajectory does to the food, predicted before anything moves.

The joints of the timed trajectory go through forward kinematics: the tool tip and its x axis
at every work sample. A knife's edge is a horizontal segment at the tip's height reaching
`blade_length` from the tip along the tool's -x axis (its yaw as the wrist turns it, not as the
cut's direction would suggest): below the object's top it cuts; where it lies on the board
inside the food, the food is cut through, and the pieces are the regions those stretches leave
(keymps.outcome.pieces). A piping nozzle deposits where it works within DEPOSIT_GAP_M of the
object's top: a dot (a disc of DOT_DIAMETER_FACTOR line widths) where it stays in place, else a
line (a band of the line width) along its path (keymps.outcome.deposits).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from keymps.outcome.cut_sweep import Footprint, Stretches, covered_stretches, edge_samples
from keymps.outcome.deposits import deposits_of
from keymps.outcome.pieces import CRUMB_FRACTION, Regions
from keymps.robot.safety_geometry import row_norms
from keymps.sorted_values import distinct
from keymps.types import CutEffect, Effect, PieceEffect, ToolPath, Trajectory

if TYPE_CHECKING:
    from keymps.robot.model import RobotModel

BELOW_TOP_M = 1e-4
"""The edge cuts where the tip is this far below the object's top."""
SEVER_HEIGHT_M = 0.001
"""The edge cuts the food through where the tip passes within this of the board (the MuJoCo
executor's "reached the board")."""
PARTING_M = 0.0015
"""A cut whose end comes this close to the object's edge or to another cut parts the pieces
there (a blade about a millimetre thick; the footprint is measured to half a pixel)."""
PIECE_RESOLUTION_M = 0.00025
"""Raster cell of the predicted pieces: a barrier takes 0.25 mm times its length from the pieces
it divides alike (the shares are of the pieces' own sum), and a piece's area is within about
0.5 % of its outline's for a 2 cm wide one; about 10 ms for a 15 cm pizza."""


@dataclass(frozen=True)
class Food:
    """One object as the prediction sees it: its id, its top's height and its footprint."""

    id: int
    height: float
    """Its top surface above the board, metres."""
    outline_m: np.ndarray
    """(N, 2) its footprint in the board frame, metres."""


@dataclass(frozen=True)
class Tool:
    """What the tool does to food: a knife's blade, or a nozzle's line."""

    cuts: bool
    """True for a cutting tool (its work goes into the food), False for icing."""
    blade_length: float = 0.0
    """Metres of edge behind the tip along the tool's -x axis (0: it cuts with its tip)."""
    line_width: float = 0.0
    """Width of the icing line, metres."""


def predict(
    model: RobotModel,
    trajectory: Trajectory,
    tool_path: ToolPath,
    foods: Sequence[Food],
    tool: Tool,
) -> Effect:
    """The cuts and pieces (a cutting tool) or the deposits (icing) of the trajectory's work."""
    work = np.flatnonzero(np.asarray(trajectory.kind) == "work")
    if len(work) == 0:
        return Effect()
    positions, x_axes = model.tool_positions_and_x_axes(np.asarray(trajectory.q, float)[work])
    pieces = np.asarray(trajectory.piece_index)[work]
    by_id = {food.id: food for food in foods}
    runs = [
        (tool_path.pieces[int(index)], pieces == index)
        for index in distinct(pieces)
        if tool_path.pieces[int(index)].kind == "work"
    ]
    if not tool.cuts:
        deposits, strokes, loops = deposits_of(
            [
                (piece.piped_pairs, by_id.get(piece.object_id), positions[rows])
                for piece, rows in runs
            ],
            tool.line_width,
        )
        return Effect(deposits=deposits, strokes=strokes, loops=loops)
    prints = {food.id: Footprint(food.outline_m) for food in foods}
    by_pair: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    owners: dict[int, Food] = {}
    for piece, rows in runs:  # a cut longer than the blade is cut from both ends: one cut
        owners[piece.pair_index] = by_id.get(piece.object_id) or foods[0]
        blade = -_unit(x_axes[rows, :2])  # the edge, from the tip along the tool's -x axis
        by_pair.setdefault(piece.pair_index, []).append((positions[rows], blade))
    cuts = [
        _cut(pair, owners[pair], prints[owners[pair].id], tips, tool.blade_length)
        for pair, tips in by_pair.items()
    ]
    return Effect(cuts=tuple(cuts), pieces=_pieces(cuts, foods))


def _cut(
    pair_index: int,
    food: Food,
    footprint: Footprint,
    strokes: Sequence[tuple[np.ndarray, np.ndarray]],
    blade_length: float,
) -> CutEffect:
    """One pair's cut, from its strokes' (tip (n, 3), edge direction (n, 2)) samples: its
    length through the food, its depth, where it cuts through."""
    taken_segments, taken_on_board = [], []
    for tip, blade in strokes:
        below = np.flatnonzero(tip[:, 2] < food.height - BELOW_TOP_M)
        if len(below) >= 2:
            taken, segments = edge_samples(tip[below], blade[below], blade_length)
            taken_segments.append(segments)
            taken_on_board.append(tip[below[taken], 2] <= SEVER_HEIGHT_M)
    through = severed = swept = None
    if taken_segments:
        segments, on_board = np.concatenate(taken_segments), np.concatenate(taken_on_board)
        through = covered_stretches(segments, footprint)
        severed = through.of(on_board) if through is not None else None
        swept = covered_stretches(segments[on_board], None) if severed is not None else None
    lowest = min(float(tip[:, 2].min()) for tip, _ in strokes)
    return CutEffect(
        pair_index=pair_index,
        object_id=food.id,
        length_m=through.length_m if through is not None else 0.0,
        depth_m=float(np.clip(food.height - lowest, 0.0, food.height)),
        severed_m=severed.segments() if severed is not None else np.zeros((0, 2, 2)),
        chord_m=chord_length(food.outline_m, through) if through is not None else 0.0,
        swept_m=swept.segments() if swept is not None else np.zeros((0, 2, 2)),
    )


def chord_length(outline_m: np.ndarray, line: Stretches) -> float:
    """Metres of the cut's line inside the outline, over the parts of it the cut reaches into:
    every inside stretch of the line that the covered intervals overlap."""
    inside = line_inside(outline_m, line.origin, line.axis)
    ends = line.segments()
    along = (ends.reshape(-1, 2) - line.origin) @ line.axis
    low, high = float(along.min()), float(along.max())
    overlapping = inside[(inside[:, 1] > low) & (inside[:, 0] < high)]
    return float((overlapping[:, 1] - overlapping[:, 0]).sum())


def line_inside(outline_m: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(m, 2) the intervals [t0, t1] of the line origin + t axis inside the polygon, ascending."""
    polygon = np.asarray(outline_m, float).reshape(-1, 2)
    a, b = polygon, np.roll(polygon, -1, axis=0)
    normal = np.array([-axis[1], axis[0]])
    side_a, side_b = (a - origin) @ normal, (b - origin) @ normal
    crossing = (side_a > 0) != (side_b > 0)
    fraction = side_a[crossing] / (side_a[crossing] - side_b[crossing])
    hits = a[crossing] + fraction[:, None] * (b[crossing] - a[crossing])
    t = np.sort((hits - origin) @ axis)
    return t[: len(t) // 2 * 2].reshape(-1, 2)


def _pieces(cuts: list[CutEffect], foods: Sequence[Food]) -> tuple[PieceEffect, ...]:
    """The pieces each cut object is left in (an object the work reaches but does not cut
    through is one piece)."""
    found: list[PieceEffect] = []
    for food in foods:
        mine = [cut for cut in cuts if cut.object_id == food.id]
        if not mine:
            continue
        lines = np.concatenate([cut.severed_m for cut in mine]).reshape(-1, 2, 2)
        regions = Regions(food.outline_m, lines, None, PIECE_RESOLUTION_M, PARTING_M)
        # shares of the regions' sum: the barriers' cells (a cell along every cut) belong to
        # no piece, and would make every piece smaller than its share alike
        total = float(regions.areas_m2.sum())
        for region in np.argsort(-regions.areas_m2, kind="stable"):
            area = float(regions.areas_m2[region])
            if area >= CRUMB_FRACTION * total:
                share = area / total if total > 0 else 0.0
                found.append(PieceEffect(food.id, area, share, regions.outline(int(region))))
    return tuple(found)


def _unit(vectors: np.ndarray) -> np.ndarray:
    norms = row_norms(vectors)[:, None]
    return np.divide(vectors, norms, out=np.zeros_like(vectors), where=norms > 1e-9)
