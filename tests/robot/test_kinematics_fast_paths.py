"""IK and forward kinematics: the closed form against the iterative solver and Pinocchio, the batched kinematics, and whole runs with and without the closed form.

Each fast path is held against the implementation it replaced, on generated inputs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from helpers.robot_toolpaths import radial_cuts, ring_of_dots

from keymps.errors import KeympsError
from keymps.robot.model import BUILTIN_TOOLS, RobotModel, Tool, solve_path, tool_poses_down
from keymps.run import RunOptions, RunOverrides
from keymps.types import ToolPath

RNG_SEED = 20261201


def random_model(rng: np.random.Generator) -> RobotModel:
    kind = str(rng.choice(["ur3", "ur3e"]))
    base = (
        float(rng.uniform(0.14, 0.16)),
        float(rng.uniform(-0.21, -0.19)),
        float(rng.uniform(-0.005, 0.01)),
        float(rng.uniform(85, 95)),
    )
    tcp = (
        float(rng.uniform(-0.004, 0.004)),
        float(rng.uniform(-0.004, 0.004)),
        0.09 + rng.random() * 0.05,
    )
    return RobotModel(kind, base, Tool("t", tcp, "fixed"))


def test_every_analytic_branch_reproduces_the_pose_in_pinocchio() -> None:
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(4):
        model = random_model(rng)
        assert model.closed_form is not None
        qs = rng.uniform(-math.pi, math.pi, (60, 6))
        positions, rotations = model.pinocchio_tool_poses(qs)
        poses = np.zeros((len(qs), 4, 4))
        poses[:, :3, :3], poses[:, :3, 3], poses[:, 3, 3] = rotations, positions, 1.0
        branches = model.closed_form.solve(poses)
        found = 0
        for i, q in enumerate(qs):
            valid = branches[i][~np.isnan(branches[i]).any(axis=1)]
            got_p, got_r = model.pinocchio_tool_poses(valid)
            assert np.abs(got_p - positions[i]).max() < 1e-9
            assert np.abs(got_r - rotations[i]).max() < 1e-9
            wrapped = np.abs((valid - q + math.pi) % (2 * math.pi) - math.pi).max(axis=1)
            found += wrapped.min() < 1e-7  # the configuration we started from is among them
        assert found >= len(qs) - 2  # (a pose next to a singularity may lose its branch)


@pytest.mark.parametrize("make_path", [ring_of_dots, radial_cuts])
def test_closed_form_and_iterative_ik_agree_on_varied_paths(make_path: Any) -> None:
    rng = np.random.default_rng(RNG_SEED + 1)
    solved = 0
    for _ in range(6):
        model = random_model(rng)
        tool_path = make_path(center=(0.15 + rng.uniform(-0.01, 0.01), 0.09))
        closed, closed_error = _solve(model, tool_path)
        model.closed_form, kept = None, model.closed_form
        iterative, iterative_error = _solve(model, tool_path)
        model.closed_form = kept
        assert closed_error == iterative_error  # the same refusal, word for word
        if closed is None or iterative is None:
            continue
        solved += 1
        for a, b in zip(closed.pieces, iterative.pieces, strict=True):
            assert np.abs(a - b).max() < 1e-6
        assert closed.max_position_error_m < 1e-9
    assert solved >= 2


def _solve(model: RobotModel, tool_path: ToolPath) -> tuple[Any, str | None]:
    try:
        return solve_path(model, tool_path), None
    except KeympsError as error:
        return None, str(error)


def test_closed_form_solutions_are_verified_and_continuous() -> None:
    model = RobotModel("ur3", tool=BUILTIN_TOOLS["knife"])
    tool_path = radial_cuts()
    joints = solve_path(model, tool_path)
    points = np.concatenate([piece.points for piece in tool_path.pieces])
    yaws = np.concatenate([piece.yaw for piece in tool_path.pieces])
    seed = model.tool_down_seed(points[0], float(yaws[0]))
    assert model.solve_closed_form(points, yaws, seed) is not None  # no fallback here
    for piece, qs in zip(tool_path.pieces, joints.pieces, strict=True):
        positions, rotations = model.pinocchio_tool_poses(qs)
        targets = tool_poses_down(piece.points, piece.yaw)
        assert np.abs(positions - piece.points).max() < 1e-9
        assert np.abs(rotations - targets[:, :3, :3]).max() < 1e-9
        assert np.abs(np.diff(qs, axis=0)).max() < 0.3  # sparse travel points turn the wrist


def test_a_path_the_closed_form_cannot_take_falls_back_with_the_same_errors() -> None:
    model = RobotModel("ur3", tool=BUILTIN_TOOLS["knife"])
    near = np.array([[0.10, 0.05, 0.08], [0.11, 0.05, 0.08]])
    seed = model.tool_down_seed(near[0], 0.0)
    # A point out of reach has no analytic solution: the iterative solver words the error.
    far = np.vstack([near, [[0.60, 0.40, 0.08]]])
    assert model.solve_closed_form(far, np.zeros(3), seed) is None
    messages = []
    for method in ("auto", "iterative"):
        with pytest.raises(
            KeympsError,
            match="cannot reach board point .* with the tool pointing down \\(path point 2;",
        ) as info:
            model.solve_points(far, np.zeros(3), seed, method=method)
        messages.append(str(info.value))
    assert messages[0] == messages[1]
    # Without a closed form (another robot) every point is solved iteratively.
    auto = model.solve_points(near, np.zeros(2), seed)
    model.closed_form = None
    assert np.abs(model.solve_points(near, np.zeros(2), seed)[0] - auto[0]).max() < 1e-6


def test_the_kinematics_self_checks_refuse_a_model_that_disagrees() -> None:
    """Both fast paths check themselves against Pinocchio at the probe configurations."""
    import dataclasses

    from keymps.robot.batch_fk import BatchKinematics
    from keymps.robot.closed_form import ClosedFormIk
    from keymps.robot.probes import probe_configurations

    probes = probe_configurations(64, 6)
    assert probes.shape == (64, 6) and np.abs(probes).max() < math.pi
    # spread: every joint's range is covered, no two probes alike
    for column in probes.T:
        assert np.histogram(column, bins=8, range=(-math.pi, math.pi))[0].min() >= 4
    assert np.array_equal(probes, probe_configurations(64, 6))

    model = RobotModel("ur3", tool=BUILTIN_TOOLS["knife"])
    base = model.base_in_board.homogeneous
    assert ClosedFormIk.for_model(model.arm, base, model.fk) is not None
    longer = dataclasses.replace(model.arm, forearm=model.arm.forearm + 1e-6)
    assert ClosedFormIk.for_model(longer, base, model.fk) is None
    batch = BatchKinematics.for_model(model.model)
    assert batch is not None
    joints = list(batch.joints)
    joints[3] = dataclasses.replace(joints[3], translation=joints[3].translation + [1e-6, 0, 0])
    assert not BatchKinematics(tuple(joints)).agrees_with(model.model)


def test_batched_forward_kinematics_is_pinocchios() -> None:
    rng = np.random.default_rng(RNG_SEED + 2)
    for _ in range(3):
        model = random_model(rng)
        assert model.batch is not None
        qs = rng.uniform(-2 * math.pi, 2 * math.pi, (5000, 6))  # more than one chunk
        positions, rotations = model.tool_poses(qs)
        expected_p, expected_r = model.pinocchio_tool_poses(qs)
        assert np.abs(positions - expected_p).max() < 1e-12
        assert np.abs(rotations - expected_r).max() < 1e-12
        origins = model.joint_origins_many(qs[:200])
        assert np.abs(origins - np.array([model.joint_origins(q) for q in qs[:200]])).max() < 1e-12
        # one pass for the safety check: the very same numbers as the two passes
        together = model.tool_poses_and_joint_origins(qs)
        apart = (positions, rotations, model.joint_origins_many(qs))
        assert all(np.array_equal(a, b) for a, b in zip(together, apart, strict=True))
        for some in (qs[:4096], qs):  # one chunk of batch FK, and more
            got_p, got_x = model.tool_positions_and_x_axes(some)
            assert np.array_equal(got_p, positions[: len(some)])
            assert np.array_equal(got_x, rotations[: len(some), :, 0])


@pytest.mark.parametrize("task_file", ["cake_icing.yaml", "object_cutting.yaml"])
def test_shipped_runs_are_unchanged_by_the_closed_form(
    task_file: str, tmp_path: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """IK, timing, validation and the simulated outcome with the closed form, and with every
    point solved iteratively as before."""
    from pathlib import Path

    from keymps import load_task, run_task
    from keymps.robot import closed_form

    task = load_task(Path(__file__).parents[2] / "tasks" / task_file)
    fast = run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path / "fast", backend="offline", executor="sim"),
    )
    monkeypatch.setattr(closed_form.ClosedFormIk, "for_model", classmethod(lambda *a: None))
    slow = run_task(
        task,
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(out=tmp_path / "slow", backend="offline", executor="sim"),
    )
    for a, b in zip(fast.stages.solve.pieces, slow.stages.solve.pieces, strict=True):
        assert np.abs(a - b).max() < 1e-6
    fast_t, slow_t = fast.stages.time, slow.stages.time
    assert np.array_equal(fast_t.t, slow_t.t)
    assert np.abs(fast_t.q - slow_t.q).max() < 1e-5
    assert np.abs(fast_t.tool_xyz - slow_t.tool_xyz).max() < 1e-6
    fast_v, slow_v = fast.stages.check.report, slow.stages.check.report
    assert fast_v.ok == slow_v.ok
    for name, value in slow_v.figures.items():
        assert fast_v.figures[name] == pytest.approx(value, rel=1e-3, abs=1e-6), name
    assert fast.stages.execute.ok == slow.stages.execute.ok


def test_inverse_dh_links_are_the_inverted_links_bit_for_bit() -> None:
    from keymps.robot.closed_form import _inverse, dh_link, inverse_dh_link

    rng = np.random.default_rng(RNG_SEED + 23)
    for _ in range(4):
        arm = random_model(rng).closed_form.arm  # type: ignore[union-attr]
        theta = np.concatenate(
            [rng.uniform(-2 * math.pi, 2 * math.pi, 3000), [0.0, -0.0, math.pi, -math.pi / 2]]
        )
        for i in range(6):
            assert (
                inverse_dh_link(theta, i, arm).tobytes()
                == _inverse(dh_link(theta, i, arm)).tobytes()
            )


def test_a_robot_built_again_shares_its_checked_kinematics_and_computes_the_same() -> None:
    """RobotModel keeps the Pinocchio model, batched FK and closed form per arm, base and tool:
    a model built again computes exactly what one built from scratch does."""
    from keymps.robot import model as robot_model

    rng = np.random.default_rng(RNG_SEED + 7)
    for _ in range(3):
        first = random_model(rng)
        again = RobotModel(first.kind, first.base, first.tool)
        assert again.model is first.model and again.data is not first.data
        robot_model._KINEMATICS.clear()
        fresh = RobotModel(first.kind, first.base, first.tool)
        assert fresh.model is not first.model
        qs = rng.uniform(-math.pi, math.pi, (40, 6))
        for q in qs[:5]:
            for got, expected in zip(again.fk(q), fresh.fk(q), strict=True):
                assert np.array_equal(got, expected)
        for got, expected in zip(again.tool_poses(qs), fresh.tool_poses(qs), strict=True):
            assert np.array_equal(got, expected)
        poses = np.zeros((len(qs), 4, 4))
        poses[:, :3, 3], poses[:, :3, :3] = fresh.tool_poses(qs)
        poses[:, 3, 3] = 1.0
        assert again.closed_form is not None and fresh.closed_form is not None
        assert np.array_equal(
            again.closed_form.solve(poses), fresh.closed_form.solve(poses), equal_nan=True
        )
    other_tool = RobotModel(first.kind, first.base, BUILTIN_TOOLS["piping_bag"])
    assert other_tool.model is not first.model
    assert not np.allclose(other_tool.fk(qs[0])[0], first.fk(qs[0])[0])
