"""A pause in a learned demonstration must not slow the cut: the timing passes through the
dwell instead of crawling along the whole stroke, and warns when the joints slow a work piece."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import keymps.motion.strokes as strokes
import keymps.motion.timing as timing
from keymps.config.task import Task
from keymps.motion.compose import compose_tool_path
from keymps.motion.timing import time_trajectory
from keymps.primitives.demos import Preprocessing, write_demo_csv
from keymps.primitives.dictionary import Primitive, learn_primitive
from keymps.robot.model import RobotModel, solve_path
from keymps.types import Segment, Trajectory

WORK_SPEED = 0.03
USER_LOG = {"rate": 500.0, "duration": 4.0, "rocks": 3.0, "amplitude": 0.01}
USER_LOG |= {"pause_at": 0.5, "still": 0.5, "noise": 1e-4}
"""The log of issue 19: 500 Hz, 4 s, a 0.3 s pause half-way, 0.1 mm noise (cut 20x slower)."""


def min_jerk(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return 10 * x**3 - 15 * x**4 + 6 * x**5


def rocking_log(
    rng: np.random.Generator, pause_s: float, **fixed: float
) -> tuple[np.ndarray, np.ndarray]:
    """A raw robot log of a rocking cut: 10 cm along, 5 cm down, the blade rocking back and
    forth; a pause of `pause_s` somewhere in the middle, still ends, sensor noise. Every
    other property is drawn from `rng` unless given in `fixed`."""
    draw = {
        "rate": float(rng.choice([125.0, 250.0, 500.0])),
        "duration": rng.uniform(3.0, 5.0),
        "rocks": rng.uniform(2.0, 4.0),
        "amplitude": rng.uniform(0.005, 0.015),
        "pause_at": rng.uniform(0.3, 0.7),
        "still": rng.uniform(0.3, 1.0),
        "noise": rng.uniform(5e-5, 2e-4),
    }
    v = draw | fixed
    rate = v["rate"]
    x = np.arange(int(v["duration"] * rate) + 1) / rate / v["duration"]
    envelope = min_jerk(x / 0.1) * (1 - min_jerk((x - 0.9) / 0.1))
    rock = v["amplitude"] * np.sin(2 * np.pi * v["rocks"] * x) * envelope
    y = np.stack([0.10 * min_jerk(x) + rock, 0 * x, 0.05 * (1 - min_jerk(x))], axis=1)
    at = int(v["pause_at"] * len(x))
    held = np.repeat(y[at : at + 1], int(pause_s * rate), axis=0)
    still = int(v["still"] * rate)
    y = np.vstack([np.repeat(y[:1], still, 0), y[:at], held, y[at:], np.repeat(y[-1:], still, 0)])
    y = y + rng.normal(0.0, v["noise"], y.shape)
    return np.arange(len(y)) / rate, y


def learn(tmp_path: Path, name: str, t: np.ndarray, y: np.ndarray) -> Primitive:
    log = tmp_path / f"{name}-log.csv"
    write_demo_csv(log, t, y)
    return learn_primitive(
        name, log, description="rocking cut", preprocessing=Preprocessing(smooth_s=0.05)
    )


def cut(primitive: Primitive, rng: np.random.Generator) -> Trajectory:
    """One tilted cut across an eggplant-sized object, composed and timed like a run."""
    task = Task.model_validate(
        {
            "name": "t",
            "instruction": "cut it",
            "scene": {"image": "x.png", "object_height": 0.06},
            "primitives": ["straight"],
            "robot": {"tool": "knife"},
            "motion": {"work_speed": WORK_SPEED},
        }
    )
    model = RobotModel.from_task(task)
    angle = rng.uniform(-0.6, 0.6) + math.pi / 2
    centre = np.array([0.15 + rng.uniform(-0.03, 0.03), 0.09, 0.0])
    half = rng.uniform(0.025, 0.04) * np.array([math.cos(angle), math.sin(angle), 0.0])
    segment = Segment(centre - half + [0, 0, 0.065], centre + half, (0.0, 0.0), (0.0, 0.0))
    path = compose_tool_path(
        [segment],
        primitive,
        object_top=0.06,
        clearance=0.03,
        work_speed=WORK_SPEED,
        travel_speed=0.15,
        yaw_mode="follow",
        home=model.home_tool_position(),
    )
    return time_trajectory(model, path, solve_path(model, path), task)


def work_seconds(trajectory: Trajectory) -> float:
    return float((trajectory.kind == "work").sum() / trajectory.rate_hz)


@pytest.mark.parametrize("seed", range(5))
def test_a_pause_in_the_demonstration_does_not_slow_the_cut(tmp_path: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    pause_s = rng.uniform(0.2, 0.6)
    state = rng.bit_generator.state
    paused = learn(tmp_path, "paused", *rocking_log(rng, pause_s))
    rng.bit_generator.state = state  # the same motion, without the pause
    smooth = learn(tmp_path, "smooth", *rocking_log(rng, 0.0))
    layout = np.random.default_rng(100 + seed)
    with_pause = cut(paused, layout)
    layout = np.random.default_rng(100 + seed)
    without = cut(smooth, layout)
    assert work_seconds(with_pause) < 1.3 * work_seconds(without), (pause_s, seed)
    assert with_pause.warnings == ()


@pytest.mark.parametrize("seed", range(3))
def test_the_reported_log_cuts_as_fast_as_without_its_pause(tmp_path: Path, seed: int) -> None:
    paused = learn(tmp_path, "p", *rocking_log(np.random.default_rng(seed), 0.3, **USER_LOG))
    smooth = learn(tmp_path, "s", *rocking_log(np.random.default_rng(seed), 0.0, **USER_LOG))
    with_pause = cut(paused, np.random.default_rng(101 + seed))
    without = cut(smooth, np.random.default_rng(101 + seed))
    assert work_seconds(with_pause) < 1.3 * work_seconds(without)
    assert with_pause.warnings == ()


def test_a_work_piece_the_joints_slow_far_below_work_speed_is_a_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The old timing (keeping the dwell's wiggles, no stop at them) makes the stroke crawl:
    # the warning must say so, with the speed it actually got.
    monkeypatch.setattr(strokes, "MIN_STEP_M", 2e-5)
    monkeypatch.setattr(timing, "MAX_STOP_DEPTH", 0)
    paused = learn(tmp_path, "paused", *rocking_log(np.random.default_rng(1), 0.3, **USER_LOG))
    slow = cut(paused, np.random.default_rng(101))
    assert len(slow.warnings) == 1, slow.warnings
    assert slow.warnings[0].startswith("work piece 1 takes ")
    assert "longer than at motion.work_speed 0.03 m/s" in slow.warnings[0]
