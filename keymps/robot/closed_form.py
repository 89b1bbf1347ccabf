"""The UR arms' analytic inverse kinematics, vectorized over many poses.

A UR arm has three parallel axes (shoulder lift, elbow, wrist 1) and a wrist whose last two axes
cross the flange axis, so every flange pose has up to eight joint solutions in closed form:
shoulder left/right, wrist up/down, elbow up/down (the classic derivation on the maker's DH
table: Hawkins, "Analytic Inverse Kinematics for the Universal Robots UR-5/UR-10 Arms", 2013).

The solver works in the DH frames. How those sit in the Pinocchio model (the URDF's base_link
placed on the board, the TCP on the flange) is not assumed: `ClosedFormIk.for_model` measures
both fixed transforms from Pinocchio's forward kinematics and refuses (returns None) unless
the DH chain between them reproduces the model at random configurations to 1e-10.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from keymps.robot.description import ArmGeometry
from keymps.robot.probes import probe_configurations

BRANCHES = 8
"""Solutions per pose: (shoulder, wrist, elbow) signs, index = 4 shoulder + 2 wrist + elbow."""
MODEL_AGREEMENT = 1e-10
"""The URDF writes its quarter turns with 10 digits: its chain differs from the exact DH table
by about 1.5e-11 m (and rad), far below the 1e-9 m every solution is verified to."""
_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)


def _dh(arm: ArmGeometry) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(d, a) of the maker's DH table."""
    return (arm.d1, 0.0, 0.0, arm.d4, arm.d5, arm.d6), (0.0, -arm.upper_arm, -arm.forearm, 0, 0, 0)


def dh_link(theta: np.ndarray, i: int, arm: ArmGeometry) -> np.ndarray:
    """(..., 4, 4) DH transforms of joint i (0-based) at angles theta (...)."""
    d, a = _dh(arm)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = math.cos(_ALPHA[i]), math.sin(_ALPHA[i])
    out = np.zeros((*np.shape(theta), 4, 4))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2], out[..., 0, 3] = (
        ct,
        -st * ca,
        st * sa,
        a[i] * ct,
    )
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2], out[..., 1, 3] = (
        st,
        ct * ca,
        -ct * sa,
        a[i] * st,
    )
    out[..., 2, 1], out[..., 2, 2], out[..., 2, 3] = sa, ca, d[i]
    out[..., 3, 3] = 1.0
    return out


def inverse_dh_link(
    theta: np.ndarray,
    i: int,
    arm: ArmGeometry,
    cos_sin: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """`_inverse(dh_link(theta, i, arm))` built directly: the rotation transposed and the
    translation -R^T p summed in einsum's order (the same numbers, a third of the work).
    `cos_sin`: np.cos(theta), np.sin(theta) when the caller has them already."""
    d, a = _dh(arm)
    ct, st = (np.cos(theta), np.sin(theta)) if cos_sin is None else cos_sin
    ca, sa = math.cos(_ALPHA[i]), math.sin(_ALPHA[i])
    rotation = ((ct, -st * ca, st * sa), (st, ct * ca, -ct * sa), (0.0, sa, ca))
    p = (a[i] * ct, a[i] * st, d[i])
    out = np.zeros((*np.shape(theta), 4, 4))
    for row in range(3):
        for column in range(3):
            out[..., row, column] = rotation[column][row]
        out[..., row, 3] = -(
            (rotation[0][row] * p[0] + rotation[1][row] * p[1]) + rotation[2][row] * p[2]
        )
    out[..., 3, 3] = 1.0
    return out


def _inverse(pose: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms."""
    out = np.zeros_like(pose)
    rotation_t = np.swapaxes(pose[..., :3, :3], -1, -2)
    out[..., :3, :3] = rotation_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rotation_t, pose[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def dh_flange(q: np.ndarray, arm: ArmGeometry) -> np.ndarray:
    """(..., 4, 4) flange poses in the DH base frame for joints (..., 6)."""
    q = np.asarray(q, dtype=float)
    pose = dh_link(q[..., 0], 0, arm)
    for i in range(1, 6):
        pose = pose @ dh_link(q[..., i], i, arm)
    return pose


@dataclass(frozen=True)
class ClosedFormIk:
    """Analytic IK of one arm between two fixed transforms measured on its Pinocchio model."""

    arm: ArmGeometry
    board_from_dh: np.ndarray
    """(4, 4) the DH base frame in the board frame."""
    flange_from_tcp: np.ndarray
    """(4, 4) the TCP frame in the DH flange frame."""

    @classmethod
    def for_model(
        cls, arm: ArmGeometry, base_link_in_board: np.ndarray, fk: Any
    ) -> ClosedFormIk | None:
        """The solver for a model whose TCP pose is `fk(q) -> (position, rotation)`, its URDF
        base_link at `base_link_in_board` (4, 4); None when the DH chain does not reproduce
        Pinocchio's forward kinematics to 1e-10 (another robot, a changed URDF)."""

        def tcp(q: np.ndarray) -> np.ndarray:
            position, rotation = fk(q)
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = rotation, position
            return pose

        # The URDF's convention: the DH base frame is base_link turned by pi about z.
        board_from_dh = np.asarray(base_link_in_board, dtype=float) @ np.diag([-1.0, -1.0, 1, 1])
        zero = np.zeros(6)
        flange_from_tcp = _inverse(board_from_dh @ dh_flange(zero, arm)) @ tcp(zero)
        for q in probe_configurations(4, 6):
            got = board_from_dh @ dh_flange(q, arm) @ flange_from_tcp
            if not np.allclose(got, tcp(q), atol=MODEL_AGREEMENT, rtol=0.0):
                return None
        return cls(arm, board_from_dh, flange_from_tcp)

    def flange_targets(self, tcp_poses: np.ndarray) -> np.ndarray:
        """(n, 4, 4) flange poses in the DH base frame for TCP poses in the board frame."""
        return _inverse(self.board_from_dh) @ tcp_poses @ _inverse(self.flange_from_tcp)

    def solve(self, tcp_poses: np.ndarray) -> np.ndarray:
        """(n, 8, 6) joint solutions (NaN where a branch does not exist), angles in (-pi, pi]."""
        targets = self.flange_targets(np.asarray(tcp_poses, dtype=float))
        return solve_flange(targets, self.arm)


def solve_flange(targets: np.ndarray, arm: ArmGeometry) -> np.ndarray:
    """(n, 8, 6) all analytic solutions for flange poses (n, 4, 4) in the DH base frame."""
    d, a = _dh(arm)
    d1, d4, d5, d6, a2, a3 = d[0], d[3], d[4], d[5], a[1], a[2]
    del d1, d5  # they enter through the DH links below
    n = len(targets)
    out = np.full((n, BRANCHES, 6), np.nan)
    p06 = targets[:, :3, 3]
    z06 = targets[:, :3, 2]
    p05 = p06 - d6 * z06
    radius = np.hypot(p05[:, 0], p05[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = np.arccos(d4 / radius)
        psi = np.arctan2(p05[:, 1], p05[:, 0])
        r = targets[:, :3, :3]
        for shoulder, sign1 in enumerate((1.0, -1.0)):
            theta1 = psi + sign1 * phi + math.pi / 2
            s1, c1 = np.sin(theta1), np.cos(theta1)
            t16 = inverse_dh_link(theta1, 0, arm, (c1, s1)) @ targets
            cos5 = (p06[:, 0] * s1 - p06[:, 1] * c1 - d4) / d6
            cos5 = np.where(np.abs(cos5) <= 1.0 + 1e-12, np.clip(cos5, -1.0, 1.0), np.nan)
            angle5 = np.arccos(cos5)
            for wrist, sign5 in enumerate((1.0, -1.0)):
                theta5 = sign5 * angle5
                s5 = np.sin(theta5)
                y_arg = (-r[:, 0, 1] * s1 + r[:, 1, 1] * c1) / s5
                x_arg = (r[:, 0, 0] * s1 - r[:, 1, 0] * c1) / s5
                theta6 = np.where(np.abs(s5) > 1e-12, np.arctan2(y_arg, x_arg), 0.0)
                t14 = t16 @ inverse_dh_link(theta6, 5, arm) @ inverse_dh_link(theta5, 4, arm)
                # Axes 2-4 are parallel to frame 1's z: the arm's plane is frame 1's x-y.
                px, py = t14[:, 0, 3], t14[:, 1, 3]
                cos3 = (px**2 + py**2 - a2**2 - a3**2) / (2 * a2 * a3)
                cos3 = np.where(np.abs(cos3) <= 1.0 + 1e-12, np.clip(cos3, -1.0, 1.0), np.nan)
                angle3 = np.arccos(cos3)
                for elbow, sign3 in enumerate((1.0, -1.0)):
                    theta3 = sign3 * angle3
                    c3, s3 = np.cos(theta3), np.sin(theta3)
                    along, across = a2 + a3 * c3, a3 * s3
                    theta2 = np.arctan2(along * py - across * px, along * px + across * py)
                    t34 = (
                        inverse_dh_link(theta3, 2, arm, (c3, s3))
                        @ inverse_dh_link(theta2, 1, arm)
                        @ t14
                    )
                    theta4 = np.arctan2(t34[:, 1, 0], t34[:, 0, 0])
                    branch = 4 * shoulder + 2 * wrist + elbow
                    q = np.column_stack([theta1, theta2, theta3, theta4, theta5, theta6])
                    out[:, branch] = (q + math.pi) % (2 * math.pi) - math.pi
    return out
