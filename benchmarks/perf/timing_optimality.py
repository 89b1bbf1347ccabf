"""keymps timing (jerk-limited Ruckig per stroke) against time-optimal TOPP-RA on the same paths.

    pip install toppra
    python benchmarks/perf/timing_optimality.py [tasks/*.yaml]

For every shipped task (default: tasks/*.yaml) the pipeline runs with the offline planner and
the sim executor. On each stroke keymps timed (the same q(s) joint path, split at the same
corners and rests), TOPP-RA computes the time-optimal duration under the same joint velocity and
acceleration limits and the same tool speed and tool acceleration limits (a pseudo-joint s with
the piece's speed and task.robot.max_tool_acceleration), but without any jerk limit, so it is a
lower bound. Reported per task: both durations and their ratio, the largest distance of the
executed tool tip (FK of the trajectory) from the tool path, and the time of every stage. The
last lines are machine-readable `name: value` pairs for the worst task.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from keymps.run import RunOptions, RunOverrides

REPO = Path(__file__).resolve().parents[2]
PLANNING_STAGES = ("image", "detect", "ground", "compose", "solve", "time", "check")
"""Every stage but the VLM ('plan') and the executor."""


def toppra_duration(model: Any, stroke: Any, tool_acceleration: float) -> float:
    """Time-optimal (no jerk limit) duration of one rest-to-rest stroke."""
    import toppra
    import toppra.algorithm as algorithm
    import toppra.constraint as constraint

    knots = np.asarray(stroke.q_of_s.x)
    waypoints = np.column_stack([stroke.q_of_s(knots), knots])  # joints + the path parameter
    path = toppra.SplineInterpolator(knots, waypoints)
    speed = np.append(model.velocity_limits, stroke.speed)
    acceleration = np.append(model.acceleration_limits, tool_acceleration)
    constraints = [
        constraint.JointVelocityConstraint(np.column_stack([-speed, speed])),
        constraint.JointAccelerationConstraint(
            np.column_stack([-acceleration, acceleration]),
            discretization_scheme=constraint.DiscretizationType.Interpolation,
        ),
    ]
    gridpoints = np.linspace(knots[0], knots[-1], max(50, int(knots[-1] / 0.0005) + 1))
    instance = algorithm.TOPPRA(
        constraints, path, gridpoints=gridpoints, parametrizer="ParametrizeConstAccel"
    )
    result = instance.compute_trajectory(0, 0)
    if result is None:
        raise RuntimeError(f"TOPP-RA failed on a stroke of piece {stroke.piece_index}")
    return float(result.duration)


def measure(
    task_path: Path, tool_jerk: float | None = None, joint_jerk: float | None = None
) -> dict[str, Any]:
    from keymps import load_task, run_task
    from keymps.config.task import PluginSection
    from keymps.motion.timing import split_strokes

    task = load_task(task_path)
    # the sim executor without the task's own executor options (sim_cutting.yaml's are MuJoCo's)
    task = task.model_copy(update={"executor": PluginSection(name="sim")})
    changes = {"max_tool_jerk": tool_jerk, "max_joint_jerk": joint_jerk}
    changes = {key: value for key, value in changes.items() if value is not None}
    if changes:
        task = task.model_copy(update={"robot": task.robot.model_copy(update=changes)})
    with tempfile.TemporaryDirectory() as folder:
        run = run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=folder, backend="offline"),
        )
    tool_path, joint_path = run.stages.compose, run.stages.solve
    trajectory, validated = run.stages.time, run.stages.check
    from keymps.robot.model import RobotModel

    model = RobotModel.from_task(task)
    strokes = split_strokes(model, tool_path, joint_path)
    started = time.perf_counter()
    optimal = sum(toppra_duration(model, s, task.robot.max_tool_acceleration) for s in strokes)
    toppra_s = time.perf_counter() - started
    stages = {name: run.timings_s.get(name, 0.0) for name in PLANNING_STAGES}
    return {
        "task": task.name,
        "strokes": len(strokes),
        "keymps_s": trajectory.duration_s,
        "toppra_s": optimal,
        "ratio": trajectory.duration_s / optimal,
        "deviation_mm": validated.report.figures["max_deviation_from_tool_path_mm"],
        "stages": stages,
        "planning_s": sum(stages.values()),
        "toppra_compute_s": toppra_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("tasks", nargs="*", type=Path)
    parser.add_argument(
        "--max-tool-jerk",
        type=float,
        default=None,
        help="override the tasks' robot.max_tool_jerk (m/s^3) to see what the jerk limit costs",
    )
    parser.add_argument(
        "--max-joint-jerk",
        type=float,
        default=None,
        help="override the tasks' robot.max_joint_jerk (rad/s^3)",
    )
    parser.add_argument(
        "--quick", action="store_true", help="the icing task alone: checks the script runs (CI)"
    )
    args = parser.parse_args()
    try:
        import toppra  # noqa: F401
    except ImportError:
        sys.exit("this benchmark needs TOPP-RA: pip install toppra")
    if args.quick and not args.tasks:
        args.tasks = [REPO / "tasks" / "cake_icing.yaml"]
    tasks = args.tasks or sorted((REPO / "tasks").glob("*.yaml"))
    results = [measure(path, args.max_tool_jerk, args.max_joint_jerk) for path in tasks]

    print(
        f"{'task':16s} {'strokes':>7s} {'keymps s':>9s} {'TOPP-RA s':>9s} {'ratio':>6s} "
        f"{'dev mm':>7s} {'plan s':>7s}"
    )
    for r in results:
        print(
            f"{r['task']:16s} {r['strokes']:7d} {r['keymps_s']:9.2f} {r['toppra_s']:9.2f} "
            f"{r['ratio']:6.3f} {r['deviation_mm']:7.4f} {r['planning_s']:7.3f}"
        )
    print()
    print("stage times (s): " + " ".join(f"{name:>8s}" for name in PLANNING_STAGES))
    for r in results:
        print(f"{r['task']:16s} " + " ".join(f"{r['stages'][n]:8.3f}" for n in PLANNING_STAGES))
    print()
    worst = max(results, key=lambda r: r["ratio"])
    print(f"worst_task: {worst['task']}")
    print(f"duration_ratio_vs_toppra: {max(r['ratio'] for r in results):.4g}")
    print(f"max_deviation_mm: {max(r['deviation_mm'] for r in results):.4g}")
    print(f"planning_s: {max(r['planning_s'] for r in results):.4g}")


if __name__ == "__main__":
    main()
