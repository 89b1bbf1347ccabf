"""Stepping a SimScene along a timed joint trajectory, as a UR controller's servo would.

The controller runs at the trajectory's rate (125 Hz on a CB3): between two samples the joint
set-points move linearly (servoJ's interpolation), with velocity and inertial feed-forward so
the position servos do not lag; gravity is compensated through the actuators. The physics runs
`substeps` steps per controller period. After each period the tool tip, the joint torques and
the tool's contact with the board are recorded; a state that is not finite, a tool tip further
than `divergence_m` from the plan, or a torque above its limit stops the simulation. Every
run starts from the scene reset (SimScene.reset): a scene simulated before gives the same
result, bit for bit, as a new one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from keymps_mujoco.model import TORQUE_LIMITS_NM, SimScene


@dataclass
class Step:
    """What the simulation reports after each controller period (for painting and video)."""

    index: int
    t: float
    tip: np.ndarray
    tool_x: np.ndarray
    """The tool x axis in the board frame (a blade lies along its negative)."""


@dataclass
class SimResult:
    t: np.ndarray
    tip: np.ndarray
    """(n, 3) simulated tool tip at each sample time."""
    torque_max_nm: np.ndarray
    """(6,) largest |torque| per joint over the whole run."""
    torque_peak_t: np.ndarray
    contact_force_n: np.ndarray
    """(n,) the largest tool-board normal force within each controller period."""
    arm_contact_n: float
    """Largest normal force between an arm link and the board (should be 0)."""
    steps: int
    stopped: str | None = None
    """Why the simulation stopped early, or None."""
    stopped_at: int = -1
    wall_s: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)


@dataclass
class _Tracking:
    """What `simulate` records as it goes: per sample and the running maxima."""

    tips: np.ndarray
    """(n, 3) simulated tool tip at each sample, metres."""
    force: np.ndarray
    """(n,) the largest tool-board normal force within each controller period, N."""
    torque_max: np.ndarray
    """(joints,) largest |torque| so far, N m."""
    torque_peak_t: np.ndarray
    """(joints,) simulation time of each joint's largest torque, s."""
    arm_contact: float = 0.0
    """Largest normal force between an arm link and the board so far, N."""

    @classmethod
    def start(cls, samples: int, joints: int, tip: np.ndarray) -> _Tracking:
        tips = np.zeros((samples, 3))
        tips[0] = tip
        return cls(tips, np.zeros(samples), np.zeros(joints), np.zeros(joints))

    def torques(self, torque: np.ndarray, now: float) -> None:
        """Keep each joint's largest |torque| (N m) and when (s) it happened."""
        higher = torque > self.torque_max
        if higher.any():
            self.torque_max = np.where(higher, torque, self.torque_max)
            self.torque_peak_t = np.where(higher, now, self.torque_peak_t)

    def result(
        self, t: np.ndarray, substeps: int, stopped: str | None, stopped_at: int, wall_s: float
    ) -> SimResult:
        """The samples of times `t` (n,) s up to the end, or up to `stopped_at` and why."""
        last = len(t) if stopped is None else stopped_at + 1
        return SimResult(
            t=np.asarray(t[:last], dtype=float),
            tip=self.tips[:last],
            torque_max_nm=self.torque_max,
            torque_peak_t=self.torque_peak_t,
            contact_force_n=self.force[:last],
            arm_contact_n=self.arm_contact,
            steps=(last - 1) * substeps,
            stopped=stopped,
            stopped_at=stopped_at,
            wall_s=wall_s,
        )


def simulate(
    scene: SimScene,
    t: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    planned_tip: np.ndarray,
    rate_hz: float,
    *,
    divergence_m: float = 0.05,
    torque_limits: tuple[float, ...] = TORQUE_LIMITS_NM,
    joint_names: tuple[str, ...] = (),
    on_step: Callable[[Step], None] | None = None,
) -> SimResult:
    """Run a trajectory of n samples from a reset scene; `on_step` sees every controller
    period's end.

    Args:
        scene: The compiled scene with an arm, its servos tuned.
        t: (n,) sample times, seconds, one controller period apart.
        q: (n, joints) joint positions, radians; `qd` and `qdd` their rates (rad/s, rad/s^2).
        planned_tip: (n, 3) the planned tool tip, board frame, metres.
        rate_hz: The controller's rate.
        divergence_m: How far the tool tip may be from the plan before the run stops.
        torque_limits: (joints,) the largest |torque| per joint, N m.
        joint_names: Names for the stop message (`joint k` when missing).
        on_step: Called after each controller period.

    Returns:
        The samples up to the end, or up to where the run stopped and why.
    """
    import time

    scene.reset(q[0])  # a scene that ran before starts as a new one would
    substeps = _set_substeps(scene.model, rate_hz)
    leads = _feed_forward_leads(scene)
    limits = np.asarray(torque_limits, dtype=float)
    tracking = _Tracking.start(len(t), len(limits), scene.data.site_xpos[scene.tcp_site])
    started = time.perf_counter()
    stopped, stopped_at = None, -1
    for k in range(len(t) - 1):
        _run_period(scene, tracking, k, (q, qd, qdd), leads, substeps)
        at = float(t[k + 1])
        stopped = (
            _diverged(scene, at)
            or _off_plan(tracking.tips[k + 1], planned_tip[k + 1], at, divergence_m)
            or _over_torque(tracking, limits, joint_names)
        )
        if stopped is not None:
            stopped_at = k + 1
            break
        if on_step is not None:
            tool_x = scene.data.site_xmat[scene.tcp_site][[0, 3, 6]]
            on_step(Step(k + 1, at, tracking.tips[k + 1].copy(), tool_x))
    return tracking.result(t, substeps, stopped, stopped_at, time.perf_counter() - started)


def _set_substeps(model: Any, rate_hz: float) -> int:
    """Physics steps per controller period; the model's timestep is shortened (never
    lengthened) to divide the period exactly."""
    substeps = max(1, math.ceil(1.0 / (rate_hz * model.opt.timestep) - 1e-9))
    model.opt.timestep = 1.0 / (rate_hz * substeps)
    return substeps


def _feed_forward_leads(scene: SimScene) -> tuple[np.ndarray, np.ndarray]:
    """(joints,) each: how far the set-point leads per unit of joint velocity (kv / kp, s)
    and of acceleration (I / kp, s^2, I the joint's inertia at the current pose)."""
    import mujoco

    full = np.zeros((scene.model.nv, scene.model.nv))
    mujoco.mj_fullM(scene.model, scene.data, full)
    inertia = np.diag(full)[scene.dof_adr]
    return scene.kv / scene.kp, inertia / scene.kp


def _run_period(
    scene: SimScene,
    tracking: _Tracking,
    k: int,
    motion: tuple[np.ndarray, np.ndarray, np.ndarray],
    leads: tuple[np.ndarray, np.ndarray],
    substeps: int,
) -> None:
    """Step from sample k to k + 1 of `motion` ((n, joints) q, qd, qdd), the set-points
    moving linearly; records the torques, the board contacts and the tool tip."""
    import mujoco

    model, data = scene.model, scene.data
    (q, qd, qdd), (lead_v, lead_a) = motion, leads
    period_force, wrench = 0.0, np.zeros(6)
    for fraction in (np.arange(substeps) + 1.0) / substeps:
        blend = 1.0 - fraction
        target = blend * q[k] + fraction * q[k + 1]
        velocity = blend * qd[k] + fraction * qd[k + 1]
        acceleration = blend * qdd[k] + fraction * qdd[k + 1]
        data.ctrl[:] = target + lead_v * velocity + lead_a * acceleration
        mujoco.mj_step(model, data)
        tracking.torques(np.abs(data.qfrc_actuator[scene.dof_adr]), data.time)
        tool_force, arm_force = _board_contact_forces(scene, wrench)
        period_force = max(period_force, tool_force)
        tracking.arm_contact = max(tracking.arm_contact, arm_force)
    tracking.force[k + 1] = period_force
    tracking.tips[k + 1] = data.site_xpos[scene.tcp_site]


def _board_contact_forces(scene: SimScene, wrench: np.ndarray) -> tuple[float, float]:
    """The largest normal force (N) on the board from the tool and from the arm's links, in
    the current contacts (0 without any); `wrench` (6,) is scratch space."""
    import mujoco

    model, data, board = scene.model, scene.data, scene.board_geom
    tool_force = arm_force = 0.0
    for c in range(data.ncon):
        pair = data.contact.geom[c]
        a, b = int(pair[0]), int(pair[1])
        if board not in (a, b):
            continue
        mujoco.mj_contactForce(model, data, c, wrench)
        if (b if a == board else a) in scene.tool_geoms:
            tool_force = max(tool_force, float(wrench[0]))
        else:
            arm_force = max(arm_force, float(wrench[0]))
    return tool_force, arm_force


def _diverged(scene: SimScene, at: float) -> str | None:
    """Why to stop at time `at` (s) if the state is not finite."""
    data = scene.data
    if np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all():
        return None
    return f"the simulation diverged at t={at:.3f} s"


def _off_plan(tip: np.ndarray, planned: np.ndarray, at: float, divergence_m: float) -> str | None:
    """Why to stop if the tool tip (3,) is over `divergence_m` from the plan's (3,), metres."""
    miss = float(np.linalg.norm(tip - planned))
    if miss <= divergence_m:
        return None
    return (
        f"the tool tip is {miss * 1000:.0f} mm from the plan at t={at:.3f} s "
        f"(more than {divergence_m * 1000:.0f} mm: the simulation diverged)"
    )


def _over_torque(
    tracking: _Tracking, limits: np.ndarray, joint_names: tuple[str, ...]
) -> str | None:
    """Why to stop if a joint's largest torque so far is above its limit (N m): the joint
    furthest over, by ratio."""
    if not (tracking.torque_max > limits).any():
        return None
    joint = int(np.argmax(tracking.torque_max / limits))
    name = joint_names[joint] if joint < len(joint_names) else f"joint {joint + 1}"
    return (
        f"{name} needs {tracking.torque_max[joint]:.1f} N m at "
        f"t={tracking.torque_peak_t[joint]:.3f} s, above the limit of {limits[joint]:.3g} N m"
    )
