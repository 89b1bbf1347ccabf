"""Inverse kinematics of every built-in arm on random board poses, against pin-pink and ikpy.

    pip install pin-pink daqp ikpy        # the `bench` extra
    python benchmarks/perf/ik_arms.py [--poses 1000] [--arms ur3,panda,...] [--quick]

Per arm, `--poses` random tool poses over the arm's default board area (the tool pointing
down, a random yaw, the tip at random heights): keymps' solver (the closed form on the UR
arms, keymps.robot.iterative_ik on the others; on the UR arms the iterative one too), pin-pink
(differential IK, a QP per step with daqp, iterated to convergence) and ikpy (scipy least
squares on the URDF chain) each solve every pose from the arm's home configuration. Pinocchio's
forward kinematics of the arm keymps plans with judges every answer: a success is within
0.1 mm and 0.1 degree of the pose, inside the joint limits. Reported per arm and solver:
success rate, worst position and orientation error of the successes, time per pose; then the
targets: the closed form at least 100x faster than the best peer with errors below 1e-9 m,
the iterative IK at least as successful as the best peer on the Panda and the SO-101 and no
slower. The last lines are machine-readable `name: value` pairs.
"""

from __future__ import annotations

import os

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

ARMS = ("ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e", "ur20", "panda", "so101")
QUICK_ARMS = ("ur5e", "panda", "so101")
POSITION_OK_M = 1e-4
ROTATION_OK_RAD = math.radians(0.1)
REGIONS = {"so101": ((0.05, 0.25), (0.0, 0.10), (0.0, 0.04))}
"""x, y, z ranges of the poses (board metres) where the default (whole board, z 0-12 cm) is
beyond an arm (the SO-101 reaches 10-30 cm from its base, 10 cm raised, a 10 cm knife)."""


@dataclass
class Outcome:
    """One solver on one arm's poses."""

    solved: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    seconds_per_pose: float

    def line(self, name: str) -> str:
        ok = self.solved
        worst_p = float(self.position_error[ok].max()) if ok.any() else math.nan
        worst_r = float(self.rotation_error[ok].max()) if ok.any() else math.nan
        return (
            f"  {name:<10} success {ok.mean() * 100:6.1f} %   worst {worst_p:9.2e} m "
            f"{math.degrees(worst_r):9.2e} deg   {self.seconds_per_pose * 1e6:10.1f} us/pose"
        )


def _require_peers() -> tuple[Any, Any]:
    try:
        import ikpy.chain
        import pink
    except ImportError as error:
        sys.exit(
            f"this benchmark needs the peer libraries ({error.name} is missing):\n"
            "    pip install pin-pink daqp ikpy    (the bench extra; keymps does not need them)"
        )
    return pink, ikpy.chain


def board_poses(robot: Any, count: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(count, 3) tip positions and (count,) yaws over the arm's board region."""
    width, height = robot.board_size
    x, y, z = REGIONS.get(robot.model_name, ((0.0, width), (0.0, height), (0.0, 0.12)))
    low, high = np.array([x[0], y[0], z[0]]), np.array([x[1], y[1], z[1]])
    return low + rng.random((count, 3)) * (high - low), rng.uniform(-math.pi, math.pi, count)


def judge(
    robot: Any, qs: np.ndarray, points: np.ndarray, yaws: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Pinocchio's verdict on joint vectors (NaN rows: no answer): solved, errors."""
    from keymps.robot.model import rotation_angles, tool_poses_down

    answered = ~np.isnan(qs).any(axis=1)
    position_error = np.full(len(qs), np.inf)
    rotation_error = np.full(len(qs), np.inf)
    if answered.any():
        positions, rotations = robot.pinocchio_tool_poses(qs[answered])
        targets = tool_poses_down(points[answered], yaws[answered])
        position_error[answered] = np.linalg.norm(positions - points[answered], axis=1)
        rotation_error[answered] = rotation_angles(rotations, targets[:, :3, :3])
    inside = answered.copy()
    inside[answered] = np.all((qs[answered] >= robot.lower - 1e-9)
                              & (qs[answered] <= robot.upper + 1e-9), axis=1)  # fmt: skip
    solved = inside & (position_error <= POSITION_OK_M) & (rotation_error <= ROTATION_OK_RAD)
    return solved, position_error, rotation_error


def timed(solve: Callable[[], np.ndarray], count: int) -> tuple[np.ndarray, float]:
    started = time.perf_counter()
    qs = solve()
    return qs, (time.perf_counter() - started) / count


def keymps_closed_form(robot: Any, points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """Every analytic branch at once; per pose the one nearest the home configuration."""
    from keymps.robot.model import _nearest_turn, tool_poses_down

    branches = robot.closed_form.solve(tool_poses_down(points, yaws))
    home = robot.arm_model.home
    near = _nearest_turn(branches, home)
    inside = np.all((near >= robot.lower) & (near <= robot.upper), axis=2)
    distance = np.where(inside, np.abs(near - home).max(axis=2), np.inf)
    distance = np.where(np.isnan(distance), np.inf, distance)
    best = np.argmin(distance, axis=1)
    chosen = near[np.arange(len(points)), best]
    chosen[~np.isfinite(distance.min(axis=1))] = np.nan
    return chosen


def keymps_iterative(robot: Any, points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """keymps.robot.iterative_ik from the home configuration turned towards each point."""
    from keymps.robot.description import tool_rotation

    out = np.full((len(points), robot.dof), np.nan)
    for i, (point, yaw) in enumerate(zip(points, yaws, strict=True)):
        seeds = robot._seeds_towards(point)
        result = robot.solver.solve_from_anywhere(point, tool_rotation(yaw), seeds, tries=8)
        out[i] = result.q
    return out


def pink_solver(pink: Any, robot: Any) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """pin-pink: a FrameTask on the tool tip, QP steps (daqp) from home until converged."""
    import pinocchio as pin
    from pink.tasks import FrameTask

    from keymps.robot.description import tool_rotation
    from keymps.robot.model import TCP_FRAME

    task = FrameTask(TCP_FRAME, position_cost=1.0, orientation_cost=1.0)

    def solve(points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        out = np.full((len(points), robot.dof), np.nan)
        for i, (point, yaw) in enumerate(zip(points, yaws, strict=True)):
            task.set_target(pin.SE3(tool_rotation(float(yaw)), np.asarray(point, float)))
            configuration = pink.Configuration(robot.model, robot.model.createData(),
                                               robot.arm_model.home.copy())  # fmt: skip
            for _ in range(200):
                error = task.compute_error(configuration)
                if np.linalg.norm(error[:3]) < 1e-7 and np.linalg.norm(error[3:]) < 1e-7:
                    break
                velocity = pink.solve_ik(configuration, [task], 0.1, solver="daqp", damping=1e-8)
                configuration.integrate_inplace(velocity, 0.1)
            out[i] = configuration.q
        return out

    return solve


def ikpy_solver(chain_module: Any, robot: Any) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """ikpy on the URDF keymps uses (its root to the tool mount), the tool tip as a fixed link
    vector; targets in the arm's root frame."""
    from keymps.robot.description import tool_rotation

    folder = Path(tempfile.mkdtemp(prefix="ikpy-"))
    urdf = folder / "arm.urdf"
    urdf.write_text(robot.arm_model.urdf_text)
    chain = _ikpy_chain(chain_module, robot, urdf)
    active = [i for i, link in enumerate(chain.links) if link.name in robot.joint_names]
    base_inverse = robot.base_in_board.inverse()

    def solve(points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        out = np.full((len(points), robot.dof), np.nan)
        start = np.zeros(len(chain.links))
        start[active] = robot.arm_model.home
        for i, (point, yaw) in enumerate(zip(points, yaws, strict=True)):
            import pinocchio as pin

            tip = base_inverse * pin.SE3(tool_rotation(float(yaw)), np.asarray(point, float))
            tip = tip * pin.SE3(np.eye(3), -np.asarray(robot.tool.tcp, float))
            q = chain.inverse_kinematics(np.array(tip.translation), np.array(tip.rotation),
                                         orientation_mode="all", initial_position=start)  # fmt: skip
            out[i] = np.asarray(q)[active]
        return out

    return solve


def _ikpy_chain(chain_module: Any, robot: Any, urdf: Path) -> Any:
    """The chain from the URDF's root to the tool mount, the arm's joints active."""
    import xml.etree.ElementTree as ElementTree

    root = ElementTree.fromstring(robot.arm_model.urdf_text)
    parent_joint = {j.find("child").get("link"): j for j in root.findall("joint")}  # type: ignore[union-attr]
    path, link = [robot.spec.tip_link], robot.spec.tip_link
    while link in parent_joint:
        joint = parent_joint[link]
        link = joint.find("parent").get("link")  # type: ignore[union-attr]
        path[:0] = [link, joint.get("name")]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        chain = chain_module.Chain.from_urdf_file(str(urdf), base_elements=path, symbolic=False)
        mask = [link.name in robot.joint_names for link in chain.links]
        return chain_module.Chain(chain.links, active_links_mask=mask)


def run_arm(
    name: str, count: int, rng: np.random.Generator, peers: tuple[Any, Any]
) -> dict[str, Outcome]:
    """Every solver on `count` poses of one arm (the knife on it, at its default base)."""
    from keymps.robot.description import BUILTIN_TOOLS
    from keymps.robot.model import RobotModel

    robot = RobotModel(name, tool=BUILTIN_TOOLS["knife"])
    points, yaws = board_poses(robot, count, rng)
    pink, chain_module = peers
    solvers: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {}
    if robot.closed_form is not None:
        solvers["closed"] = lambda p, y: keymps_closed_form(robot, p, y)
    solvers["iterative"] = lambda p, y: keymps_iterative(robot, p, y)
    solvers["pink"] = pink_solver(pink, robot)
    solvers["ikpy"] = ikpy_solver(chain_module, robot)
    outcomes = {}
    for label, solve in solvers.items():
        qs, seconds = timed(lambda solve=solve: solve(points, yaws), count)
        outcomes[label] = Outcome(*judge(robot, qs, points, yaws), seconds)
    return outcomes


def verdicts(name: str, outcomes: dict[str, Outcome]) -> list[tuple[str, float, bool]]:
    """(figure name, value, target met) for one arm."""
    peers = [outcomes["pink"], outcomes["ikpy"]]
    fastest = min(p.seconds_per_pose for p in peers)
    best = max(float(p.solved.mean()) for p in peers)
    rows = []
    if "closed" in outcomes:
        closed = outcomes["closed"]
        worst = float(closed.position_error[closed.solved].max()) if closed.solved.any() else 0.0
        rows.append((f"{name}_closed_form_speedup", fastest / closed.seconds_per_pose,
                     fastest / closed.seconds_per_pose >= 100))  # fmt: skip
        rows.append((f"{name}_closed_form_worst_m", worst, worst < 1e-9))
    else:
        mine = outcomes["iterative"]
        rows.append((f"{name}_iterative_success_vs_best_peer",
                     float(mine.solved.mean()) - best, float(mine.solved.mean()) >= best))  # fmt: skip
        rows.append((f"{name}_iterative_speedup", fastest / mine.seconds_per_pose,
                     mine.seconds_per_pose <= fastest))  # fmt: skip
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--poses", type=int, default=1000, help="random poses per arm")
    parser.add_argument("--arms", default=",".join(ARMS), help="comma-separated arm names")
    parser.add_argument("--seed", type=int, default=20260101)
    parser.add_argument("--quick", action="store_true", help="a few poses on three arms")
    args = parser.parse_args()
    peers = _require_peers()
    arms = QUICK_ARMS if args.quick else tuple(a for a in args.arms.split(",") if a)
    count = 10 if args.quick else args.poses
    rng = np.random.default_rng(args.seed)
    rows: list[tuple[str, float, bool]] = []
    for name in arms:
        outcomes = run_arm(name, count, rng, peers)
        print(f"{name}: {count} poses")
        for label, outcome in outcomes.items():
            print(outcome.line(label))
        rows += verdicts(name, outcomes)
    print()
    for figure, value, met in rows:
        print(
            f"{figure}: {value:.6g}{'' if args.quick else '  (target met)' if met else '  (MISSED)'}"
        )
    return 0 if args.quick or all(met for *_, met in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
