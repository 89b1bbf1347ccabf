"""Every built-in arm and any URDF: the UR family against UR's DH tables and the shipped URDFs,
the iterative IK on generated board poses (Panda, SO-101), the SO-101's refusals, a task's own
URDF (its errors located, its files kept inside the task's tree), and the shipped tasks on
every arm end to end."""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.box_arm import JOINTS, stl_box, urdf_text

from keymps.config.task import load_task
from keymps.errors import KeympsError, TaskFileError
from keymps.robot.catalog import UR_ARMS, example_robot_data
from keymps.robot.description import BUILTIN_TOOLS, Tool, tool_rotation
from keymps.robot.model import RobotModel, tool_poses_down
from keymps.run import RunOptions, RunOverrides

REPO = Path(__file__).resolve().parents[2]
FLANGE = Tool("flange", (0.0, 0.0, 0.0), "fixed")


def dh_flange(q: np.ndarray, dh: tuple[float, ...]) -> np.ndarray:
    """The flange pose from a UR standard DH table (written out here, not keymps')."""
    d1, a2, a3, d4, d5, d6 = dh
    d, a = [d1, 0, 0, d4, d5, d6], [0, a2, a3, 0, 0, 0]
    alpha = [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]
    pose = np.eye(4)
    for i in range(6):
        ct, st, ca, sa = math.cos(q[i]), math.sin(q[i]), math.cos(alpha[i]), math.sin(alpha[i])
        pose = pose @ np.array(
            [[ct, -st * ca, st * sa, a[i] * ct], [st, ct * ca, -ct * sa, a[i] * st],
             [0, sa, ca, d[i]], [0, 0, 0, 1]]
        )  # fmt: skip
    return pose


@pytest.mark.parametrize("name", sorted(UR_ARMS))
def test_every_ur_arm_is_its_published_dh_table(name: str) -> None:
    # base yaw 180: the DH base frame is base_link turned by pi
    robot = RobotModel(name, (0.0, 0.0, 0.0, 180.0), FLANGE)
    assert robot.closed_form is not None and robot.dof == 6
    rng = np.random.default_rng(hash(name) % 2**32)
    for q in rng.uniform(-math.pi, math.pi, (25, 6)):
        position, rotation = robot.fk(q)
        expected = dh_flange(q, UR_ARMS[name]["dh"])  # type: ignore[arg-type]
        assert np.allclose(position, expected[:3, 3], atol=1e-9)
        assert np.allclose(rotation, expected[:3, :3], atol=1e-9)


@pytest.mark.parametrize("name", ["ur3", "ur5", "ur10"])
def test_the_shipped_cb3_urdfs_agree_with_the_dh_tables(name: str) -> None:
    """example-robot-data's URDF as shipped (not edited by keymps) against UR's table."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(
        str(example_robot_data(f"ur_description/urdf/{name}_robot.urdf"))
    )
    data = model.createData()
    frame = model.getFrameId("tool0")
    turn = np.diag([-1.0, -1.0, 1.0, 1.0])  # base_link -> the DH base frame
    rng = np.random.default_rng(3)
    for q in rng.uniform(-math.pi, math.pi, (25, 6)):
        pin.framesForwardKinematics(model, data, q)
        got = turn @ data.oMf[frame].homogeneous
        expected = dh_flange(q, UR_ARMS[name]["dh"])  # type: ignore[arg-type]
        assert np.abs(got[:3, 3] - expected[:3, 3]).max() < 1e-6  # the URDF's 6-digit lengths


def test_joint_speed_limits_follow_each_models_manual() -> None:
    degrees = {name: np.degrees(RobotModel(name).velocity_limits).round(6).tolist()
               for name in ("ur3", "ur5e", "ur10e", "ur16e", "ur20")}  # fmt: skip
    assert degrees["ur3"] == [180, 180, 180, 360, 360, 360]
    assert degrees["ur5e"] == [180] * 6
    assert degrees["ur10e"] == degrees["ur16e"] == [120, 120, 180, 180, 180, 180]
    assert degrees["ur20"] == [120, 120, 150, 210, 210, 210]
    assert RobotModel("ur3").rate_hz == 125 and RobotModel("ur5e").rate_hz == 500
    panda = RobotModel("panda")
    assert panda.dof == 7 and panda.velocity_limits[-1] == pytest.approx(2.61)
    assert panda.acceleration_limits[1] == pytest.approx(7.5)


def board_poses(robot: RobotModel, count: int, seed: int, region: Any = None) -> tuple[Any, Any]:
    (x0, x1), (y0, y1), (z0, z1) = region or ((0, robot.board_size[0]), (0, robot.board_size[1]),
                                              (0.0, 0.12))  # fmt: skip
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(x0, x1, count), rng.uniform(y0, y1, count),
                              rng.uniform(z0, z1, count)])  # fmt: skip
    return points, rng.uniform(-math.pi, math.pi, count)


def solve_each(robot: RobotModel, points: np.ndarray, yaws: np.ndarray) -> list[np.ndarray | None]:
    found: list[np.ndarray | None] = []
    for point, yaw in zip(points, yaws, strict=True):
        try:
            found.append(robot.tool_down_seed(point, float(yaw)))
        except KeympsError as error:
            assert str(error).startswith("robot: ") and "\n" not in str(error)
            found.append(None)
    return found


def assert_solutions_exact(robot: RobotModel, qs: list[Any], points: Any, yaws: Any) -> None:
    for q, point, yaw in zip(qs, points, yaws, strict=True):
        if q is None:
            continue
        position, rotation = robot.fk(q)
        assert np.linalg.norm(position - point) < 1e-6
        assert np.allclose(rotation, tool_rotation(float(yaw)), atol=1e-4)  # the contract: 0.1 deg
        assert np.all(q >= robot.lower) and np.all(q <= robot.upper)


@pytest.mark.parametrize("name", ["ur5e", "ur10e", "ur16e", "ur20"])
def test_the_closed_form_solves_every_ur_arm_over_the_board(name: str) -> None:
    robot = RobotModel(name, tool=BUILTIN_TOOLS["knife"])
    points, yaws = board_poses(robot, 200, 11)
    branches = robot.closed_form.solve(tool_poses_down(points, yaws))  # type: ignore[union-attr]
    valid = ~np.isnan(branches).any(axis=2)
    assert valid.any(axis=1).mean() == 1.0  # every pose has analytic solutions
    qs = branches[valid]
    poses = np.repeat(tool_poses_down(points, yaws), valid.sum(axis=1), axis=0)
    positions, rotations = robot.pinocchio_tool_poses(qs)
    assert np.abs(positions - poses[:, :3, 3]).max() < 1e-9
    assert np.abs(rotations - poses[:, :3, :3]).max() < 1e-9


def test_the_panda_reaches_the_board_with_its_redundancy_away_from_its_limits() -> None:
    robot = RobotModel("panda", tool=BUILTIN_TOOLS["knife"])
    points, yaws = board_poses(robot, 120, 5)
    qs = solve_each(robot, points, yaws)
    assert sum(q is not None for q in qs) / len(qs) >= 0.97
    assert_solutions_exact(robot, qs, points, yaws)
    margin = np.array(
        [np.minimum(q - robot.lower, robot.upper - q).min() for q in qs if q is not None]
    )
    assert np.median(margin) > 0.2  # radians from the nearest limit: the null space kept it away


def test_the_pandas_home_yaw_leaves_its_seventh_joint_room_both_ways() -> None:
    """Joint 7 turns 28 degrees short of a whole turn: cuts turn from the yaw that puts it in
    the middle of its range (a UR's wrist turns two turns each way: no preference)."""
    for base in (None, (0.15, -0.35, 0.0, 90.0), (-0.25, 0.09, 0.0, 0.0)):
        robot = RobotModel("panda", base, BUILTIN_TOOLS["knife"], object_height=0.02)
        q = robot.tool_down_seed(robot.home_tool_position(), robot.home_yaw())
        assert abs(q[-1] - (robot.lower[-1] + robot.upper[-1]) / 2) < 0.3  # yaw 0: 2.2 rad off
    assert RobotModel("ur3").home_yaw() == 0.0


def test_a_path_stopped_by_a_joint_limit_names_the_joint() -> None:
    """The Panda 25 cm from the board folding towards its base: the elbow's limit, not a
    distance, is what stops it (the message said "0.0 mm short" of such points)."""
    robot = RobotModel("panda", (0.15, -0.25, 0.0, 90.0), BUILTIN_TOOLS["knife"])
    points = np.linspace([0.15, 0.09, 0.10], [0.15, 0.0, 0.05], 40)
    yaws = np.full(len(points), math.pi / 2)
    seed = robot.tool_down_seed(points[0], math.pi / 2)
    with pytest.raises(KeympsError) as caught:
        robot.solve_points(points, yaws, seed, where="path")
    message = str(caught.value)
    assert "panda_joint4 at its limit (-176 degrees)" in message and "\n" not in message


def test_the_so101_holds_the_tool_down_where_its_roll_allows_and_says_where_not() -> None:
    """Five joints: the tool points down anywhere in its reach band, at a yaw its wrist roll
    (-2.74 .. 2.84 rad) can give; the 0.6 rad of yaw beyond is refused, not tilted."""
    robot = RobotModel("so101", tool=BUILTIN_TOOLS["knife"])
    region = ((0.08, 0.22), (0.0, 0.09), (0.0, 0.03))
    points, yaws = board_poses(robot, 60, 9, region)
    qs = solve_each(robot, points, yaws)
    assert 0.6 <= sum(q is not None for q in qs) / len(qs) < 1.0
    assert_solutions_exact(robot, qs, points, yaws)
    # facing straight ahead of the base, the yaw the roll cannot give:
    point = np.array([robot.base[0], 0.05, 0.01])
    bad = [yaw for yaw in np.linspace(-math.pi, math.pi, 73)
           if not robot.reachable(point, float(yaw))]  # fmt: skip
    assert 0 < len(bad) < 20
    with pytest.raises(KeympsError) as caught:
        robot.tool_down_seed(point, float(bad[len(bad) // 2]))
    message = str(caught.value)
    assert message.startswith("robot: SO-101 (LeRobot), 5 joints cannot hold the tool pointing")
    assert f"board point ({point[0]:.3f}, 0.050, 0.010) m" in message


def write_task(folder: Path, robot: str) -> Path:
    scenes = folder / "scenes"
    scenes.mkdir(parents=True, exist_ok=True)
    shutil.copy(REPO / "tasks/scenes/round_cake.png", scenes / "round_cake.png")
    task = (REPO / "tasks/cake_icing.yaml").read_text()
    task = task.replace("robot: {model: ur3, tool: piping_bag}", f"robot: {robot}")
    task = task.replace("prompt: ../prompts/icing.md", "prompt: null")
    path = folder / "task.yaml"
    path.write_text(task)
    return path


def box_arm(folder: Path, mesh: str = "package://boxarm/meshes/base.stl") -> None:
    (folder / "arm/urdf").mkdir(parents=True, exist_ok=True)
    (folder / "arm/meshes").mkdir(parents=True, exist_ok=True)
    (folder / "arm/urdf/boxarm.urdf").write_text(urdf_text(mesh))
    (folder / "arm/meshes/base.stl").write_bytes(stl_box(0.06))


def test_a_tasks_own_urdf_runs_end_to_end(tmp_path: Path) -> None:
    import keymps

    box_arm(tmp_path)
    task = load_task(write_task(
        tmp_path, "{urdf: arm/urdf/boxarm.urdf, tip_link: tool0, tool: piping_bag, home: "
        "[0, 0.6, 1.2, 0, -0.25, 0], limits: {acceleration: 4.0, jerk: [80, 80, 80, 80, 80, 80]}}"
    ))  # fmt: skip
    run = keymps.run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path / "run", backend="offline"),
    )
    assert run.robot is not None and run.robot.model_name == "boxarm"
    assert run.robot.joint_names == tuple(JOINTS) and run.robot.closed_form is None
    assert run.robot.acceleration_limits.tolist() == [4.0] * 6
    assert run.stages.execute is not None and run.stages.execute.ok


@pytest.mark.parametrize(
    ("robot", "expected"),
    [
        (
            "{model: ur7}",
            r"task.yaml:\d+:\d+: robot.model: unknown robot 'ur7' \(available: .*panda",
        ),
        ("{model: ur3, urdf: a.urdf}", "give either model .* or urdf"),
        ("{urdf: arm/urdf/boxarm.urdf}", "urdf needs tip_link"),
        ("{tip_link: tool0}", "tip_link describe a urdf arm; add urdf"),
        ("{urdf: ../elsewhere.urdf, tip_link: tool0}", r"robot.urdf: .* is outside the task's"),
        (
            "{urdf: arm/urdf/boxarm.urdf, tip_link: hand}",
            r"robot.urdf: arm 'boxarm' .*no link 'hand'",
        ),
    ],
)
def test_a_bad_robot_section_is_one_located_line(robot: str, expected: str, tmp_path: Path) -> None:
    import re

    import keymps

    folder = tmp_path / "task"
    box_arm(folder)
    (tmp_path / "elsewhere.urdf").write_text(urdf_text())
    with pytest.raises((KeympsError, TaskFileError)) as caught:
        task = load_task(write_task(folder, robot))
        keymps.run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=tmp_path / "run", backend="offline"),
        )
    message = str(caught.value)
    assert re.search(expected, message), message
    assert "Traceback" not in message
    assert not (tmp_path / "run" / "trajectory.csv").exists()


@pytest.mark.parametrize("mesh", ["package://boxarm/../../outside.stl", "/etc/hostname"])
def test_a_urdf_mesh_outside_its_package_is_never_read(mesh: str, tmp_path: Path) -> None:
    import keymps

    folder = tmp_path / "task"
    box_arm(folder, mesh)
    (tmp_path / "outside.stl").write_bytes(stl_box(0.05))
    task = load_task(write_task(folder, "{urdf: arm/urdf/boxarm.urdf, tip_link: tool0}"))
    with pytest.raises(KeympsError, match=r"robot.urdf: arm 'boxarm' .* is outside the arm's"):
        keymps.run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=tmp_path / "run", backend="offline"),
        )


def test_a_robot_factory_that_raises_is_one_line(keymps_plugins: Any, tmp_path: Path) -> None:
    import keymps
    from keymps.plugin import hookimpl

    class Broken:
        @hookimpl
        def register_robots(self, register: Any) -> None:
            register("broken", lambda options: 1 / 0)

    keymps_plugins.register(Broken(), name="broken-robot")
    task = load_task(write_task(tmp_path, "{model: broken}"))
    with pytest.raises(TaskFileError) as caught:
        keymps.run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=tmp_path / "run", backend="offline"),
        )
    message = str(caught.value)
    assert "robot.model: robot 'broken' of plugin 'broken-robot' could not be built" in message
    assert "ZeroDivisionError" in message and "\n" not in message


@pytest.mark.parametrize("model", ["ur3", "ur5e", "ur10e", "panda"])
@pytest.mark.parametrize("task_file", ["object_cutting.yaml", "cake_icing.yaml"])
def test_the_shipped_tasks_run_on_every_arm_that_reaches_the_board(
    model: str, task_file: str, tmp_path: Path
) -> None:
    import keymps

    task = load_task(REPO / "tasks" / task_file)
    assert task.robot.base is None  # a user swapping `model:` gets each arm at its own place
    arm = task.robot.model_copy(update={"model": model})
    task = task.model_copy(update={"robot": arm})
    run = keymps.run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path, backend="offline", executor="sim"),
    )
    assert run.robot is not None and run.robot.model_name == model
    assert run.stages.execute is not None and run.stages.execute.ok
    figures = run.stages.check.report.figures  # type: ignore[union-attr]
    assert figures["min_arm_board_clearance_mm"] >= 10 and figures["min_self_clearance_mm"] >= 0
    header = (tmp_path / "trajectory.csv").read_text().split("\n", 1)[0]
    assert header.count(",q") == run.robot.dof


@pytest.mark.parametrize("task_file", ["object_cutting.yaml", "cake_icing.yaml"])
def test_the_shipped_tasks_are_refused_in_one_line_where_the_so101_cannot_reach(
    task_file: str, tmp_path: Path
) -> None:
    import keymps

    task = load_task(REPO / "tasks" / task_file)
    arm = task.robot.model_copy(update={"model": "so101", "base": None})  # its default place
    task = task.model_copy(update={"robot": arm})
    with pytest.raises(KeympsError) as caught:
        keymps.run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=tmp_path, backend="offline", executor="sim"),
        )
    message = str(caught.value)
    assert "\n" not in message
    if task_file == "cake_icing.yaml":  # the 6 cm cake: refused before planning, at its height
        assert ": scene.object_height: 0.06 m: the so101 cannot reach 0.090 m above" in message
    else:  # it reaches every cut only by folding its gripper into its shoulder
        assert message.startswith("check: safety: the arm would hit itself (shoulder_link_5 and ")
    assert not (tmp_path / "trajectory.csv").exists()
