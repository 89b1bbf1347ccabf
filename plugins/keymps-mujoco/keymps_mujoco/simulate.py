"""Stepping a SimScene along a timed joint trajectory, as a UR controller's servo would.

The controller runs at the trajectory's rate (125 Hz on a CB3): between two samples the joint
set-points move linearly (servoJ's interpolation), with velocity and inertial feed-forward so
the position servos do not lag; gravity is compensated through the actuators. The physics runs
`substeps` steps per controller period. After each period the tool tip, the joint torques and
the tool's contact with the board are recorded; a state that is not finite, a tool tip further
than `divergence_m` from the plan, or a torque above its limit stops the simulation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

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
    """Run the trajectory (n samples); `on_step` sees every controller period's end."""
    import time

    import mujoco

    model, data = scene.model, scene.data
    substeps = max(1, math.ceil(1.0 / (rate_hz * model.opt.timestep) - 1e-9))
    model.opt.timestep = 1.0 / (rate_hz * substeps)
    n = len(t)
    scene.set_joints(q[0])
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    inertia = np.diag(full)[scene.dof_adr]
    kp, kv = scene.kp, scene.kv
    lead_v = kv / kp
    lead_a = inertia / kp
    limits = np.asarray(torque_limits, dtype=float)
    tips = np.zeros((n, 3))
    tips[0] = data.site_xpos[scene.tcp_site]
    torque_max = np.zeros(len(limits))
    torque_peak_t = np.zeros(len(limits))
    force = np.zeros(n)
    arm_contact = 0.0
    tool_geoms = scene.tool_geoms
    board = scene.board_geom
    wrench = np.zeros(6)
    fractions = (np.arange(substeps) + 1.0) / substeps
    started = time.perf_counter()
    stopped, stopped_at = None, -1
    dofs = scene.dof_adr
    for k in range(n - 1):
        period_force = 0.0
        for fraction in fractions:
            blend = 1.0 - fraction
            target = blend * q[k] + fraction * q[k + 1]
            velocity = blend * qd[k] + fraction * qd[k + 1]
            acceleration = blend * qdd[k] + fraction * qdd[k + 1]
            data.ctrl[:] = target + lead_v * velocity + lead_a * acceleration
            mujoco.mj_step(model, data)
            torque = np.abs(data.qfrc_actuator[dofs])
            higher = torque > torque_max
            if higher.any():
                torque_max = np.where(higher, torque, torque_max)
                torque_peak_t = np.where(higher, data.time, torque_peak_t)
            for c in range(data.ncon):
                pair = data.contact.geom[c]
                a, b = int(pair[0]), int(pair[1])
                if board not in (a, b):
                    continue
                other = b if a == board else a
                mujoco.mj_contactForce(model, data, c, wrench)
                if other in tool_geoms:
                    period_force = max(period_force, float(wrench[0]))
                else:
                    arm_contact = max(arm_contact, float(wrench[0]))
        force[k + 1] = period_force
        tips[k + 1] = data.site_xpos[scene.tcp_site]
        if not (np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()):
            stopped, stopped_at = f"the simulation diverged at t={t[k + 1]:.3f} s", k + 1
            break
        miss = float(np.linalg.norm(tips[k + 1] - planned_tip[k + 1]))
        if miss > divergence_m:
            stopped = (
                f"the tool tip is {miss * 1000:.0f} mm from the plan at t={t[k + 1]:.3f} s "
                f"(more than {divergence_m * 1000:.0f} mm: the simulation diverged)"
            )
            stopped_at = k + 1
            break
        over = torque_max > limits
        if over.any():
            joint = int(np.argmax(torque_max / limits))
            name = joint_names[joint] if joint < len(joint_names) else f"joint {joint + 1}"
            stopped = (
                f"{name} needs {torque_max[joint]:.1f} N m at "
                f"t={torque_peak_t[joint]:.3f} s, above the limit of {limits[joint]:.3g} N m"
            )
            stopped_at = k + 1
            break
        if on_step is not None:
            on_step(
                Step(
                    k + 1,
                    float(t[k + 1]),
                    tips[k + 1].copy(),
                    data.site_xmat[scene.tcp_site][[0, 3, 6]],
                )
            )
    last = n if stopped is None else stopped_at + 1
    return SimResult(
        t=np.asarray(t[:last], dtype=float),
        tip=tips[:last],
        torque_max_nm=torque_max,
        torque_peak_t=torque_peak_t,
        contact_force_n=force[:last],
        arm_contact_n=arm_contact,
        steps=(last - 1) * substeps,
        stopped=stopped,
        stopped_at=stopped_at,
        wall_s=time.perf_counter() - started,
    )
