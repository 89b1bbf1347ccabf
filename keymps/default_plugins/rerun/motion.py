"""The motion side of a Rerun recording: the tool path, the joint and speed series, the tool tip."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.default_plugins.rerun.entities import time_colors

if TYPE_CHECKING:
    from keymps.types import ToolPath, Trajectory

WORK_RADIUS_M = 0.0015
TRAVEL_RADIUS_M = 0.0006
TRAVEL_ALPHA = 90
JOINT_COLORS = (
    (31, 119, 180, 255),
    (255, 127, 14, 255),
    (44, 160, 44, 255),
    (214, 39, 40, 255),
    (148, 103, 189, 255),
    (23, 190, 207, 255),
)
"""One line colour per joint in the joint plots (the viewer's own palette is per entity)."""
GRADIENT_CHUNK_POINTS = 12
"""Work pieces are drawn as short strips of this many points, each in its own time colour."""


def piece_time_fractions(tool_path: ToolPath) -> list[np.ndarray]:
    """Per piece, each point's share of the total (estimated) execution time in [0, 1]."""
    times = []
    offset = 0.0
    for piece in tool_path.pieces:
        steps = np.linalg.norm(np.diff(piece.points, axis=0), axis=1)
        along = np.concatenate([[0.0], np.cumsum(steps)]) / max(piece.speed, 1e-6)
        times.append(offset + along)
        offset += float(along[-1]) if len(along) else 0.0
    total = max(offset, 1e-9)
    return [t / total for t in times]


def _gradient_strips(
    points: np.ndarray, fractions: np.ndarray, chunk: int
) -> tuple[list[np.ndarray], list[float]]:
    """Split a polyline into short overlapping strips, each with its mid-time fraction."""
    if len(points) < 2:
        return [points], [float(fractions[0]) if len(fractions) else 0.0]
    strips, mids = [], []
    for start in range(0, len(points) - 1, chunk):
        stop = min(start + chunk, len(points) - 1)
        strips.append(points[start : stop + 1])
        mids.append(float(fractions[(start + stop) // 2]))
    return strips, mids


def log_tool_path(rec: Any, tool_path: ToolPath) -> None:
    import rerun as rr

    fractions = piece_time_fractions(tool_path)
    for kind, radius, alpha in (
        ("work", WORK_RADIUS_M, 255),
        ("travel", TRAVEL_RADIUS_M, TRAVEL_ALPHA),
    ):
        strips: list[np.ndarray] = []
        mids: list[float] = []
        for piece, piece_fractions in zip(tool_path.pieces, fractions, strict=True):
            if piece.kind != kind:
                continue
            chunk = GRADIENT_CHUNK_POINTS if kind == "work" else max(len(piece.points), 2)
            piece_strips, piece_mids = _gradient_strips(piece.points, piece_fractions, chunk)
            strips.extend(piece_strips)
            mids.extend(piece_mids)
        if strips:
            rec.log(
                f"world/tool_path/{kind}",
                rr.LineStrips3D(
                    strips,
                    colors=time_colors(np.array(mids), alpha=alpha),
                    radii=[radius],
                ),
            )


def subsample_indices(t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of samples about 1/rate_hz apart, always keeping the first and the last."""
    if len(t) == 0:
        return np.zeros(0, dtype=int)
    targets = np.arange(t[0], t[-1], 1.0 / rate_hz)
    picked = np.searchsorted(t, targets)
    return np.unique(np.concatenate([picked, [len(t) - 1]]).clip(0, len(t) - 1))


def tool_speed(trajectory: Trajectory) -> np.ndarray:
    """Tool-tip speed along the trajectory, m/s (from the planned tool positions)."""
    if trajectory.samples < 2:
        return np.zeros(trajectory.samples)
    velocity = np.gradient(trajectory.tool_xyz, trajectory.t, axis=0)
    return np.asarray(np.linalg.norm(velocity, axis=1), dtype=float)


def log_trajectory(rec: Any, trajectory: Trajectory, stage_index: int, rate_hz: float) -> None:
    """Joint and tool-speed series at full rate; the tool tip animated at rate_hz."""
    import rerun as rr

    t = np.asarray(trajectory.t, dtype=float)
    time_column = rr.TimeColumn("time", duration=t)
    # One entity per quantity, one component per joint: the viewer draws a named line per
    # joint, and the file pays the row ids and times once instead of six times.
    for group, values, unit in (("q", trajectory.q, "rad"), ("qd", trajectory.qd, "rad/s")):
        rec.log(
            f"joints/{group}",
            rr.SeriesLines(
                names=[f"{name} [{unit}]" for name in trajectory.joint_names],
                colors=[JOINT_COLORS[i % len(JOINT_COLORS)] for i in range(len(values[0]))],
            ),
            static=True,
        )
        rec.send_columns(
            f"joints/{group}",
            indexes=[time_column],
            columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)).partition(
                np.full(len(t), len(trajectory.joint_names))
            ),
        )
    rec.send_columns(
        "tool/speed",
        indexes=[time_column],
        columns=rr.Scalars.columns(scalars=tool_speed(trajectory)),
    )
    rec.log("tool/speed", rr.SeriesLines(names=["tool speed [m/s]"]), static=True)
    picked = subsample_indices(t, rate_hz)
    kinds = np.asarray(trajectory.kind)[picked]
    colors = np.where(
        (kinds == "work")[:, None], [[255, 255, 255, 255]], [[120, 120, 120, 255]]
    ).astype(np.uint8)
    rec.send_columns(
        "world/tool_tip",
        indexes=[
            rr.TimeColumn("time", duration=t[picked]),
            rr.TimeColumn("stage", sequence=np.full(len(picked), stage_index)),
        ],
        columns=rr.Points3D.columns(
            positions=trajectory.tool_xyz[picked], colors=colors, radii=np.full(len(picked), 0.004)
        ),
    )
