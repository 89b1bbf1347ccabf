"""The rosbag executor: bags read back with rosbags' own reader and compared exactly (joints
bit for bit, times to the ns) on real validated trajectories and on generated ones."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from keymps_ros.rosbag import joint_trajectory, replace_bag, typestore
from rosbags.rosbag2 import Reader

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.motion.timing import time_trajectory
from keymps.plugin import trajectory_digest
from keymps.plugin.manager import build_manager, components, create_component
from keymps.robot.model import RobotModel, solve_path
from keymps.robot.safety import SafetyError, validate
from keymps.run import Run
from keymps.types import Piece, ToolPath, Trajectory, ValidatedTrajectory


def make_task(model: str, name: str = "icing lines") -> Task:
    return Task.model_validate(
        {
            "name": name,
            "instruction": "icing",
            "scene": {"image": "x.png", "object_height": 0.06},
            "primitives": ["line"],
            "robot": {"model": model, "tool": "piping_bag"},
        }
    )


def validated_run(
    folder: Path, model: str = "ur3", angle: float = 0.0
) -> tuple[ValidatedTrajectory, Run]:
    """Two real 3 cm icing lines and the move between them at `angle` (rad) above the board, through the safety check."""
    task = make_task(model)
    robot = RobotModel.from_task(task)
    direction = np.array([math.cos(angle), math.sin(angle), 0.0])
    first, second = (
        start + np.linspace(0, 0.03, 31)[:, None] * direction
        for start in (np.array([0.13, 0.08, 0.065]), np.array([0.15, 0.10, 0.065]))
    )
    over = first[-1] + np.linspace(0, 1, 21)[:, None] * (second[0] - first[-1])
    path = ToolPath(
        (
            Piece("work", 0, first, np.zeros(31), 0.05),
            Piece("travel", 1, over, np.zeros(21), 0.1),
            Piece("work", 1, second, np.zeros(31), 0.05),
        ),
        "line",
    )
    trajectory = time_trajectory(robot, path, solve_path(robot, path), task)
    outline = np.array([[0.08, 0.03], [0.22, 0.03], [0.22, 0.15], [0.08, 0.15]])
    validated = validate(robot, trajectory, path, outline, task)
    assert validated.report.ok, validated.report.problems
    return validated, Run(task=task, folder=folder, robot=robot)


def read_bag(folder: Path) -> dict[str, list[tuple[int, Any]]]:
    """topic -> [(log time ns, message)], read and decoded by rosbags."""
    store = typestore()
    topics: dict[str, list[tuple[int, Any]]] = {}
    with Reader(folder) as reader:
        for connection, stamp, raw in reader.messages():
            message = store.deserialize_cdr(raw, connection.msgtype)
            topics.setdefault(connection.topic, []).append((stamp, message))
    return topics


def nanoseconds(time: Any) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def expected_ns(t: np.ndarray) -> np.ndarray:
    return np.rint((np.asarray(t) - t[0]) * 1e9).astype(np.int64)


def check_joint_trajectory(message: Any, trajectory: Trajectory, prefix: str) -> None:
    assert message.joint_names == [prefix + name for name in trajectory.joint_names]
    assert nanoseconds(message.header.stamp) == 0 and message.header.frame_id == ""
    points = message.points
    assert len(points) == trajectory.samples
    for column, name in ((trajectory.q, "positions"), (trajectory.qd, "velocities")):
        assert np.array_equal(np.array([getattr(p, name) for p in points]), column), name
    assert np.array_equal(np.array([p.accelerations for p in points]), trajectory.qdd)
    assert all(len(p.effort) == 0 for p in points)
    assert all(0 <= p.time_from_start.nanosec < 1_000_000_000 for p in points)
    stamps = np.array([nanoseconds(p.time_from_start) for p in points])
    assert np.array_equal(stamps, expected_ns(trajectory.t))


@pytest.mark.parametrize("model", ["ur3", "ur3e"])
def test_the_bag_reads_back_exactly(tmp_path: Path, model: str) -> None:
    validated, run = validated_run(tmp_path, model)
    trajectory = validated.trajectory
    options = {"joint_states_topic": "/joint_states", "joint_prefix": "arm_"}
    report = create_component("executor", "rosbag", options).execute(validated, run)
    bag = tmp_path / "trajectory_bag"
    assert report.ok and report.files == (str(bag),) and report.dry_run is None
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "trajectory_bag.mcap"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trajectory_bag"]  # no leftovers
    topics = read_bag(bag)
    assert sorted(topics) == ["/joint_states", "/joint_trajectory", "/tool_path"]
    [(start, message)] = topics["/joint_trajectory"]
    check_joint_trajectory(message, trajectory, "arm_")
    offsets = expected_ns(trajectory.t)
    states = topics["/joint_states"]
    assert [stamp for stamp, _ in states] == (start + offsets).tolist()
    assert [nanoseconds(s.header.stamp) for _, s in states] == (start + offsets).tolist()
    assert np.array_equal(np.array([s.position for _, s in states]), trajectory.q)
    assert np.array_equal(np.array([s.velocity for _, s in states]), trajectory.qd)
    assert all(s.name == message.joint_names for _, s in states)
    check_tool_path(topics["/tool_path"], trajectory, run.robot, start + offsets)
    custom = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert custom["storage_identifier"] == "mcap"
    assert custom["custom_data"] == {
        "keymps_version": custom["custom_data"]["keymps_version"],
        "task": "icing lines",
        "trajectory_sha256": trajectory_digest(trajectory),
        "robot_model": model,
    }


def check_tool_path(
    messages: list[tuple[int, Any]], trajectory: Trajectory, robot: Any, stamps: np.ndarray
) -> None:
    [(_, path)] = messages
    assert path.header.frame_id == "board"
    poses = path.poses
    assert all(p.header.frame_id == "board" for p in poses)
    assert [nanoseconds(p.header.stamp) for p in poses] == stamps.tolist()
    xyz = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in poses])
    assert np.array_equal(xyz, trajectory.tool_xyz)
    x, y, z, w = np.array(
        [[p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w]
         for p in poses]
    ).T  # fmt: skip
    rotations = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )
    _, expected = robot.tool_poses(np.asarray(trajectory.q))
    assert np.abs(rotations - expected).max() < 1e-12
    assert np.abs(expected[:, :, 2] - [0, 0, -1]).max() < 1e-3  # the nozzle points down


def test_paths_in_any_direction_read_back(tmp_path: Path) -> None:
    for case, angle in enumerate(np.linspace(0, 2 * math.pi, 7, endpoint=False)):
        validated, run = validated_run(tmp_path / str(case), "ur3e", float(angle))
        create_component("executor", "rosbag", {"path_topic": None}).execute(validated, run)
        topics = read_bag(tmp_path / str(case) / "trajectory_bag")
        assert sorted(topics) == ["/joint_trajectory"]
        check_joint_trajectory(topics["/joint_trajectory"][0][1], validated.trajectory, "")


def test_generated_trajectories_read_back_to_the_nanosecond(tmp_path: Path) -> None:
    """60 joint trajectories with uneven times, long and short, written and read back."""
    rng = np.random.default_rng(11)
    store = typestore()
    names = tuple(f"joint_{i}" for i in range(6))
    for case in range(60):
        samples = int(rng.integers(1, 400))
        t = np.cumsum(rng.uniform(1e-4, 0.05, samples)) + rng.uniform(0, 100)
        q = rng.normal(0, 3, (samples, 6))
        trajectory = Trajectory(
            t, q, rng.normal(size=q.shape), rng.normal(size=q.shape), np.zeros((samples, 3)),
            np.zeros(samples, int), np.full(samples, "work"), names, 125.0,
        )  # fmt: skip
        message = joint_trajectory(store, trajectory, "p_")
        bag = tmp_path / f"bag{case}"

        def write(folder: Path, message: Any = message) -> None:
            from rosbags.rosbag2 import StoragePlugin, Writer

            with Writer(folder, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
                connection = writer.add_connection("/t", message.__msgtype__, typestore=store)
                writer.write(connection, 1, store.serialize_cdr(message, message.__msgtype__))

        replace_bag(bag, write)
        [(_, back)] = read_bag(bag)["/t"]
        check_joint_trajectory(back, trajectory, "p_")


def test_an_earlier_bag_is_replaced_and_anything_else_is_refused(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path)
    executor = create_component("executor", "rosbag", {"bag": "out/bag"})
    executor.execute(validated, run)
    first = (tmp_path / "out" / "bag" / "metadata.yaml").read_text()
    executor.execute(validated, run)  # a second export replaces the first
    assert (tmp_path / "out" / "bag" / "metadata.yaml").read_text() != first  # a new start time
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["bag"]
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "mine.txt").write_text("keep me")
    with pytest.raises(KeympsError) as error:
        create_component("executor", "rosbag", {"bag": "notes"}).execute(validated, run)
    assert str(error.value) == (
        f"executor rosbag: {tmp_path / 'notes'} exists and is not a bag: choose another "
        "executor.bag"
    )
    assert (tmp_path / "notes" / "mine.txt").read_text() == "keep me"


def test_unvalidated_trajectories_are_refused(tmp_path: Path) -> None:
    validated, run = validated_run(tmp_path)
    copy = ValidatedTrajectory(validated.trajectory, validated.report)
    with pytest.raises(SafetyError, match="did not come from keymps.robot.safety.validate"):
        create_component("executor", "rosbag", {}).execute(copy, run)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"bag": "/tmp/bag"}, "leads out of the run folder"),
        ({"bag": "../bag"}, "leads out of the run folder"),
        ({"trajectory_topic": "joint_trajectory"}, "is not an absolute ROS name"),
        ({"path_topic": "/tool path"}, "is not an absolute ROS name"),
        ({"joint_states_topic": "/a//b"}, "is not an absolute ROS name"),
        ({"joint_prefix": "ur/"}, "may hold only letters, digits and '_'"),
        ({"storage": "sqlite3"}, "unknown option"),
    ],
)
def test_bad_options_are_one_line(options: dict[str, object], message: str) -> None:
    with pytest.raises(KeympsError) as error:
        create_component("executor", "rosbag", options)
    text = str(error.value)
    assert text.startswith("executor rosbag: option ") and message in text and "\n" not in text


def test_the_package_registers_its_executors_through_its_entry_point() -> None:
    executors = components("executor", build_manager())
    assert {"rosbag", "ros2"} <= set(executors)


def run_into(folder: Path, executor: dict[str, Any], instruction: str | None = None) -> Any:
    """The shipped icing task run into `folder` with `executor` (a failed run: its error)."""
    import json

    import keymps

    repo = Path(__file__).resolve().parents[3]
    task = keymps.load_task(repo / "tasks" / "cake_icing.yaml")
    task = task.model_copy(update={"executor": task.executor.model_validate(executor)})
    overrides = keymps.RunOverrides(backend="offline", out=folder, instruction=instruction)
    try:
        keymps.run_task(task, options=keymps.RunOptions(rerun="off", quiet=True),
                        overrides=overrides)  # fmt: skip
    except KeympsError as error:
        return error
    return json.loads((folder / "run.json").read_text())


def test_a_later_run_into_the_folder_leaves_no_bag_of_an_earlier_one(tmp_path: Path) -> None:
    """A run with the rosbag executor, then one with another executor into the same --out: the
    earlier run's bag stayed beside the new run's run.json, and a script reading the folder
    took its motion for the new run's. Its bag goes with the rest of the earlier run's files,
    wherever `executor.bag` put it, even after the folder was moved."""
    folder = tmp_path / "run"
    first = run_into(folder, {"name": "rosbag"})
    assert first["files"] == ["plan.png", "plan_outcome.png", "trajectory.csv", "trajectory_bag/"]
    assert first["execution"]["files"] == [str(folder / "trajectory_bag")]
    (folder / "notes.txt").write_text("mine")  # not a run's: kept
    second = run_into(folder, {"name": "sim"})
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        [".keymps.lock", "notes.txt", "run.json", "vlm", *second["files"]]
    )
    assert "trajectory_bag/" not in second["files"] and "outcome.png" in second["files"]

    run_into(folder, {"name": "rosbag", "bag": "exports/icing/bag"})
    assert (folder / "exports" / "icing" / "bag" / "metadata.yaml").is_file()
    moved = tmp_path / "moved"
    folder.rename(moved)  # run.json names its files relative to its folder
    failed = run_into(moved, {"name": "rosbag"}, instruction="asdf")
    assert isinstance(failed, KeympsError) and "cannot turn 'asdf' into a design" in str(failed)
    assert sorted(p.name for p in moved.iterdir()) == [
        ".keymps.lock",
        "notes.txt",
        "run.json",
        "vlm",
    ]
