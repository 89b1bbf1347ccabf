"""keymps.primitives.dmp: fitting, exact re-targeting in every mode, temporal scaling, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from keymps.errors import KeympsError
from keymps.primitives.dmp import DMP, ZERO_LENGTH_M, DmpError, heading_rotation, retarget_map
from keymps.primitives.retarget import blade_map


def min_jerk(x: np.ndarray) -> np.ndarray:
    return 10 * x**3 - 15 * x**4 + 6 * x**5


def sawing_demo(samples: int = 600, duration: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Three +-2 cm strokes along x while advancing 6 cm and descending 5 cm."""
    t = np.linspace(0.0, duration, samples)
    x = t / duration
    envelope = np.sin(np.pi * x) ** 2
    y = np.stack(
        [
            0.06 * min_jerk(x) + 0.02 * np.sin(2 * np.pi * 3 * x) * envelope,
            np.zeros_like(x),
            0.05 * (1 - min_jerk(x)),
        ],
        axis=1,
    )
    return t, y


@pytest.fixture(scope="module")
def sawing() -> DMP:
    return DMP.fit(*sawing_demo())


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(((a - b) ** 2).sum(axis=1).mean()))


def test_fit_reproduces_the_demonstration_and_ends_at_rest(sawing: DMP) -> None:
    t, y = sawing_demo()
    rollout = sawing.rollout(y[0], y[-1], num=len(t))
    # 0.12 um; 1.4 um when the ridge term was scaled by the heavy end rows as well
    assert rmse(rollout.y, y) < 5e-7
    assert np.allclose(rollout.t, t)
    assert np.linalg.norm(rollout.y[-1] - y[-1]) < 1e-9
    assert np.linalg.norm(rollout.yd[-1]) < 1e-9
    assert sawing.demo_duration == pytest.approx(3.0)


def test_fit_accepts_non_uniform_time_stamps() -> None:
    t, y = sawing_demo(2000)
    rng = np.random.default_rng(1)
    keep = np.sort(
        np.concatenate([[0, len(t) - 1], rng.choice(len(t) - 2, 400, replace=False) + 1])
    )
    t_sparse, y_sparse = t[keep] + 12.5, y[keep]  # and a clock that does not start at zero
    dmp = DMP.fit(t_sparse, y_sparse)
    rollout = dmp.rollout(y[0], y[-1], num=len(t))
    assert rmse(rollout.y, y) < 1e-4


def test_rollout_solves_the_continuous_transformation_system(sawing: DMP) -> None:
    """The filter implementation agrees with a tight ODE solve of the DMP equations."""
    from scipy.integrate import solve_ivp

    start, goal, tau = np.array([0.1, 0.2, 0.06]), np.array([0.1, 0.3, 0.0]), 2.0
    rollout = sawing.rollout(start, goal, tau=tau, num=2001)
    transform = rollout.transform
    k, d = sawing.alpha_z * sawing.beta_z, sawing.alpha_z

    def rhs(time: float, state: np.ndarray) -> np.ndarray:
        y, z = state[:3], state[3:]
        s = math.exp(-sawing.alpha_s * time / tau)
        f = transform @ sawing.forcing(np.array([s]))[0]
        zd = (k * (goal - y) - d * z - k * (goal - start) * s + k * f) / tau
        return np.concatenate([z / tau, zd])

    solution = solve_ivp(
        rhs,
        (0, tau),
        np.concatenate([start, np.zeros(3)]),
        t_eval=rollout.t,
        rtol=1e-10,
        atol=1e-12,
        max_step=tau / 2000,
    )
    assert np.abs(solution.y[:3].T - rollout.y).max() < 1e-6
    assert np.abs(solution.y[3:].T / tau - rollout.yd).max() < 1e-5


def test_velocity_and_acceleration_are_derivatives_of_position(sawing: DMP) -> None:
    rollout = sawing.rollout([0, 0, 0.05], [0.08, 0.05, 0.0], tau=1.5, num=3000)
    dt = rollout.t[1]
    assert np.abs(np.gradient(rollout.y, dt, axis=0)[2:-2] - rollout.yd[2:-2]).max() < 1e-3
    assert np.abs(np.gradient(rollout.yd, dt, axis=0)[2:-2] - rollout.ydd[2:-2]).max() < 0.05


unit = st.floats(-1.0, 1.0, allow_nan=False)
point = st.tuples(
    st.floats(-0.5, 0.5, allow_nan=False),
    st.floats(-0.5, 0.5, allow_nan=False),
    st.floats(-0.2, 0.3, allow_nan=False),
)


@st.composite
def segments(draw: st.DrawFn, demo_delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and goals: arbitrary, rotated/scaled copies of the demo, dots, antiparallel."""
    start = np.array(draw(point))
    kind = draw(st.sampled_from(["any", "rotated", "dot", "antiparallel", "vertical"]))
    if kind == "any":
        return start, np.array(draw(point))
    if kind == "dot":
        return start, start.copy()
    scale = draw(st.floats(0.05, 4.0))
    if kind == "antiparallel":
        return start, start - scale * demo_delta
    if kind == "vertical":
        return start, start + np.array(
            [0.0, 0.0, draw(st.sampled_from([-1.0, 1.0])) * scale * 0.05]
        )
    angle = draw(st.floats(-math.pi, math.pi))
    c, s = math.cos(angle), math.sin(angle)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return start, start + scale * rz @ demo_delta


DEMO_DELTA = sawing_demo()[1][-1] - sawing_demo()[1][0]


@settings(max_examples=150, deadline=None)
@given(
    segment=segments(DEMO_DELTA),
    mode=st.sampled_from(["similarity", "axial", "blade", "translate"]),
    tau=st.floats(0.2, 20.0),
    num=st.integers(2, 400),
)
def test_retargeted_rollout_is_an_exact_linear_image_of_the_demo_fit(
    sawing: DMP, segment: tuple[np.ndarray, np.ndarray], mode: str, tau: float, num: int
) -> None:
    """y(t) = y0 + S (y_fit(t) - y0_d), with y(t) from integrating the re-targeted system."""
    start, goal = segment
    rollout = sawing.rollout(start, goal, tau=tau, num=num, mode=mode)
    S = rollout.transform
    reached = start + S @ sawing.demo_delta
    direct = sawing.integrate(start, reached, S, tau=tau, num=num)
    demo_fit = sawing.rollout(sawing.demo_start, sawing.demo_goal, tau=tau, num=num)
    predicted = start + (demo_fit.y - sawing.demo_start) @ S.T
    assert np.abs(direct.y - predicted).max() < 1e-9
    assert np.abs(rollout.y - predicted).max() < 1e-9
    assert np.abs(direct.yd - rollout.yd).max() < 1e-9 * max(1.0, 1.0 / tau)
    is_dot = np.linalg.norm(goal - start) < ZERO_LENGTH_M
    if mode != "translate" and not (is_dot and mode == "similarity"):
        # a dot (shorter than ZERO_LENGTH_M, not only exactly 0) ends where it started
        tolerance = ZERO_LENGTH_M if is_dot else 1e-12
        assert np.allclose(S @ sawing.demo_delta, goal - start, atol=tolerance)
    if mode == "similarity" and not is_dot:
        # A scaled rotation: S^T S = k^2 I and det > 0.
        k2 = (np.linalg.norm(goal - start) / np.linalg.norm(sawing.demo_delta)) ** 2
        assert np.allclose(S.T @ S, k2 * np.eye(3), atol=1e-12 * max(1.0, k2))
        assert np.linalg.det(S) > 0


@settings(max_examples=100, deadline=None)
@given(a=st.tuples(unit, unit, unit), b=st.tuples(unit, unit, unit))
def test_heading_rotation_is_a_rotation_taking_a_to_b(a: tuple, b: tuple) -> None:
    a_arr, b_arr = np.array(a), np.array(b)
    if np.linalg.norm(a_arr) < 1e-3 or np.linalg.norm(b_arr) < 1e-3:
        return
    a_arr /= np.linalg.norm(a_arr)
    b_arr /= np.linalg.norm(b_arr)
    rotation = heading_rotation(a_arr, b_arr)
    assert np.allclose(rotation @ a_arr, b_arr, atol=1e-9)
    assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
    assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_antiparallel_horizontal_segment_turns_about_world_z() -> None:
    """A line demonstrated along +x, drawn along -x: the dip stays a dip."""
    S = retarget_map(np.array([0.05, 0.0, 0.0]), np.array([-0.05, 0.0, 0.0]))
    assert np.allclose(S @ [0, 0, -1], [0, 0, -1])
    assert np.allclose(S @ [1, 0, 0], [-1, 0, 0])


def test_antiparallel_inclined_segment_keeps_down_down() -> None:
    demo = np.array([0.06, 0.0, -0.05])
    S = retarget_map(demo, -demo * 1.0 + np.array([0.0, 0.0, -0.1]))  # back along x, still down
    assert (S @ np.array([0, 0, -1.0]))[2] < 0


def test_heading_rotation_keeps_horizontal_strokes_horizontal() -> None:
    """Sawing re-targeted 90 degrees about z: the map is exactly that rotation."""
    demo = np.array([0.06, 0.0, -0.05])
    S = retarget_map(demo, np.array([0.0, 0.06, -0.05]))
    assert np.allclose(S, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_sawing_keeps_its_full_stroke_when_the_cut_turns(sawing: DMP) -> None:
    t, y = sawing_demo()
    turned = sawing.rollout([0.2, 0.1, 0.05], [0.2, 0.16, 0.0], num=len(t))
    along_blade = turned.y[:, 1] - 0.1
    demo_along = y[:, 0]
    assert np.abs(along_blade - demo_along).max() < 1e-3
    assert np.abs(turned.y[:, 0] - 0.2).max() < 1e-3


def test_axial_mode_keeps_the_depth_across_the_segment() -> None:
    """A line demo dipping 4 mm keeps its 4 mm dip at three times the length, and a dot."""
    t = np.linspace(0.0, 2.0, 400)
    x = t / 2.0
    y = np.stack([0.05 * min_jerk(x), 0 * x, -0.004 * np.sin(np.pi * x) ** 2], axis=1)
    dmp = DMP.fit(t, y)
    long = dmp.rollout([0, 0, 0.05], [0.0, 0.15, 0.05], mode="axial")
    assert long.y[:, 2].min() == pytest.approx(0.05 - 0.004, abs=2e-4)
    similar = dmp.rollout([0, 0, 0.05], [0.0, 0.15, 0.05], mode="similarity")
    assert similar.y[:, 2].min() == pytest.approx(0.05 - 0.012, abs=6e-4)
    dot = dmp.rollout([0.1, 0.1, 0.05], [0.1, 0.1, 0.05], mode="axial")
    assert np.abs(dot.y[:, :2] - 0.1).max() < 1e-6
    assert dot.y[:, 2].min() == pytest.approx(0.046, abs=2e-4)
    assert np.allclose(dot.y[-1], [0.1, 0.1, 0.05], atol=1e-6)


def test_blade_mode_re_targets_a_flat_demo_as_axial() -> None:
    """A stroke along the board whose height only drifts (0.07 mm over 8 cm, as in a robot
    log): dividing by that depth threw the path 35 m away. Below 10% slope blade is axial."""
    flat = np.array([0.08, 0.0, -7e-5])
    for delta in ([0.1, 0.05, 0.0], [0.0, 0.0, -0.03], [0.0, 0.0, 0.0], [-0.02, 0.01, 0.01]):
        S = retarget_map(flat, np.array(delta), "blade")
        assert np.allclose(S, retarget_map(flat, np.array(delta), "axial"))
        assert np.abs(S).max() < 3.0
    with pytest.raises(DmpError, match="at least 10% of its length"):
        blade_map(flat, np.array([0.1, 0.05, 0.0]))
    steep = np.array([0.08, 0.0, -0.01])  # 12% of its length: a shallow cut, still blade
    S = retarget_map(steep, np.array([0.0, 0.1, -0.01]), "blade")
    assert np.allclose(S, blade_map(steep, np.array([0.0, 0.1, -0.01])))


def test_dots_and_closed_demos_replay_the_demo_translated(sawing: DMP) -> None:
    dot = sawing.rollout([0.1, 0.0, 0.05], [0.1, 0.0, 0.05])
    assert np.allclose(dot.transform, np.eye(3))
    assert np.all(np.isfinite(dot.y))
    t = np.linspace(0, 1, 100)
    loop = np.stack([0.01 * np.sin(2 * np.pi * t), 0.01 * (1 - np.cos(2 * np.pi * t)), 0 * t], 1)
    closed = DMP.fit(t, loop)
    out = closed.rollout([0, 0, 0], [0.1, 0, 0])
    assert np.allclose(out.transform, np.eye(3))
    assert np.abs(out.y).max() < 0.03


def test_temporal_scaling_runs_at_the_requested_speed(sawing: DMP) -> None:
    start, goal = np.array([0.0, 0.0, 0.05]), np.array([0.1, 0.0, 0.0])
    tau = sawing.tau_for_speed(start, goal, 0.04)
    rollout = sawing.rollout(start, goal, tau=tau)
    assert rollout.length_m / rollout.t[-1] == pytest.approx(0.04, rel=1e-3)
    slow = sawing.rollout(start, goal, tau=2 * tau)
    assert np.allclose(slow.y, rollout.y)
    assert np.allclose(slow.yd, rollout.yd / 2)
    assert np.allclose(slow.ydd, rollout.ydd / 4)


def test_round_trip_through_a_dict_is_exact(sawing: DMP) -> None:
    again = DMP.from_dict(sawing.to_dict())
    assert np.array_equal(again.weights, sawing.weights)
    assert np.array_equal(
        again.rollout([0, 0, 0], [1, 1, 1]).y, sawing.rollout([0, 0, 0], [1, 1, 1]).y
    )


@pytest.mark.parametrize(
    ("t", "y", "message"),
    [
        (np.arange(5.0), np.zeros((5, 3)), "at least 10 samples"),
        (np.arange(20.0), np.zeros((20, 2)), "shape"),
        (np.r_[np.arange(10.0), 5.0, np.arange(11.0, 20)], np.zeros((20, 3)), "increase"),
        (np.arange(20.0), np.r_[np.zeros((19, 3)), [[np.nan, 0, 0]]], "NaN"),
    ],
)
def test_bad_demonstrations_raise_one_clear_line(
    t: np.ndarray, y: np.ndarray, message: str
) -> None:
    with pytest.raises(KeympsError, match=message) as info:
        DMP.fit(t, y)
    assert "\n" not in str(info.value)


def test_bad_requests_raise(sawing: DMP) -> None:
    with pytest.raises(DmpError, match="mode"):
        sawing.rollout([0, 0, 0], [1, 0, 0], mode="mirror")
    with pytest.raises(DmpError, match="tau"):
        sawing.rollout([0, 0, 0], [1, 0, 0], tau=-1)
    with pytest.raises(DmpError, match="goal"):
        sawing.rollout([0, 0, 0], [1, 0])
    bad = sawing.to_dict()
    bad["weights"] = bad["weights"][:-1]
    with pytest.raises(DmpError, match="rows but dmp.n_basis"):
        DMP.from_dict(bad, "x.yaml")


@settings(max_examples=200, deadline=None)
@given(
    a=st.tuples(unit, unit, unit),
    e=st.tuples(unit, unit, unit),
    offset=st.sampled_from([0.0, 1e-12, 1e-8, 1e-5, 1e-3, 2e-3, 0.1]),
    sign=st.sampled_from([1.0, -1.0]),
)
def test_rotations_stay_exact_near_parallel_and_opposite(
    a: tuple, e: tuple, offset: float, sign: float
) -> None:
    a_arr, e_arr = np.array(a), np.array(e)
    if np.linalg.norm(a_arr) < 1e-3:
        return
    a_arr /= np.linalg.norm(a_arr)
    e_arr -= (e_arr @ a_arr) * a_arr
    if np.linalg.norm(e_arr) < 1e-3:
        return
    b = sign * a_arr + offset * e_arr / np.linalg.norm(e_arr)
    b /= np.linalg.norm(b)
    S = retarget_map(0.1 * a_arr, 0.3 * b)
    assert np.abs(S @ (0.1 * a_arr) - 0.3 * b).max() < 1e-14
    assert np.abs(S.T @ S - 9.0 * np.eye(3)).max() < 1e-12


def test_heading_orients_the_demo_for_a_vertical_segment(sawing: DMP) -> None:
    plunge = sawing.rollout([0, 0, 0.05], [0, 0, 0.0], heading=math.pi / 2)
    assert np.abs(plunge.y[:, 0]).max() < 1e-12  # strokes along y, none along x
    assert np.ptp(plunge.y[:, 1]) > 0.005  # scaled by 0.05 / 0.11 with the segment
    assert np.allclose(plunge.y[-1], [0, 0, 0], atol=1e-6)
    ignored = sawing.rollout([0, 0, 0.05], [0.1, 0, 0.0], heading=math.pi / 2)
    assert np.array_equal(ignored.y, sawing.rollout([0, 0, 0.05], [0.1, 0, 0.0]).y)
