"""The sim executor: cut lengths, painted cuts, the replay's kinematics and the blade's positions against the direct computations.

Each fast path is held against the implementation it replaced, on generated inputs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from keymps.robot.model import RobotModel, Tool

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


def test_cut_length_from_runs_matches_all_blade_samples_at_once() -> None:
    from keymps.default_plugins.sim.cut_sweep import Footprint, covered_length

    rng = np.random.default_rng(RNG_SEED + 14)
    for trial in range(40):
        outlines = []
        for _ in range(int(rng.choice([1, 1, 2, 3]))):  # several objects: holes between them
            angles = np.sort(rng.uniform(0, 2 * math.pi, int(rng.integers(3, 60))))
            radius = rng.uniform(0.01, 0.09, len(angles))  # ragged: concave outlines
            centre = np.array([0.15, 0.1]) + rng.normal(0, 0.04, 2)
            outlines.append(
                centre + radius[:, None] * np.column_stack([np.cos(angles), np.sin(angles)])
            )
        footprint = Footprint(outlines if len(outlines) > 1 else outlines[0]) if trial % 4 else None
        count = int(rng.integers(1, 400))
        heading = rng.uniform(0, math.pi)
        along = np.array([math.cos(heading), math.sin(heading)])
        tips = np.array([0.15, 0.1]) + np.outer(rng.uniform(-0.1, 0.1, count), along)
        tips += rng.normal(0, float(rng.choice([0.0, 1e-4, 3e-3])), tips.shape)
        blade = float(rng.choice([0.0005, 0.02, 0.16]))
        turn = heading + rng.normal(0, float(rng.choice([0.0, 0.05, 0.5])), count)
        backwards = np.column_stack([np.cos(turn), np.sin(turn)])
        segments = np.stack([tips, tips - blade * backwards], axis=1)
        got = covered_length(segments, footprint)
        assert got == _covered_length_at_once(segments, footprint)


def _covered_length_at_once(segments: np.ndarray, footprint: Any) -> float:
    """covered_length as it was: every blade sample tested and projected on the SVD's axis,
    np.unique of the bins."""
    from keymps.default_plugins.sim.cut_sweep import FOOTPRINT_CELL_M, LENGTH_BIN_M

    longest = float(np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).max())
    fractions = np.linspace(0.0, 1.0, max(2, math.ceil(2 * longest / LENGTH_BIN_M) + 1))
    starts, ends = segments[:, None, 0], segments[:, None, 1]
    points = (starts + fractions[None, :, None] * (ends - starts)).reshape(-1, 2)
    if footprint is not None:
        cells = np.floor((points - footprint.origin) / FOOTPRINT_CELL_M)
        rows, cols = footprint.mask.shape
        ok = (cells[:, 0] >= 0) & (cells[:, 0] < cols) & (cells[:, 1] >= 0) & (cells[:, 1] < rows)
        inside = np.zeros(len(cells), dtype=bool)
        cells = cells[ok].astype(np.intp)
        inside[ok] = footprint.mask[cells[:, 1], cells[:, 0]] > 0
        points = points[inside]
    if len(points) < 2:
        return 0.0
    centred = points - points.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    return float(len(np.unique(np.floor(centred @ axis / LENGTH_BIN_M))) * LENGTH_BIN_M)


def test_painting_cuts_on_covered_pixels_matches_blending_the_whole_image() -> None:
    from keymps.default_plugins.sim.executor import _paint_cuts

    rng = np.random.default_rng(RNG_SEED + 17)
    shift, painted = 4, 0
    for trial in range(8):
        height, width = (int(v) for v in rng.integers(50, 300, 2))
        scale = float(rng.uniform(1500, 3000))  # pixels per metre

        def pixels(xy: np.ndarray, scale: float = scale) -> np.ndarray:
            return np.round(np.asarray(xy).reshape(-1, 2) * scale * (1 << shift)).astype(np.int32)

        image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        size = np.array([width, height]) / scale
        sweeps = []
        for _ in range(int(rng.integers(1, 5))):
            tips = rng.uniform(0, 1, (int(rng.integers(2, 60)), 2)) * size
            sweeps.append(np.stack([tips, tips + rng.normal(0, 0.02, tips.shape)], axis=1))
        footprint = None
        if trial % 3:
            angles = np.sort(rng.uniform(0, 2 * math.pi, 12))
            footprint = size / 2 + np.column_stack([np.cos(angles), np.sin(angles)]) * size / 3
        line = int(rng.integers(1, 6))
        got = image.copy()
        _paint_cuts(got, sweeps, footprint, pixels, line, shift)
        assert np.array_equal(got, _paint_whole_image(image, sweeps, footprint, pixels, line))
        painted += not np.array_equal(got, image)
    assert painted >= 6  # (a footprint may happen to clip every cut away)


def _paint_whole_image(
    image: np.ndarray, sweeps: list[np.ndarray], footprint: Any, pixels: Any, width: int
) -> np.ndarray:
    """_paint_cuts as it was: every pixel of the image blended."""
    import cv2

    from keymps.default_plugins.sim.executor import CUT_COLOUR

    covered = np.zeros(image.shape[:2], np.uint8)
    for sweep in sweeps:
        segments = pixels(sweep.reshape(-1, 2)).reshape(-1, 2, 2)
        cv2.polylines(covered, list(segments), False, 255, width, cv2.LINE_AA, 4)
    alpha = covered.astype(np.float32) / 255.0
    if footprint is not None:
        inside = np.zeros(image.shape[:2], np.uint8)
        cv2.fillPoly(inside, [pixels(footprint)], 255, cv2.LINE_AA, 4)
        alpha *= inside.astype(np.float32) / 255.0
    alpha = alpha[:, :, None]
    return np.round(image * (1.0 - alpha) + np.array(CUT_COLOUR) * alpha).astype(np.uint8)


def test_interpolated_cos_sin_by_recurrence_matches_numpy() -> None:
    from keymps.robot.batch_fk import interpolated_cos_sin

    rng = np.random.default_rng(RNG_SEED + 18)
    for substeps in (1, 2, 3, 8, 40):
        speed = float(rng.choice([1e-4, 0.01, 0.3]))  # radians per sample
        qs = np.cumsum(rng.normal(0, speed, (int(rng.integers(2, 400)), 6)), axis=0)
        qs += rng.uniform(-2 * math.pi, 2 * math.pi, 6)
        fractions = np.arange(substeps) / substeps
        between = qs[:-1, None] + fractions[:, None] * (qs[1:] - qs[:-1])[:, None]
        angles = np.concatenate([between.reshape(-1, 6), qs[-1:]]).T
        cos, sin = interpolated_cos_sin(qs, substeps)
        assert np.abs(cos - np.cos(angles)).max() < 1e-14
        assert np.abs(sin - np.sin(angles)).max() < 1e-14


def test_sim_replay_matches_forward_kinematics_of_every_interpolated_sample() -> None:
    from keymps.default_plugins.sim.executor import replay
    from keymps.types import Trajectory

    rng = np.random.default_rng(RNG_SEED + 19)
    for _ in range(6):
        model = random_model(rng)
        rate = float(rng.choice([125.0, 500.0]))
        n = int(rng.integers(2, 700))
        q = np.cumsum(rng.normal(0, 0.004, (n, 6)), axis=0) + rng.uniform(-math.pi, math.pi, 6)
        pieces = np.sort(rng.integers(0, 5, n))
        trajectory = Trajectory(
            np.arange(n) / rate, q, np.zeros((n, 6)), np.zeros((n, 6)),
            rng.uniform(-0.1, 0.3, (n, 3)), pieces, np.where(pieces % 2, "work", "travel"),
            tuple(model.joint_names), rate,
        )  # fmt: skip
        replay_rate = float(rng.choice([250.0, 1000.0, 3000.0]))
        got = replay(model, trajectory, replay_rate)
        # the straightforward replay: every replayed sample's joints, then forward kinematics
        substeps = max(1, math.ceil(replay_rate / rate))
        base = np.append(np.repeat(np.arange(n - 1), substeps), n - 1)
        frac = np.append(np.tile(np.arange(substeps) / substeps, n - 1), 0.0)
        nxt = np.minimum(base + 1, n - 1)
        joints = q[base] + frac[:, None] * (q[nxt] - q[base])
        positions, rotations = model.tool_poses(joints)
        planned = trajectory.tool_xyz
        assert np.array_equal(got.t, trajectory.t[base] + frac / rate)
        assert np.array_equal(
            got.planned_xyz, planned[base] + frac[:, None] * (planned[nxt] - planned[base])
        )
        assert np.array_equal(got.piece_index, pieces[base])
        assert np.array_equal(got.kind, trajectory.kind[base])
        assert np.abs(got.tool_xyz - positions).max() < 1e-13
        x_axis = rotations[:, :2, 0] / np.linalg.norm(rotations[:, :2, 0], axis=1, keepdims=True)
        assert got.tool_x is not None and np.abs(got.tool_x - x_axis).max() < 1e-12


def test_blade_positions_are_picked_as_with_numpys_norm_and_union() -> None:
    from keymps.default_plugins.sim.cut_sweep import SWEEP_STEP_M, _every

    rng = np.random.default_rng(RNG_SEED + 22)
    for _ in range(20):
        n = int(rng.integers(2, 5000))
        tip = np.cumsum(rng.normal(0, float(rng.choice([1e-5, 1e-4, 1e-3])), (n, 3)), axis=0)
        far = tip[:, :2] + 0.16 * rng.normal(0, 1, (n, 2)) / 40
        moved = np.maximum(
            np.linalg.norm(np.diff(tip, axis=0), axis=1),
            np.linalg.norm(np.diff(far, axis=0), axis=1),
        )
        bins = np.floor(np.concatenate([[0.0], np.cumsum(moved)]) / SWEEP_STEP_M)
        expected = np.union1d(np.flatnonzero(np.diff(bins, prepend=-1.0) > 0), [n - 1])
        assert np.array_equal(_every(tip, far, SWEEP_STEP_M), expected)


def test_row_norms_are_numpys_norms_to_the_bit() -> None:
    from keymps.robot.safety_geometry import row_norms

    rng = np.random.default_rng(RNG_SEED + 23)
    for columns in (1, 2, 3, 6):
        vectors = rng.normal(0, 1, (20_000, columns)) * 10.0 ** rng.uniform(-12, 3, (20_000, 1))
        assert np.array_equal(row_norms(vectors), np.linalg.norm(vectors, axis=1))
