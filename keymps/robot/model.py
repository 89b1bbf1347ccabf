"""The UR3 (or UR3e) in Pinocchio: base placed in the board frame, tool TCP, FK and IK.

Conventions:
- task.robot.base = (x, y, z, yaw_deg) is the pose of the URDF root link `base_link` (ROS
  convention: z up through joint 1, x towards where the arm points at shoulder_pan = 0) in the
  board frame. The controller's own base frame (teach pendant, RTDE poses) is base_link turned
  by 180 degrees about z.
- The tool points straight down (tool z = -board z); its yaw is the angle of the tool x axis
  about board z. Rotation of the tool frame: Rz(yaw) @ diag(1, -1, -1).
- Joint angles are the controller's (same zero and sign as the UR pendant and ur_rtde).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.robot.batch_fk import CHUNK as BATCH_CHUNK
from keymps.robot.batch_fk import BatchKinematics
from keymps.robot.closed_form import ClosedFormIk
from keymps.robot.description import (
    ARMS,
    BUILTIN_TOOLS,
    JOINT_NAMES,
    POSITION_TOLERANCE_M,
    REACH_MARGIN_M,
    ROTATION_TOLERANCE_RAD,
    ArmGeometry,
    Tool,
    build_pinocchio_model,
    rz,
    se3,
    tool_from_task,
    tool_rotation,
    ur_urdf_path,
)
from keymps.types import JointPath, Piece, ToolPath

__all__ = [
    "ARMS",
    "BUILTIN_TOOLS",
    "JOINT_NAMES",
    "ArmGeometry",
    "IkResult",
    "RobotModel",
    "Tool",
    "solve_path",
    "tool_from_task",
    "tool_rotation",
    "ur_urdf_path",
]

if TYPE_CHECKING:
    from keymps.config.task import Task


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


@dataclass(frozen=True)
class _Kinematics:
    """What a RobotModel builds and checks once per arm, base and tool (about 5 ms): the
    Pinocchio model (read-only; each RobotModel has its own Data), the batched FK and the
    closed-form IK, each verified against that model."""

    model: Any
    tcp_frame: int
    batch: BatchKinematics | None
    closed_form: ClosedFormIk | None


_KINEMATICS: dict[tuple[Any, ...], _Kinematics] = {}
"""Per process, by (kind, base, tool): `keymps eval` builds the same robot for every run."""
KINEMATICS_KEPT = 16


class RobotModel:
    """A UR arm placed on the board with a tool: FK, IK and limits."""

    def __init__(
        self,
        kind: str = "ur3",
        base: tuple[float, float, float, float] = (0.15, -0.20, 0.0, 90.0),
        tool: Tool = BUILTIN_TOOLS["knife"],
        *,
        max_joint_acceleration: float = 3.0,
        max_joint_jerk: float = 30.0,
        board_size: tuple[float, float] = (0.30, 0.18),
        object_height: float = 0.05,
        clearance: float = 0.03,
    ):
        if kind not in ARMS:
            raise KeympsError(f"robot.model: unknown arm {kind!r} (available: {', '.join(ARMS)})")
        self.kind = kind
        self.arm = ARMS[kind]
        self.base = tuple(float(v) for v in base)
        self.tool = tool
        self.board_size = board_size
        self.object_height = float(object_height)
        self.clearance = float(clearance)
        x, y, z, yaw_deg = self.base
        self.base_in_board = se3(rz(math.radians(yaw_deg)), np.array([x, y, z]))
        key = (kind, self.base, tool)
        known = _KINEMATICS.get(key)
        if known is None:
            self.model, self.tcp_frame = build_pinocchio_model(self.arm, self.base_in_board, tool)
        else:
            self.model, self.tcp_frame = known.model, known.tcp_frame
        self.flange_frame = self.model.getFrameId("flange")
        self.data = self.model.createData()
        self.joint_names = JOINT_NAMES
        self.lower = np.array(self.model.lowerPositionLimit, dtype=float)
        self.upper = np.array(self.model.upperPositionLimit, dtype=float)
        self.velocity_limits = np.array(self.arm.joint_speed_limits, dtype=float)
        self.acceleration_limits = np.full(6, float(max_joint_acceleration))
        self.jerk_limits = np.full(6, float(max_joint_jerk))
        self.urdf_path = ur_urdf_path()
        self._tcp_frame = self.model.frames[self.tcp_frame]
        self._flange = self.model.frames[self.flange_frame]
        if known is None:
            batch = BatchKinematics.for_model(self.model)
            closed_form = ClosedFormIk.for_model(self.arm, self.base_in_board.homogeneous, self.fk)
            if len(_KINEMATICS) >= KINEMATICS_KEPT:
                _KINEMATICS.pop(next(iter(_KINEMATICS)), None)  # the oldest
            known = _KINEMATICS.setdefault(
                key, _Kinematics(self.model, self.tcp_frame, batch, closed_form)
            )
        self.batch = known.batch
        """Forward kinematics of many configurations at once (None: one Pinocchio call each)."""
        self.closed_form = known.closed_form
        """The analytic IK, None when the DH chain does not reproduce this model (then every
        point is solved iteratively)."""

    @classmethod
    def from_task(cls, task: Task) -> RobotModel:
        robot = task.robot
        return cls(
            robot.model,
            robot.base,
            tool_from_task(task),
            max_joint_acceleration=robot.max_joint_acceleration,
            max_joint_jerk=robot.max_joint_jerk,
            board_size=task.scene.workspace.size,
            object_height=task.scene.tallest_object_height,
            clearance=task.motion.clearance,
        )

    @property
    def rate_hz(self) -> float:
        """The controller's default rate: 125 Hz (CB3) or 500 Hz (e-Series)."""
        return self.arm.rate_hz

    # -- forward kinematics --------------------------------------------------------------------

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool tip position (3,) and rotation (3, 3) in the board frame."""
        import pinocchio as pin

        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        pose = self.data.oMf[self.tcp_frame]
        return np.array(pose.translation), np.array(pose.rotation)

    def tool_positions(self, qs: np.ndarray) -> np.ndarray:
        """(n, 3) tool tip positions for (n, 6) joint vectors."""
        return self.tool_poses(qs)[0]

    def tool_poses(
        self, qs: np.ndarray, cos_sin: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) tool tip positions and (n, 3, 3) rotations for (n, 6) joint vectors
        (`cos_sin`: their cosines and sines, (6, n) each, when the caller has them)."""
        if self.batch is None or len(qs) == 0:
            return self.pinocchio_tool_poses(qs)
        frame = self._tcp_frame
        return self.batch.frame_poses(qs, frame.parentJoint, frame.placement, cos_sin)

    def tool_positions_and_x_axes(
        self, qs: np.ndarray, cos_sin: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) tool tip positions and tool x axes (the rotations' first columns) for (n, 6)
        joint vectors, as `tool_poses` gives them, without the rest of the rotations."""
        if self.batch is None or len(qs) == 0 or len(qs) > BATCH_CHUNK:
            positions, rotations = self.tool_poses(qs, cos_sin)
            return positions, rotations[:, :, 0]
        frame = self._tcp_frame
        return self.batch.frame_positions_and_x_axes(
            qs, frame.parentJoint, frame.placement, cos_sin
        )

    def tool_poses_and_joint_origins(
        self, qs: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`tool_poses` and `joint_origins_many` of (n, 6) joint vectors, in one pass when
        batched."""
        if self.batch is None or len(qs) == 0:
            return (*self.tool_poses(qs), self.joint_origins_many(qs))
        frame, flange = self._tcp_frame, self._flange
        return self.batch.frame_poses_and_origins(
            qs, frame.parentJoint, frame.placement, (flange.parentJoint, flange.placement)
        )

    def pinocchio_tool_poses(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`tool_poses` by one Pinocchio call per configuration (what verifies the IK)."""
        import pinocchio as pin

        poses = np.empty((len(qs), 4, 4))
        model, data, frame = self.model, self.data, self.tcp_frame
        forward, place = pin.forwardKinematics, pin.updateFramePlacement
        for i, q in enumerate(np.asarray(qs, dtype=float)):
            forward(model, data, q)
            poses[i] = place(model, data, frame).homogeneous  # one conversion, not two
        return poses[:, :3, 3].copy(), poses[:, :3, :3].copy()

    def joint_origins(self, q: np.ndarray) -> np.ndarray:
        """(7, 3): the origins of the six joints and of the flange, board frame."""
        import pinocchio as pin

        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        points = [np.array(self.data.oMi[j].translation) for j in range(1, 7)]
        points.append(np.array(self.data.oMf[self.flange_frame].translation))
        return np.array(points)

    def joint_origins_many(self, qs: np.ndarray) -> np.ndarray:
        """(n, 7, 3): `joint_origins` of each of (n, 6) joint vectors."""
        if self.batch is None:
            return np.array([self.joint_origins(q) for q in qs]).reshape(-1, 7, 3)
        return self.batch.origins(qs, (self._flange.parentJoint, self._flange.placement))

    # -- inverse kinematics --------------------------------------------------------------------

    def ik(
        self,
        position: np.ndarray,
        yaw: float,
        seed: np.ndarray,
        *,
        max_iterations: int = 100,
        damping: float = 1e-3,
    ) -> IkResult:
        """Damped least squares on the SE(3) error from `seed`; converges far below 0.1 mm."""
        import pinocchio as pin

        model, data, frame = self.model, self.data, self.tcp_frame
        target_p = np.asarray(position, dtype=float)
        target_r = tool_rotation(yaw)
        q = np.array(seed, dtype=float)
        damping2 = damping * damping
        error = np.zeros(6)
        pos_err = rot_err = math.inf
        for iteration in range(max_iterations + 1):
            pin.forwardKinematics(model, data, q)
            pose = pin.updateFramePlacement(model, data, frame)
            error[:3] = target_p - pose.translation
            rot_local = pin.log3(pose.rotation.T @ target_r)
            error[3:] = pose.rotation @ rot_local
            pos_err = float(np.linalg.norm(error[:3]))
            rot_err = float(np.linalg.norm(rot_local))
            # Converge far below the 0.1 mm / 0.1 degree contract: the joint path is later
            # differentiated twice, and solver noise would show up as acceleration.
            if pos_err < 1e-9 and rot_err < 1e-8:
                break
            if iteration == max_iterations:
                break
            jacobian = pin.computeFrameJacobian(
                model, data, q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
            )
            step = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + damping2 * np.eye(6), error)
            largest = float(np.abs(step).max())
            if largest > 0.3:  # big steps can jump to another arm configuration
                step *= 0.3 / largest
            q = q + step
        return IkResult(q, pos_err, rot_err, iteration)

    def tool_down_seed(self, position: np.ndarray, yaw: float) -> np.ndarray:
        """Closed-form elbow-up, wrist-outward joints for a tool pointing down (the IK seed)."""
        arm = self.arm
        flange = np.asarray(position, dtype=float) + np.array([0.0, 0.0, self.tool.tcp[2]])
        local = self._in_base_link(flange)
        radius = math.hypot(local[0], local[1])
        outward = math.sqrt(max(radius**2 - arm.d4**2, 1e-12))
        q1 = _wrap(math.atan2(local[1], local[0]) - math.atan2(arm.d4, outward))
        reach_r = outward - arm.d5
        reach_z = local[2] + arm.d6 - arm.d1
        dist2 = reach_r**2 + reach_z**2
        cos_elbow = (dist2 - arm.upper_arm**2 - arm.forearm**2) / (2 * arm.upper_arm * arm.forearm)
        q3 = math.acos(min(1.0, max(-1.0, cos_elbow)))
        alpha1 = math.atan2(reach_r, reach_z) - math.atan2(
            arm.forearm * math.sin(q3), arm.upper_arm + arm.forearm * math.cos(q3)
        )
        q2 = alpha1 - math.pi / 2
        q4 = -(alpha1 + q3)
        q = np.array([q1, q2, q3, q4, -math.pi / 2, 0.0])
        _, rotation = self.fk(q)
        yaw_at_zero = math.atan2(rotation[1, 0], rotation[0, 0])
        q[5] = _wrap(yaw_at_zero - yaw)
        if abs(_wrap(self._yaw_of(q) - yaw)) > 1e-6:
            q[5] = _wrap(yaw - yaw_at_zero)
        return q

    def _yaw_of(self, q: np.ndarray) -> float:
        _, rotation = self.fk(q)
        return math.atan2(rotation[1, 0], rotation[0, 0])

    def _in_base_link(self, point: np.ndarray) -> np.ndarray:
        """A board point in the URDF root frame (base_link, z up through joint 1)."""
        return np.array(self.base_in_board.actInv(np.asarray(point, dtype=float)))

    def reach_shortfall(self, points: np.ndarray) -> np.ndarray:
        """(n,) metres by which each tool-down tip position is out of reach (<= 0: reachable)."""
        arm = self.arm
        flange = np.asarray(points, dtype=float) + np.array([0.0, 0.0, self.tool.tcp[2]])
        base = self.base_in_board
        local = (flange - base.translation) @ base.rotation
        radius = np.hypot(local[:, 0], local[:, 1])
        # Too close to the base axis: the arm cannot fold around its own shoulder offset.
        too_close = (arm.d4 + REACH_MARGIN_M) - radius
        outward = np.sqrt(np.maximum(radius**2 - arm.d4**2, 0.0))
        wrist = np.hypot(outward - arm.d5, local[:, 2] + arm.d6 - arm.d1)
        too_far = wrist - (arm.upper_arm + arm.forearm - REACH_MARGIN_M)
        folded = (abs(arm.upper_arm - arm.forearm) + REACH_MARGIN_M) - wrist
        return np.maximum.reduce([too_close, too_far, folded])

    def home_tool_position(self) -> np.ndarray:
        """Above the middle of the board, clear of the object (or as high as reachable)."""
        width, height = self.board_size
        z = self.object_height + self.clearance + 0.05
        point = np.array([width / 2, height / 2, z])
        while z > self.object_height + self.clearance and self.reach_shortfall(point[None])[0] > 0:
            z -= 0.005
            point[2] = z
        return point

    def configuration_problem(self, q: np.ndarray) -> str | None:
        """Why `q` is not the elbow-up, wrist-outward configuration (None when it is)."""
        if q[2] <= 0.05:
            return "elbow down or stretched"
        if math.sin(q[4]) > -0.2:
            return "wrist flipped or singular"
        if np.any(q < self.lower) or np.any(q > self.upper):
            return "outside the joint limits"
        return None

    def check_reachable(self, tool_path: ToolPath) -> None:
        """Raise a KeympsError naming the piece furthest out of reach, and by how much."""
        shortfalls = [self.reach_shortfall(piece.points) for piece in tool_path.pieces]
        out = [i for i, s in enumerate(shortfalls) if s.max() > 0]
        if not out:
            return
        index = max(out, key=lambda i: float(shortfalls[i].max()))
        piece = tool_path.pieces[index]
        point = piece.points[int(np.argmax(shortfalls[index]))]
        amount = float(shortfalls[index].max())
        role = "work on pair" if piece.kind == "work" else "travel to pair"
        x, y, z, yaw = self.base
        distance = math.hypot(point[0] - x, point[1] - y)
        direction = "closer to" if distance > 0.25 else "further from"
        raise KeympsError(
            f"robot: {len(out)} of {len(shortfalls)} path pieces are out of the "
            f"{self.kind.upper()}'s reach; piece {index} ({role} {piece.pair_index}) by "
            f"{amount * 100:.1f} cm at board point ({point[0]:.3f}, {point[1]:.3f}, "
            f"{point[2]:.3f}) m, {distance * 100:.0f} cm from the base; move the base {direction} "
            f"the work (task robot.base, now [{x:g}, {y:g}, {z:g}, {yaw:g}])"
        )

    def solve_points(
        self,
        points: np.ndarray,
        yaws: np.ndarray,
        seed: np.ndarray,
        *,
        where: str = "path",
        method: str = "auto",
    ) -> tuple[np.ndarray, float, float]:
        """IK along consecutive points, continuous from `seed`: (n, 6) joints, max position
        and rotation error. `method` 'auto' takes the closed form when it exists and every
        solution checks out, else the iterative solver; 'iterative' forces the latter."""
        if method not in ("auto", "iterative"):
            raise ValueError(f"solve_points: unknown method {method!r}")
        if method == "auto" and self.closed_form is not None and len(points):
            solved = self._solve_closed_form(points, yaws, seed)
            if solved is not None:
                return solved
        return self._solve_iterative(points, yaws, seed, where)

    def _solve_closed_form(
        self, points: np.ndarray, yaws: np.ndarray, seed: np.ndarray
    ) -> tuple[np.ndarray, float, float] | None:
        """All analytic branches at once, the one continuous with `seed` kept and each point
        verified by Pinocchio's forward kinematics; None if any point is doubtful."""
        assert self.closed_form is not None
        points = np.asarray(points, dtype=float)
        yaws = np.asarray(yaws, dtype=float)
        targets = tool_poses_down(points, yaws)
        branches = self.closed_form.solve(targets)
        chosen = choose_continuous_branch(branches, np.asarray(seed, dtype=float))
        if chosen is None:
            return None
        if np.any(chosen[:, 2] <= 0.05) or np.any(np.sin(chosen[:, 4]) > -0.2):
            return None  # the iterative path words the configuration error
        if np.any(chosen < self.lower) or np.any(chosen > self.upper):
            return None
        positions, rotations = self.pinocchio_tool_poses(chosen)
        position_error = np.linalg.norm(positions - points, axis=1)
        rotation_error = rotation_angles(rotations, targets[:, :3, :3])
        worst_p, worst_r = float(position_error.max()), float(rotation_error.max())
        if worst_p > CLOSED_FORM_TOLERANCE_M or worst_r > CLOSED_FORM_TOLERANCE_RAD:
            return None
        return chosen, worst_p, worst_r

    def _solve_iterative(
        self, points: np.ndarray, yaws: np.ndarray, seed: np.ndarray, where: str
    ) -> tuple[np.ndarray, float, float]:
        """Warm-started damped least squares, point after point."""
        qs = np.empty((len(points), 6))
        previous = np.array(seed, dtype=float)
        velocity = np.zeros(6)
        worst_p = worst_r = 0.0
        for i, (point, yaw) in enumerate(zip(points, yaws, strict=True)):
            result = self.ik(point, float(yaw), previous + velocity)
            if not result.converged:
                result = self.ik(point, float(yaw), previous, max_iterations=300)
            if not result.converged:
                raise KeympsError(
                    f"robot: inverse kinematics failed at {where} point {i} "
                    f"({point[0]:.3f}, {point[1]:.3f}, {point[2]:.3f}) m: "
                    f"{result.position_error_m * 1000:.2f} mm off; move the base (task robot.base)"
                )
            problem = self.configuration_problem(result.q)
            if problem is not None:
                raise KeympsError(
                    f"robot: at {where} point {i} ({point[0]:.3f}, {point[1]:.3f}, "
                    f"{point[2]:.3f}) m the arm would leave its configuration ({problem}); "
                    "move the base (task robot.base)"
                )
            velocity = result.q - previous if i else np.zeros(6)
            previous = result.q
            qs[i] = result.q
            worst_p = max(worst_p, result.position_error_m)
            worst_r = max(worst_r, result.rotation_error_rad)
        return qs, worst_p, worst_r


CLOSED_FORM_TOLERANCE_M = 1e-9
CLOSED_FORM_TOLERANCE_RAD = 1e-9
MAX_BRANCH_STEP_RAD = 1.0
"""A larger joint step between consecutive path points is not trusted to the closed form."""
BRANCH_MARGIN = 0.5
"""The kept branch must be at most this fraction of the next nearest one's distance from the
previous point: where two branches come close (a singularity), the iterative solver decides."""


def tool_poses_down(points: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """(n, 4, 4) tool poses pointing down at `points` with tool x at `yaws` (board frame)."""
    c, s = np.cos(yaws), np.sin(yaws)
    poses = np.zeros((len(points), 4, 4))
    poses[:, 0, 0], poses[:, 0, 1] = c, s
    poses[:, 1, 0], poses[:, 1, 1] = s, -c
    poses[:, 2, 2] = -1.0
    poses[:, :3, 3] = points
    poses[:, 3, 3] = 1.0
    return poses


def rotation_angles(rotations: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(n,) angles of rotations[i]^T targets[i] (accurate near zero)."""
    error = np.swapaxes(rotations, 1, 2) @ targets
    skew = np.stack(
        [
            error[:, 2, 1] - error[:, 1, 2],
            error[:, 0, 2] - error[:, 2, 0],
            error[:, 1, 0] - error[:, 0, 1],
        ],
        axis=1,
    )
    cosine = (np.trace(error, axis1=1, axis2=2) - 1.0) / 2.0
    return np.arctan2(np.linalg.norm(skew, axis=1) / 2.0, cosine)


def _nearest_turn(angles: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """`angles` shifted by whole turns to lie within pi of `reference` (broadcasting)."""
    return angles + 2 * np.pi * np.round((reference - angles) / (2 * np.pi))


def choose_continuous_branch(branches: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
    """(n, 6) joints from (n, 8, 6) analytic solutions: at the first point the branch nearest
    `seed`, then at every point the branch nearest the previous one (unwrapped: no jumps of a
    whole turn). None when that is not one branch kept throughout with small steps (a
    singularity, a missing solution, or a path stepping too far between points)."""
    first = _nearest_turn(branches[0], seed)
    distance = np.abs(first - seed).max(axis=1)
    if np.isnan(distance).all():
        return None
    branch = int(np.nanargmin(distance))
    path = branches[:, branch].copy()
    if np.isnan(path).any():
        return None
    path[0] = first[branch]
    path = np.unwrap(path, axis=0)
    if len(path) > 1:
        steps = np.abs(np.diff(path, axis=0)).max(axis=1)
        if steps.max() > MAX_BRANCH_STEP_RAD:
            return None
        # Every point's nearest branch to the previous point must be the branch kept.
        others = _nearest_turn(branches[1:], path[:-1, None, :])
        gaps = np.abs(others - path[:-1, None, :]).max(axis=2)
        gaps = np.where(np.isnan(gaps), np.inf, gaps)
        if np.any(np.argmin(gaps, axis=1) != branch):
            return None
        others = np.delete(gaps, branch, axis=1).min(axis=1)
        if np.any(gaps[:, branch] > BRANCH_MARGIN * others):
            return None
    return path


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _check_piece(index: int, piece: Piece) -> None:
    points, yaw = np.asarray(piece.points), np.asarray(piece.yaw)
    problem = None
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        problem = f"points must be an (n, 3) array, got shape {points.shape}"
    elif yaw.shape != (len(points),):
        problem = f"yaw must have one value per point ({len(points)}), got shape {yaw.shape}"
    elif not (np.isfinite(points).all() and np.isfinite(yaw).all()):
        problem = "points or yaw contain NaN or infinity"
    elif not (math.isfinite(piece.speed) and piece.speed > 0):
        problem = f"speed must be positive, got {piece.speed}"
    if problem:
        raise KeympsError(f"robot: tool path piece {index} ({piece.kind}): {problem}")


def solve_path(model: RobotModel, tool_path: ToolPath) -> JointPath:
    """IK of every point of every piece, one arm configuration for the whole path."""
    if not tool_path.pieces:
        raise KeympsError("robot: the tool path has no pieces")
    for index, piece in enumerate(tool_path.pieces):
        _check_piece(index, piece)
    model.check_reachable(tool_path)
    first = tool_path.pieces[0]
    seed = model.tool_down_seed(first.points[0], float(first.yaw[0]))
    if model.closed_form is not None:
        # One analytic solve for the whole path: continuity runs across piece boundaries.
        points = np.concatenate([piece.points for piece in tool_path.pieces])
        yaws = np.concatenate([piece.yaw for piece in tool_path.pieces])
        solved = model._solve_closed_form(points, yaws, seed)
        if solved is not None:
            qs, worst_p, worst_r = solved
            ends = np.cumsum([len(piece.points) for piece in tool_path.pieces])[:-1]
            pieces = tuple(np.split(qs, ends))
            return JointPath(pieces, model.joint_names, worst_p, worst_r)
    solutions = []
    worst_p = worst_r = 0.0
    for index, piece in enumerate(tool_path.pieces):
        qs, err_p, err_r = model.solve_points(
            piece.points, piece.yaw, seed, where=f"piece {index} ({piece.kind})"
        )
        solutions.append(qs)
        seed = qs[-1]
        worst_p, worst_r = max(worst_p, err_p), max(worst_r, err_r)
    return JointPath(tuple(solutions), model.joint_names, worst_p, worst_r)
