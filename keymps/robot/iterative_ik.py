"""Inverse kinematics of any arm: damped least squares on Pinocchio's frame Jacobian (CLIK).

Each step solves J dq = e in the damped least-squares sense (e: the tool frame's SE(3) error,
position and orientation, in the board-aligned frame), steps at most 0.5 rad, and is clipped to
the joint limits. An arm with more than six joints (the Panda's seventh) spends its redundancy
in J's null space, moving away from its joint limits (the squared distance from the middle of
each range, scaled by the range), in proportion to the pose error so that a path's postures
follow its points continuously. The full pose is the task: a 5-joint arm asked for an
orientation it cannot hold does not converge, and the caller refuses the point instead of
tilting the tool. Convergence is to 1e-9 m and 1e-8 rad (the timing differentiates joint paths
twice: solver noise would show as acceleration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from keymps.robot.probes import probe_configurations

POSITION_TOLERANCE_M = 1e-4
ROTATION_TOLERANCE_RAD = math.radians(0.1)
"""What a solution must meet (the contract); the solver itself goes far below."""
MAX_STEP_RAD = 0.5
"""Big steps can jump to another arm configuration."""
STALL_ITERATIONS = 15
STALL_RATIO = 0.5
"""A solve whose error has not halved in STALL_ITERATIONS iterations gives up (it is stuck at a
joint limit or the pose is out of reach): multi-start then tries the next seed."""
_EYE6 = np.eye(6)
NULLSPACE_GAIN = 0.2
"""Of the step towards the middle of the joint ranges, per iteration (redundant arms)..."""
NULLSPACE_SPAN = 0.05
""".. for an error of this much (metres and radians) or more; less for a smaller error."""


@dataclass(frozen=True)
class IkResult:
    """One inverse-kinematics solution and how far its pose is from the asked one."""

    q: np.ndarray
    position_error_m: float
    rotation_error_rad: float
    iterations: int

    @property
    def converged(self) -> bool:
        return (
            self.position_error_m <= POSITION_TOLERANCE_M
            and self.rotation_error_rad <= ROTATION_TOLERANCE_RAD
        )


class IterativeIk:
    """Damped least-squares IK of one frame of a Pinocchio model, inside its joint limits."""

    def __init__(self, model: Any, frame: int, lower: np.ndarray, upper: np.ndarray) -> None:
        self.model, self.frame = model, frame
        self.data = model.createData()
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.middle = (self.lower + self.upper) / 2.0
        span = np.minimum(self.upper - self.lower, 4.0 * math.pi)  # +-2 turns: no pull at all
        self.weight = 1.0 / span**2
        self.redundant = model.nv > 6

    def solve(
        self,
        position: np.ndarray,
        rotation: np.ndarray,
        seed: np.ndarray,
        *,
        max_iterations: int = 100,
        damping: float = 1e-3,
    ) -> IkResult:
        """The joints putting the frame at `position` (3,) with `rotation` (3, 3), from `seed`."""
        import pinocchio as pin

        model, data, frame = self.model, self.data, self.frame
        target_p, target_r = np.asarray(position, float), np.asarray(rotation, float)
        lower, upper = self.lower, self.upper
        q = np.minimum(np.maximum(np.array(seed, dtype=float), lower), upper)
        damping2 = damping * damping
        error = np.zeros(6)
        pos_err = rot_err = math.inf
        iteration = 0
        checkpoint = math.inf
        for iteration in range(max_iterations + 1):
            pin.forwardKinematics(model, data, q)
            pose = pin.updateFramePlacement(model, data, frame)
            error[:3] = target_p - pose.translation
            rot_local = pin.log3(pose.rotation.T @ target_r)
            error[3:] = pose.rotation @ rot_local
            pos_err = math.sqrt(float(error[:3] @ error[:3]))
            rot_err = math.sqrt(float(rot_local @ rot_local))
            if (pos_err < 1e-9 and rot_err < 1e-8) or iteration == max_iterations:
                break
            if iteration % STALL_ITERATIONS == 0:  # stuck (at a joint limit, out of reach)?
                if pos_err + rot_err > STALL_RATIO * checkpoint:
                    break
                checkpoint = pos_err + rot_err
            jacobian = pin.computeFrameJacobian(
                model, data, q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
            )
            step = self._step(jacobian, error, q, damping2)
            largest = float(np.abs(step).max())
            if largest > MAX_STEP_RAD:
                step *= MAX_STEP_RAD / largest
            q = np.minimum(np.maximum(q + step, lower), upper)
        return IkResult(q, pos_err, rot_err, iteration)

    def _step(
        self, jacobian: np.ndarray, error: np.ndarray, q: np.ndarray, damping2: float
    ) -> np.ndarray:
        """The damped least-squares step, plus for a redundant arm the step away from its joint
        limits projected into the Jacobian's null space."""
        inverse = jacobian.T @ np.linalg.inv(jacobian @ jacobian.T + damping2 * _EYE6)
        step = inverse @ error
        if self.redundant:
            # In proportion to the error: along a path the posture then follows the tool
            # continuously, the same however many iterations a point takes.
            scale = NULLSPACE_GAIN * min(1.0, float(np.linalg.norm(error)) / NULLSPACE_SPAN)
            away = -scale * self.weight * (q - self.middle) / self.weight.max()
            step += away - inverse @ (jacobian @ away)
        return step

    def solve_from_anywhere(
        self,
        position: np.ndarray,
        rotation: np.ndarray,
        seeds: list[np.ndarray],
        *,
        tries: int = 16,
    ) -> IkResult:
        """`solve` from each seed in turn, then from spread-out configurations, until one
        converges: the best found (the one that converged, else the least position error)."""
        spread = probe_configurations(tries, len(self.lower))
        unit = (spread + math.pi) / (2 * math.pi)  # [0, 1): a point of every joint's range
        candidates = [*seeds, *(self.lower + unit * (self.upper - self.lower))]
        best: IkResult | None = None
        for seed in candidates:
            result = self.solve(position, rotation, seed, max_iterations=200)
            if result.converged:
                return result
            if best is None or result.position_error_m < best.position_error_m:
                best = result
        assert best is not None
        return best
