"""The independent safety check every trajectory passes before any executor runs it.

It trusts nothing the planner computed: it recomputes forward kinematics from the joint
samples, derives velocities, accelerations and jerks from the positions alone, and compares
with the tool path, the board, the object's footprint and the arm's limits. Only `validate`
issues ValidatedTrajectory objects; executors call `require_validated`, which refuses anything
else (a hand-built or modified one included).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from keymps.errors import SafetyError
from keymps.plugin.trajectories import issue as _issue
from keymps.robot.safety_geometry import distance_to_polylines, outside_distance, row_norms
from keymps.types import (
    GroundedObject,
    ToolPath,
    Trajectory,
    ValidatedTrajectory,
    ValidationReport,
)

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.robot.model import RobotModel

PATH_TOLERANCE_M = 0.0005
BOARD_TOLERANCE_M = 0.0005
FOOTPRINT_MARGIN_M = 0.02
"""Work may leave the outline by this much: a sawing stroke overshoots a cut's ends by ~15 mm."""
TILT_TOLERANCE_RAD = math.radians(0.5)
WORKSPACE_TOLERANCE_M = 0.001
"""The tool tip stays over the workspace (the board area the image shows) within this."""
ARM_CLEARANCE_M = 0.01
"""Elbow, wrists and flange stay this far above the board surface, and so does every part of
the arm's collision model (its links; not the base, not what only turns about the vertical
first joint, not the tool)."""
SELF_CLEARANCE_M = 0.0
"""The arm's links (convex hulls) stay apart from each other by this much."""
LIMIT_TOLERANCE = {"velocity": 1e-3, "acceleration": 0.01, "jerk": 0.05}
"""Relative slack on limits measured by finite differences (rounding, not physics)."""


def validate(
    model: RobotModel,
    trajectory: Trajectory,
    tool_path: ToolPath,
    outline_m: np.ndarray | Sequence[GroundedObject],
    task: Task,
) -> ValidatedTrajectory:
    """Check everything that can hurt the arm, the board or the food; raise SafetyError if not.

    `outline_m` is the object's footprint (board metres), or every object: then each work piece
    must stay on its own object (Piece.object_id), not merely on some object."""
    problems: list[str] = []
    figures: dict[str, float] = {}
    if not _check_structure(model, trajectory, tool_path, problems):
        raise SafetyError(problems)
    figures["duration_s"] = trajectory.duration_s
    figures["samples"] = float(trajectory.samples)
    check_joints(model, trajectory, problems, figures)
    positions, rotations, origins = model.tool_poses_and_joint_origins(
        np.asarray(trajectory.q, dtype=float)
    )
    _check_path(trajectory, tool_path, positions, problems, figures)
    check_board(trajectory, positions, rotations, origins, problems, figures)
    _check_collisions(model, trajectory, problems, figures)
    _check_footprint(trajectory, tool_path, positions, outline_m, problems, figures)
    check_workspace(trajectory, tool_path, positions, task, problems, figures)
    if problems:
        raise SafetyError(problems)
    return _issue(trajectory, ValidationReport(True, (), figures))


def _at(trajectory: Trajectory, index: int) -> str:
    return f"t={float(trajectory.t[min(index, len(trajectory.t) - 1)]):.3f} s"


def _check_structure(
    model: RobotModel, trajectory: Trajectory, tool_path: ToolPath, problems: list[str]
) -> bool:
    n, dof = len(trajectory.t), model.dof
    shapes = {
        "q": (n, dof),
        "qd": (n, dof),
        "qdd": (n, dof),
        "tool_xyz": (n, 3),
        "piece_index": (n,),
        "kind": (n,),
    }
    if n < 2:
        problems.append(f"the trajectory has {n} samples; at least 2 are needed")
    for name, shape in shapes.items():
        actual = np.shape(getattr(trajectory, name))
        if actual != shape:
            problems.append(f"trajectory.{name} has shape {actual}, expected {shape}")
    if problems:
        return False
    for name in ("t", "q", "qd", "qdd", "tool_xyz"):
        if not np.isfinite(np.asarray(getattr(trajectory, name), dtype=float)).all():
            problems.append(f"trajectory.{name} contains NaN or infinity")
    if tuple(trajectory.joint_names) != tuple(model.joint_names):
        problems.append(f"joint names {list(trajectory.joint_names)} are not the arm's")
    if not trajectory.rate_hz > 0:
        problems.append(f"rate_hz is {trajectory.rate_hz}")
    if problems:
        return False
    period = 1.0 / trajectory.rate_hz
    steps = np.diff(trajectory.t)
    if np.abs(steps - period).max() > 1e-6:
        worst = int(np.argmax(np.abs(steps - period)))
        problems.append(
            f"samples are not {period * 1000:.3f} ms apart (controller rate "
            f"{trajectory.rate_hz:g} Hz): {steps[worst] * 1000:.3f} ms at {_at(trajectory, worst)}"
        )
    pieces = len(tool_path.pieces)
    index = np.asarray(trajectory.piece_index)
    if index.min() < 0 or index.max() >= pieces:
        problems.append(f"piece_index outside the tool path's {pieces} pieces")
    else:
        expected = np.array([piece.kind for piece in tool_path.pieces])[index]
        if not np.array_equal(expected, np.asarray(trajectory.kind).astype(str)):
            problems.append("kind does not match the kinds of the tool path's pieces")
    return not problems


def check_joints(
    model: RobotModel, trajectory: Trajectory, problems: list[str], figures: dict[str, float]
) -> None:
    """Joint positions inside their limits, no jumps, velocity, acceleration and jerk (from the
    positions, and as reported) inside the arm's limits, at rest at both ends.

    Args:
        model: The arm and its joint limits.
        trajectory: The samples to check.
        problems: Extended with one line per problem found.
        figures: Updated with the largest ratio to each limit (`max_joint_*_ratio`).
    """
    q = np.asarray(trajectory.q, dtype=float)
    names = model.joint_names
    period = 1.0 / trajectory.rate_hz

    below, above = q < model.lower, q > model.upper
    for joint in range(model.dof):
        outside = np.flatnonzero(below[:, joint] | above[:, joint])
        if len(outside):
            i = int(outside[0])
            problems.append(
                f"{names[joint]} at {q[i, joint]:.3f} rad is outside its limits "
                f"[{model.lower[joint]:.2f}, {model.upper[joint]:.2f}] at {_at(trajectory, i)}"
            )

    velocity = np.diff(q, axis=0) / period
    acceleration = np.diff(velocity, axis=0) / period
    jerk = np.diff(acceleration, axis=0) / period
    step_limit = model.velocity_limits * period * 1.5
    jumps = np.abs(np.diff(q, axis=0)) > step_limit
    if jumps.any():
        i, joint = (int(v) for v in np.argwhere(jumps)[0])
        problems.append(
            f"{names[joint]} jumps by {abs(q[i + 1, joint] - q[i, joint]):.3f} rad between two "
            f"samples at {_at(trajectory, i)} (at most {step_limit[joint]:.3f} rad possible)"
        )
    checks = (
        ("velocity", "", velocity, model.velocity_limits, "rad/s"),
        ("velocity", " (as reported)", trajectory.qd, model.velocity_limits, "rad/s"),
        ("acceleration", "", acceleration, model.acceleration_limits, "rad/s^2"),
        ("acceleration", " (as reported)", trajectory.qdd, model.acceleration_limits, "rad/s^2"),
        ("jerk", "", jerk, model.jerk_limits, "rad/s^3"),
    )
    for quantity, source, values, limits, unit in checks:
        values = np.asarray(values, dtype=float)
        if not len(values):
            continue
        ratio = np.abs(values) / limits
        key = f"max_joint_{quantity}_ratio"
        figures[key] = max(figures.get(key, 0.0), float(ratio.max()))
        i, joint = (int(v) for v in np.unravel_index(int(np.argmax(ratio)), ratio.shape))
        if ratio[i, joint] > 1.0 + LIMIT_TOLERANCE[quantity]:
            problems.append(
                f"{names[joint]} {quantity}{source} {abs(values[i, joint]):.2f} {unit} exceeds "
                f"its limit {limits[joint]:.2f} {unit} at {_at(trajectory, i)}"
            )
    for label, row in (("start", 0), ("end", -1)):
        if np.abs(trajectory.qd[row]).max() > 1e-6:
            problems.append(f"the arm is not at rest at the {label} (joint velocity not zero)")


def _check_path(
    trajectory: Trajectory,
    tool_path: ToolPath,
    positions: np.ndarray,
    problems: list[str],
    figures: dict[str, float],
) -> None:
    off_plan = row_norms(positions - trajectory.tool_xyz)
    polylines = [np.asarray(piece.points) for piece in tool_path.pieces]
    off_path = distance_to_polylines(positions, trajectory.piece_index, polylines)
    figures["max_deviation_from_tool_path_mm"] = float(off_path.max() * 1000)
    figures["max_deviation_from_planned_samples_mm"] = float(off_plan.max() * 1000)
    for label, error in (("tool path", off_path), ("planned tool positions", off_plan)):
        if error.max() > PATH_TOLERANCE_M:
            i = int(np.argmax(error))
            problems.append(
                f"the tool leaves the {label} by {error[i] * 1000:.2f} mm (at most "
                f"{PATH_TOLERANCE_M * 1000:.1f} mm) at {_at(trajectory, i)}, piece "
                f"{int(trajectory.piece_index[i])}"
            )


def check_board(
    trajectory: Trajectory,
    positions: np.ndarray,
    rotations: np.ndarray,
    origins: np.ndarray,
    problems: list[str],
    figures: dict[str, float],
) -> None:
    """The tool tip stays above the board and points down; the arm keeps its clearance.

    Args:
        trajectory: The samples (named in the problems).
        positions: (n, 3) the tool tip per sample, board frame, metres.
        rotations: (n, 3, 3) the tool's orientation per sample.
        origins: (n, joints, 3) the joints' origins per sample, board frame, metres.
        problems: Extended with one line per problem found.
        figures: Updated with the lowest tool and arm points (mm) and the largest tilt (deg).
    """
    z = positions[:, 2]
    figures["min_tool_z_mm"] = float(z.min() * 1000)
    if z.min() < -BOARD_TOLERANCE_M:
        i = int(np.argmin(z))
        problems.append(
            f"the tool tip goes {-z[i] * 1000:.1f} mm below the board surface at "
            f"{_at(trajectory, i)}, board point ({positions[i, 0]:.3f}, {positions[i, 1]:.3f})"
        )
    tilt = np.arccos(np.clip(-rotations[:, 2, 2], -1.0, 1.0))
    figures["max_tool_tilt_deg"] = float(np.degrees(tilt.max()))
    if tilt.max() > TILT_TOLERANCE_RAD:
        i = int(np.argmax(tilt))
        problems.append(
            f"the tool tilts {math.degrees(tilt[i]):.1f} degrees from straight down at "
            f"{_at(trajectory, i)}"
        )
    lowest, lowest_at = _lowest_arm_point(origins)
    figures["min_arm_z_mm"] = lowest * 1000
    if lowest < ARM_CLEARANCE_M:
        problems.append(
            f"the arm comes within {lowest * 1000:.0f} mm of the board surface at "
            f"{_at(trajectory, lowest_at)}: move the base (task robot.base)"
        )


def _lowest_arm_point(origins: np.ndarray) -> tuple[float, int]:
    """The lowest height of the joints after the second (a UR's elbow and wrists) and the
    tool mount over every sample (`origins`: each sample's joint origins and tool mount,
    (n, dof + 1, 3)), and its index."""
    heights = origins[:, 2:, 2].min(axis=1)  # joint origins 2..6 and the flange
    index = int(np.argmin(heights))
    return float(heights[index]), index


def _check_collisions(
    model: RobotModel, trajectory: Trajectory, problems: list[str], figures: dict[str, float]
) -> None:
    """The arm's collision model (keymps.robot.collision) against the board's plane and itself,
    at samples close enough together that nothing between them can come nearer unseen."""
    clearances = model.clearances()
    q = np.asarray(trajectory.q, dtype=float)
    picked, board, apart, closest = clearances.distances(q)
    padding = model.spec.collision_padding
    if len(board) and np.isfinite(board).any():
        i = int(np.argmin(board))
        figures["min_arm_board_clearance_mm"] = float(board[i] * 1000)
        if board[i] < ARM_CLEARANCE_M + padding:
            problems.append(
                f"the arm ({model.label}'s collision model) comes within "
                f"{max(board[i], 0.0) * 1000:.0f} mm of the board surface at "
                f"{_at(trajectory, int(picked[i]))} (at least "
                f"{(ARM_CLEARANCE_M + padding) * 1000:.0f} mm): move the base (task robot.base)"
            )
    if len(apart) and np.isfinite(apart).any():
        i = int(np.argmin(apart))
        figures["min_self_clearance_mm"] = float(apart[i] * 1000)
        if apart[i] < SELF_CLEARANCE_M + padding:
            problems.append(
                f"the arm would hit itself ({closest[i]}) at {_at(trajectory, int(picked[i]))}: "
                "move the base (task robot.base)"
            )


def _check_footprint(
    trajectory: Trajectory,
    tool_path: ToolPath,
    positions: np.ndarray,
    outline_m: np.ndarray | Sequence[GroundedObject],
    problems: list[str],
    figures: dict[str, float],
) -> None:
    footprints: dict[int | None, tuple[str, np.ndarray]]
    if isinstance(outline_m, np.ndarray) or not all(
        isinstance(o, GroundedObject) for o in outline_m
    ):
        footprints = {None: ("the object's", np.asarray(outline_m, dtype=float).reshape(-1, 2))}
    elif len(outline_m) == 1:  # one object: the same words as with a bare footprint
        footprints = {None: ("the object's", np.asarray(outline_m[0].outline_m, float))}
    else:
        footprints = {
            o.id: (f"object {o.label}'s", np.asarray(o.outline_m, float)) for o in outline_m
        }
    for what, outline in footprints.values():
        if len(outline) < 3:
            problems.append(f"{what} footprint has {len(outline)} points; work cannot be checked")
            return
    piece_object = [p.object_id if p.kind == "work" else -1 for p in tool_path.pieces]
    kind = np.asarray(trajectory.kind)
    index = np.asarray(trajectory.piece_index, dtype=int)
    worst = 0.0
    for key, (what, outline) in footprints.items():
        if key is None:
            mine = kind == "work"
            planned = [np.asarray(p.points)[:, :2] for p in tool_path.pieces if p.kind == "work"]
        else:
            owners = np.array(
                [piece_object[i] if 0 <= i < len(piece_object) else -1 for i in index]
            )
            mine = (kind == "work") & (owners == key)
            planned = [
                np.asarray(p.points)[:, :2]
                for p in tool_path.pieces
                if p.kind == "work" and p.object_id == key
            ]
        if not mine.any() and not planned:
            continue
        samples = np.concatenate([positions[mine, :2], *planned])
        outside = outside_distance(samples, outline)
        worst = max(worst, float(outside.max()))
        if outside.max() > FOOTPRINT_MARGIN_M:
            i = int(np.argmax(outside))
            problems.append(
                f"work leaves {what} footprint by {outside[i] * 1000:.0f} mm (at most "
                f"{FOOTPRINT_MARGIN_M * 1000:.0f} mm) at board point ({samples[i, 0]:.3f}, "
                f"{samples[i, 1]:.3f})"
            )
    figures["max_work_outside_footprint_mm"] = worst * 1000


def check_workspace(
    trajectory: Trajectory,
    tool_path: ToolPath,
    positions: np.ndarray,
    task: Task,
    problems: list[str],
    figures: dict[str, float],
) -> None:
    """The tool tip never leaves the area the camera saw (scene.workspace, board frame).

    Args:
        trajectory: The samples (named in the problems).
        tool_path: The planned pieces (a problem names the piece).
        positions: (n, 3) the tool tip per sample, board frame, metres.
        task: The task (its scene.workspace).
        problems: Extended with one line per problem found.
        figures: Updated with how far the tip leaves the workspace (`max_outside_workspace_mm`).
    """
    workspace = task.scene.workspace
    low = np.asarray(workspace.shift, dtype=float)
    high = low + np.asarray(workspace.size, dtype=float)
    xy = positions[:, :2]
    outside = np.maximum(low - xy, xy - high).max(axis=1)
    figures["max_outside_workspace_mm"] = float(max(outside.max(), 0.0) * 1000)
    if outside.max() > WORKSPACE_TOLERANCE_M:
        i = int(np.argmax(outside))
        problems.append(
            f"the tool leaves the workspace (scene.workspace, the board area the image shows) by "
            f"{outside[i] * 1000:.1f} mm at {_at(trajectory, i)}, board point ({xy[i, 0]:.3f}, "
            f"{xy[i, 1]:.3f}), {_workspace_hint(tool_path, int(trajectory.piece_index[i]))}"
        )


def _workspace_hint(tool_path: ToolPath, index: int) -> str:
    """Which pair left the workspace. Keypoints are inside the image, so a work piece leaves it
    only where its primitive reaches past the pair's ends (a sawing stroke at the edge)."""
    piece = tool_path.pieces[index]
    if piece.kind != "work":
        return f"on the travel move to pair {piece.pair_index + 1}"
    return (
        f"during {piece.pairs_label()}: primitive {tool_path.keyword!r} reaches past the "
        "pair's ends (leave more board around the object, or choose a primitive without strokes)"
    )
