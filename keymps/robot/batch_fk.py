"""Forward kinematics of a Pinocchio model for many configurations at once, in numpy.

Pinocchio evaluates one configuration per call; the safety check and the simulator need tens of
thousands (every sample, the replay at 1 kHz), where the per-call overhead dominates. This
module reads the model's own joint placements, axes and frame placements and composes them
for all configurations with batched matrix products, in Pinocchio's order (oMi = oMparent *
placement * joint motion). `BatchKinematics.for_model` compares it with Pinocchio at random
configurations and refuses (returns None) any model it does not reproduce to 1e-12.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from keymps.robot.probes import probe_configurations

AGREEMENT = 1e-12
CHUNK = 4096
"""Configurations per pass: keeps every temporary in cache and out of fresh memory mappings
(a pass over all 28,000 replay samples at once is about 1.4x slower)."""


@dataclass(frozen=True)
class _Joint:
    """One revolute joint of the chain: its parent, placement and axis."""

    parent: int
    q_index: int
    rotation: np.ndarray
    translation: np.ndarray
    cross: np.ndarray
    """K, the cross-product matrix of the joint's unit axis."""

    principal: int | None
    """0, 1, 2 when the axis is the local x, y or z axis (the common case: a cheaper turn)."""

    @property
    def cross2(self) -> np.ndarray:
        return self.cross @ self.cross

    @property
    def rotation_is_identity(self) -> bool:
        return bool(np.array_equal(self.rotation, np.eye(3)))


@dataclass(frozen=True)
class BatchKinematics:
    """Revolute chains only (the UR arms); joint i's pose and any frame on a joint."""

    joints: tuple[_Joint, ...]
    """Joints 1.. of the model (joint 0 is the universe)."""

    @classmethod
    def for_model(cls, model: Any) -> BatchKinematics | None:
        joints = []
        for index in range(1, model.njoints):
            axis = _revolute_axis(model.joints[index])
            if axis is None or model.joints[index].nq != 1:
                return None
            placement = model.jointPlacements[index]
            joints.append(
                _Joint(
                    int(model.parents[index]),
                    int(model.joints[index].idx_q),
                    np.array(placement.rotation),
                    np.array(placement.translation),
                    _cross_matrix(axis),
                    _principal(axis),
                )
            )
        kinematics = cls(tuple(joints))
        return kinematics if kinematics.agrees_with(model) else None

    def joint_poses(
        self, qs: np.ndarray, cos_sin: tuple[np.ndarray, np.ndarray] | None = None
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per joint (0: the universe), rotations (3, 3, n) and origins (3, n) for (n, nq)
        configurations: component-major, so that every step is a few long vector operations.
        `cos_sin`: the angles' cosines and sines (nq, n) when the caller has them already."""
        qs = np.atleast_2d(np.asarray(qs, dtype=float))
        n = len(qs)
        if cos_sin is None:
            angles = np.ascontiguousarray(qs.T)
            cos_sin = np.cos(angles), np.sin(angles)
        cos, sin = cos_sin
        poses = [(np.repeat(np.eye(3)[:, :, None], n, axis=2), np.zeros((3, n)))]
        for joint in self.joints:
            parent_r, parent_p = poses[joint.parent]
            if joint.rotation_is_identity:
                fixed = parent_r
            else:
                fixed = np.einsum("ijn,jk->ikn", parent_r, joint.rotation)
            origin = parent_p + np.einsum("ijn,j->in", parent_r, joint.translation)
            column = joint.q_index
            poses.append((_turn(fixed, joint, cos[column], sin[column]), origin))
        return poses

    def frame_poses(
        self,
        qs: np.ndarray,
        joint: int,
        placement: Any,
        cos_sin: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) positions and (n, 3, 3) rotations of a frame placed at `placement` on `joint`
        (`cos_sin` as for `joint_poses`)."""
        qs = np.atleast_2d(np.asarray(qs, dtype=float))
        return _in_chunks(
            qs, cos_sin, lambda q, cs: self._frame(self.joint_poses(q, cs), joint, placement)
        )

    def frame_poses_and_origins(
        self, qs: np.ndarray, joint: int, placement: Any, extra: tuple[int, Any] | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`frame_poses` and `origins` from one pass over the chain (the same values)."""

        def both(q: np.ndarray, _: Any) -> tuple[np.ndarray, ...]:
            poses = self.joint_poses(q)
            return (*self._frame(poses, joint, placement), self._origins(poses, extra))

        return _in_chunks(np.atleast_2d(np.asarray(qs, dtype=float)), None, both)

    def frame_positions_and_x_axes(
        self,
        qs: np.ndarray,
        joint: int,
        placement: Any,
        cos_sin: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """`frame_poses` with only the rotations' first columns, (n, 3) each (the same values):
        for up to CHUNK configurations."""
        rotation, origin = self.joint_poses(qs, cos_sin)[joint]
        position = origin + np.einsum("ijn,j->in", rotation, np.array(placement.translation))
        x_axis = np.einsum("ijn,j->in", rotation, np.array(placement.rotation)[:, 0].copy())
        return np.ascontiguousarray(position.T), np.ascontiguousarray(x_axis.T)

    def _frame(
        self, poses: list[tuple[np.ndarray, np.ndarray]], joint: int, placement: Any
    ) -> tuple[np.ndarray, np.ndarray]:
        rotation, origin = poses[joint]
        position = origin + np.einsum("ijn,j->in", rotation, np.array(placement.translation))
        turned = np.einsum("ijn,jk->nik", rotation, np.array(placement.rotation))
        return np.ascontiguousarray(position.T), np.ascontiguousarray(turned)

    def _origins(
        self, poses: list[tuple[np.ndarray, np.ndarray]], extra: tuple[int, Any] | None
    ) -> np.ndarray:
        points = [origin for _, origin in poses[1:]]
        if extra is not None:
            rotation, origin = poses[extra[0]]
            points.append(origin + np.einsum("ijn,j->in", rotation, np.array(extra[1].translation)))
        return np.ascontiguousarray(np.stack(points).transpose(2, 0, 1))

    def origins(self, qs: np.ndarray, extra: tuple[int, Any] | None = None) -> np.ndarray:
        """(n, njoints - 1 [+ 1], 3): the joints' origins [and a frame's, (joint, placement)]."""
        qs = np.atleast_2d(np.asarray(qs, dtype=float))
        return _in_chunks(qs, None, lambda q, _: self._origins(self.joint_poses(q), extra))

    def agrees_with(self, model: Any) -> bool:
        """True when these kinematics match Pinocchio's `model` on a few probe configurations."""
        import pinocchio as pin

        data = model.createData()
        qs = probe_configurations(4, model.nq)
        poses = self.joint_poses(qs)
        for k, q in enumerate(qs):
            pin.forwardKinematics(model, data, q)
            for index in range(1, model.njoints):
                pose, (rotation, origin) = data.oMi[index], poses[index]
                if (
                    np.abs(pose.rotation - rotation[:, :, k]).max() > AGREEMENT
                    or np.abs(pose.translation - origin[:, k]).max() > AGREEMENT
                ):
                    return False
        return True


def _in_chunks(qs: np.ndarray, cos_sin: Any, compute: Callable[[np.ndarray, Any], Any]) -> Any:
    """compute(qs, cos_sin) over chunks of at most CHUNK configurations (fresh memory for one
    long pass costs more than the arithmetic), the arrays it returns concatenated: an array,
    or a tuple of arrays."""
    if len(qs) <= CHUNK:
        return compute(qs, cos_sin)
    parts = [
        compute(
            qs[a : a + CHUNK],
            None
            if cos_sin is None
            else (cos_sin[0][:, a : a + CHUNK], cos_sin[1][:, a : a + CHUNK]),
        )
        for a in range(0, len(qs), CHUNK)
    ]
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate(column) for column in zip(*parts, strict=True))
    return np.concatenate(parts)


def _revolute_axis(joint: Any) -> np.ndarray | None:
    name = joint.shortname()
    simple = {"JointModelRX": (1.0, 0, 0), "JointModelRY": (0, 1.0, 0), "JointModelRZ": (0, 0, 1.0)}
    if name in simple:
        return np.array(simple[name], dtype=float)
    if name == "JointModelRevoluteUnaligned":
        return np.array(joint.axis, dtype=float)
    return None


def _principal(axis: np.ndarray) -> int | None:
    for index in range(3):
        if np.array_equal(axis, np.eye(3)[index]):
            return index
    return None


def _turn(fixed: np.ndarray, joint: _Joint, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """fixed (3, 3, n) times the joint's rotation about its axis by angles of cosines c and
    sines s (n,)."""
    if joint.principal is None:  # Rodrigues: I + sin K + (1 - cos) K^2
        turned = fixed + s * np.einsum("ijn,jk->ikn", fixed, joint.cross)
        turned += (1.0 - c) * np.einsum("ijn,jk->ikn", fixed, joint.cross2)
        return turned
    # About a principal axis only the two other columns mix: (a, b) -> (a c + b s, b c - a s).
    first, second = {0: (1, 2), 1: (2, 0), 2: (0, 1)}[joint.principal]
    turned = np.empty_like(fixed)
    turned[:, joint.principal] = fixed[:, joint.principal]
    a, b = fixed[:, first], fixed[:, second]
    np.multiply(a, c, out=turned[:, first])  # in place: a * c + b * s, b * c - a * s
    turned[:, first] += b * s
    np.multiply(b, c, out=turned[:, second])
    turned[:, second] -= a * s
    return turned


def _cross_matrix(axis: np.ndarray) -> np.ndarray:
    x, y, z = axis / np.linalg.norm(axis)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def interpolated_cos_sin(qs: np.ndarray, substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """Cosines and sines of the angles qs[i] + j / substeps * (qs[i + 1] - qs[i]) for every
    sample i but the last and j = 0 .. substeps - 1, then of qs[-1]: (nq, (n - 1) * substeps
    + 1) each, in that order (component-major, as `joint_poses` takes them).

    Trigonometric functions dominate batched forward kinematics. Each substep turns the
    previous angle by the same small angle (a rotation recurrence, exact but for a few
    rounding errors), so only the samples and their steps need cos and sin."""
    qs = np.asarray(qs, dtype=float)
    n, nq = qs.shape
    angles = np.ascontiguousarray(qs.T)
    step = (angles[:, 1:] - angles[:, :-1]) / substeps
    cos, sin = np.empty((substeps, nq, n - 1)), np.empty((substeps, nq, n - 1))
    cos[0], sin[0] = np.cos(angles[:, :-1]), np.sin(angles[:, :-1])
    cos_step, sin_step = np.cos(step), np.sin(step)
    for j in range(1, substeps):
        np.multiply(cos[j - 1], cos_step, out=cos[j])
        cos[j] -= sin[j - 1] * sin_step
        np.multiply(sin[j - 1], cos_step, out=sin[j])
        sin[j] += cos[j - 1] * sin_step
    out_cos, out_sin = (
        np.empty((nq, (n - 1) * substeps + 1)),
        np.empty((nq, (n - 1) * substeps + 1)),
    )
    out_cos[:, :-1].reshape(nq, n - 1, substeps)[:] = cos.transpose(1, 2, 0)
    out_sin[:, :-1].reshape(nq, n - 1, substeps)[:] = sin.transpose(1, 2, 0)
    out_cos[:, -1], out_sin[:, -1] = np.cos(angles[:, -1]), np.sin(angles[:, -1])
    return out_cos, out_sin
