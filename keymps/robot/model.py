"""An arm placed on the board with a tool: FK, IK and limits, for any arm a robot plugin
describes (keymps.plugin.ArmSpec).

Conventions:
- task.robot.base = (x, y, z, yaw_deg) is the pose of the arm's URDF root link (for a UR arm
  `base_link`: the ROS convention, z up through joint 1, x towards where the arm points at
  shoulder_pan = 0) in the board frame. A UR controller's own base frame (teach pendant, RTDE
  poses) is base_link turned by 180 degrees about z. Without it, the arm's default placement
  for the board (ArmSpec.base_for).
- The tool points straight down (tool z = -board z); its yaw is the angle of the tool x axis
  about board z. Rotation of the tool frame: Rz(yaw) @ diag(1, -1, -1). The tool's tcp is
  given in the arm's tool mount frame (ArmSpec.tip_link: a UR's flange tool0).
- Joint angles are the controller's (for a UR: the same zero and sign as the pendant).
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
from keymps.robot.collision import Clearances
from keymps.robot.description import (
    ARMS,
    BUILTIN_TOOLS,
    JOINT_NAMES,
    REACH_MARGIN_M,
    ArmGeometry,
    Tool,
    rz,
    se3,
    tool_from_task,
    tool_rotation,
    ur_geometry,
    ur_urdf_path,
)
from keymps.robot.iterative_ik import IkResult, IterativeIk
from keymps.robot.urdf_model import ArmModel, load_arm
from keymps.types import JointPath, Piece, ToolPath

__all__ = [
    "ARMS",
    "BUILTIN_TOOLS",
    "JOINT_NAMES",
    "ArmGeometry",
    "IkResult",
    "RobotModel",
    "Tool",
    "arm_by_name",
    "solve_path",
    "tool_from_task",
    "tool_rotation",
    "ur_urdf_path",
]

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.plugin.components import Arm


def arm_by_name(name: str, options: dict[str, Any] | None = None) -> Arm:
    """The arm a robot plugin registered as `name` (`robot.model`), built with `options`; a
    factory that fails is one line naming it."""
    from keymps.plugin.manager import create_robot

    try:
        return create_robot(name, options)
    except KeympsError:
        raise
    except Exception as error:  # a broken plugin: one line, never a traceback
        detail = " ".join(str(error).split()) or "no message"
        raise KeympsError(
            f"robot {name!r} failed to build: {type(error).__name__}: {detail}"
        ) from None


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
"""Per process, by (arm, base, tool): `keymps eval` builds the same robot for every run."""
KINEMATICS_KEPT = 16
FLANGE_FRAME, TCP_FRAME = "keymps_tool_mount", "keymps_tcp"
"""The frames keymps adds to an arm's model: its tool mount (ArmSpec.tip_link) and the tool's
tip (names no URDF of an arm uses: "flange" and "tcp" are common link names)."""
_CLEARANCES: dict[tuple[Any, ...], Clearances] = {}


class RobotModel:
    """An arm placed on the board with a tool: FK, IK and limits (`run.robot`)."""

    def __init__(
        self,
        kind: str | Arm = "ur3",
        base: tuple[float, float, float, float] | None = None,
        tool: Tool = BUILTIN_TOOLS["knife"],
        *,
        max_joint_acceleration: float | None = None,
        max_joint_jerk: float | None = None,
        board_size: tuple[float, float] = (0.30, 0.18),
        object_height: float = 0.05,
        clearance: float = 0.03,
    ):
        spec = arm_by_name(kind) if isinstance(kind, str) else kind
        self.arm_model: ArmModel = load_arm(spec)
        self.spec = spec
        self.kind = spec.name
        self.base = tuple(float(v) for v in (base or spec.base_for(board_size)))
        self.tool = tool
        self.board_size = board_size
        self.object_height = float(object_height)
        self.clearance = float(clearance)
        x, y, z, yaw_deg = self.base
        self.base_in_board = se3(rz(math.radians(yaw_deg)), np.array([x, y, z]))
        key = (spec, self.base, tool)
        known = _KINEMATICS.get(key)
        if known is None:
            self.model, self.tcp_frame = place_arm(self.arm_model, self.base_in_board, tool)
        else:
            self.model, self.tcp_frame = known.model, known.tcp_frame
        self.flange_frame = self.model.getFrameId(FLANGE_FRAME)
        self.data = self.model.createData()
        arm = self.arm_model
        self.joint_names = arm.joint_names
        self.lower, self.upper = arm.lower.copy(), arm.upper.copy()
        self.velocity_limits = arm.velocity.copy()
        self.acceleration_limits = _capped(arm.acceleration, max_joint_acceleration)
        self.jerk_limits = _capped(arm.jerk, max_joint_jerk)
        self.effort_limits = arm.effort.copy()
        self.urdf_path = spec.urdf
        self.arm: ArmGeometry | None = (
            None if spec.dh is None else ur_geometry(spec.dh, tuple(arm.velocity), spec.rate_hz)
        )
        """The DH lengths of a UR-type arm (the closed-form IK), None for any other arm."""
        self._tcp_frame = self.model.frames[self.tcp_frame]
        self._flange = self.model.frames[self.flange_frame]
        self.solver = IterativeIk(self.model, self.tcp_frame, self.lower, self.upper)
        if known is None:
            known = self._check_kinematics(key)
        self.batch = known.batch
        """Forward kinematics of many configurations at once (None: one Pinocchio call each)."""
        self.closed_form = known.closed_form
        """The analytic IK, None for an arm without one or when the DH chain does not
        reproduce this model (then every point is solved iteratively)."""

    def _check_kinematics(self, key: tuple[Any, ...]) -> _Kinematics:
        batch = BatchKinematics.for_model(self.model)
        closed_form = None
        if self.arm is not None and self.dof == 6:
            closed_form = ClosedFormIk.for_model(self.arm, self.base_in_board.homogeneous, self.fk)
        if len(_KINEMATICS) >= KINEMATICS_KEPT:
            _KINEMATICS.pop(next(iter(_KINEMATICS)), None)  # the oldest
        return _KINEMATICS.setdefault(
            key, _Kinematics(self.model, self.tcp_frame, batch, closed_form)
        )

    @classmethod
    def from_task(cls, task: Task, arm: Arm | None = None) -> RobotModel:
        """The task's arm (`arm`, or the one its robot section names), placed and tooled."""
        robot = task.robot
        if arm is None:
            arm = arm_by_name(*robot.arm_component(task.folder))
        return cls(
            arm,
            robot.base,
            tool_from_task(task),
            max_joint_acceleration=robot.max_joint_acceleration,
            max_joint_jerk=robot.max_joint_jerk,
            board_size=task.scene.workspace.size,
            object_height=task.scene.tallest_object_height,
            clearance=task.motion.clearance,
        )

    def clearances(self) -> Clearances:
        """The arm's collision model on the board (built on first use, kept per arm and base)."""
        key = (self.spec, self.base)
        found = _CLEARANCES.get(key)
        if found is None:
            found = Clearances(
                self.model, self.arm_model.collision, self.arm_model.home, self.base_in_board
            )
            if len(_CLEARANCES) >= KINEMATICS_KEPT:
                _CLEARANCES.pop(next(iter(_CLEARANCES)), None)
            _CLEARANCES[key] = found
        return found

    @property
    def model_name(self) -> str:
        """The arm's model name (`robot.model`: "ur5e", "panda"; a URDF's file stem)."""
        return self.spec.name

    @property
    def label(self) -> str:
        """The arm as error messages name it ("the UR5E", "the panda")."""
        return f"the {self.kind.upper()}" if self.arm is not None else f"the {self.kind}"

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    @property
    def rate_hz(self) -> float:
        """The controller's default rate (UR: 125 Hz CB3, 500 Hz e-Series)."""
        return float(self.spec.rate_hz)

    # -- forward kinematics --------------------------------------------------------------------

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool tip position (3,) and rotation (3, 3) in the board frame."""
        import pinocchio as pin

        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        pose = self.data.oMf[self.tcp_frame]
        return np.array(pose.translation), np.array(pose.rotation)

    def tool_positions(self, qs: np.ndarray) -> np.ndarray:
        """(n, 3) tool tip positions for (n, dof) joint vectors."""
        return self.tool_poses(qs)[0]

    def tool_poses(
        self, qs: np.ndarray, cos_sin: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) tool tip positions and (n, 3, 3) rotations for (n, dof) joint vectors
        (`cos_sin`: their cosines and sines, (dof, n) each, when the caller has them)."""
        if self.batch is None or len(qs) == 0:
            return self.pinocchio_tool_poses(qs)
        frame = self._tcp_frame
        return self.batch.frame_poses(qs, frame.parentJoint, frame.placement, cos_sin)

    def tool_positions_and_x_axes(
        self, qs: np.ndarray, cos_sin: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) tool tip positions and tool x axes (the rotations' first columns) for (n, dof)
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
        """`tool_poses` and `joint_origins_many` of (n, dof) joint vectors, in one pass when
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
        """(dof + 1, 3): the origins of the joints and of the tool mount, board frame."""
        import pinocchio as pin

        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        points = [np.array(self.data.oMi[j].translation) for j in range(1, self.model.njoints)]
        points.append(np.array(self.data.oMf[self.flange_frame].translation))
        return np.array(points)

    def joint_origins_many(self, qs: np.ndarray) -> np.ndarray:
        """(n, dof + 1, 3): `joint_origins` of each of (n, dof) joint vectors."""
        if self.batch is None:
            return np.array([self.joint_origins(q) for q in qs]).reshape(-1, self.dof + 1, 3)
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
        """Damped least squares on the SE(3) error from `seed` (keymps.robot.iterative_ik)."""
        return self.solver.solve(
            position, tool_rotation(yaw), seed, max_iterations=max_iterations, damping=damping
        )

    def tool_down_seed(self, position: np.ndarray, yaw: float) -> np.ndarray:
        """Joints for the tool pointing down at `position` with `yaw`, to start a path from: a UR
        arm's closed-form elbow-up, wrist-outward solution; any other arm's IK solution from its
        home configuration (turned towards the point), else from spread-out configurations.
        Raises a KeympsError naming the point and the arm when there is none."""
        if self.arm is not None:
            return self._ur_seed(position, yaw)
        seeds = self._seeds_towards(position)
        result = self.solver.solve_from_anywhere(position, tool_rotation(yaw), seeds)
        if not result.converged:
            raise KeympsError(self._unreachable(position, yaw, result, "the path's first point"))
        return result.q

    def _seeds_towards(self, position: np.ndarray) -> list[np.ndarray]:
        """The home configuration turned to face `position` (its first joint), with its last
        joint (the tool's roll on a table arm) at seven places across its range: a roll limit
        the solver would run into is then approached from the other side."""
        home = self.arm_model.home
        turned = home.copy()
        turned[0] = np.clip(
            home[0] + self._azimuth_change(position, home), self.lower[0], self.upper[0]
        )
        seeds = [turned]
        for roll in np.linspace(self.lower[-1], self.upper[-1], 9)[1:-1]:
            seeds.append(turned.copy())
            seeds[-1][-1] = roll
        return [*seeds, home]

    def _azimuth_change(self, position: np.ndarray, q: np.ndarray) -> float:
        """How far the first joint (a vertical axis on a table arm) turns the tool from its
        place at `q` to face `position`, both seen from the base."""
        here, _ = self.fk(q)
        local = [self._in_base_link(p) for p in (here, np.asarray(position, float))]
        return float(
            _wrap(math.atan2(local[1][1], local[1][0]) - math.atan2(local[0][1], local[0][0]))
        )

    def _unreachable(self, position: np.ndarray, yaw: float, result: IkResult, where: str) -> str:
        """Why a point cannot be solved, naming the arm and the point: out of reach, or (an arm
        of fewer than six joints) reachable with the tool down but not at this yaw."""
        x, y, z = (float(v) for v in position)
        point = f"board point ({x:.3f}, {y:.3f}, {z:.3f}) m"
        shortfall = self._shortfall(yaw, result)
        held = [
            other
            for other in np.linspace(-math.pi, math.pi, 12, endpoint=False)
            if self.dof < 6 and self.reachable(position, float(other))
        ]
        if held:
            what = (
                f"cannot hold the tool pointing down at yaw {math.degrees(yaw):.0f} degrees at "
                f"{point} ({where}; with {self.dof} joints its yaw there is limited, e.g. "
                f"{math.degrees(held[0]):.0f} degrees works)"
            )
        else:
            what = f"cannot reach {point} with the tool pointing down ({where}; {shortfall})"
        bx, by, bz, byaw = self.base
        return (
            f"robot: {self.spec.description or self.kind} {what}; move the base (task "
            f"robot.base, now [{bx:g}, {by:g}, {bz:g}, {byaw:g}]) or the work"
        )

    def _shortfall(self, yaw: float, result: IkResult) -> str:
        """What stopped the solver: the joints it left at a limit, else the distance short."""
        at = np.flatnonzero((result.q <= self.lower + 1e-9) | (result.q >= self.upper - 1e-9))
        short = (
            f"{result.position_error_m * 1000:.1f} mm and "
            f"{math.degrees(result.rotation_error_rad):.1f} degrees short"
        )
        if not len(at):
            return short
        limits = ", ".join(
            f"{self.joint_names[j]} at its limit ({math.degrees(result.q[j]):.0f} degrees)"
            for j in at
        )
        return f"{limits}, {short} at yaw {math.degrees(yaw):.0f} degrees"

    def _ur_seed(self, position: np.ndarray, yaw: float) -> np.ndarray:
        """Closed-form elbow-up, wrist-outward joints of a UR arm, tool pointing down."""
        arm = self.arm
        assert arm is not None
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
        """A board point in the arm's root frame (a UR's base_link, z up through joint 1)."""
        return np.array(self.base_in_board.actInv(np.asarray(point, dtype=float)))

    def reach_shortfall(self, points: np.ndarray) -> np.ndarray:
        """(n,) metres by which each tool-down tip position is out of a UR arm's reach (<= 0:
        reachable), in closed form; for any other arm zeros (its IK decides)."""
        arm = self.arm
        if arm is None:
            return np.zeros(len(points))
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

    def reachable(self, point: np.ndarray, yaw: float = 0.0) -> bool:
        """Whether the tool can point down at `point` (closed form for a UR arm, else IK)."""
        if self.arm is not None:
            return bool(self.reach_shortfall(np.asarray(point, float)[None])[0] <= 0)
        seeds = self._seeds_towards(point)
        return self.solver.solve_from_anywhere(point, tool_rotation(yaw), seeds, tries=0).converged

    def height_problem(self) -> str | None:
        """Why the object's top is beyond the arm (None when the arm can work there): the tool,
        pointing down, must reach the top plus the travel clearance somewhere over the board.
        Tried at the board's middle first (one IK for most tasks), then at eight more points.
        An arm that cannot work over the board even at a flat object's height is no height
        problem: the solve stage names the board point it cannot reach."""
        z = self.object_height + self.clearance
        if self._reaches_over_board(z) or not self._reaches_over_board(self.clearance):
            return None
        bx, by, bz, byaw = self.base
        return (
            f"{self.object_height:g} m: {self.label} cannot reach {z:.3f} m above the board (the "
            f"object's top plus motion.clearance) anywhere over it with its base at [{bx:g}, "
            f"{by:g}, {bz:g}, {byaw:g}]: the unit is metres, or move robot.base"
        )

    def _reaches_over_board(self, z: float) -> bool:
        """Whether the tool, pointing down, reaches height `z` (m) anywhere over the board."""
        width, height = self.board_size
        points = [(0.5, 0.5), *[(a, b) for a in (0.2, 0.5, 0.8) for b in (0.2, 0.5, 0.8)]]
        return any(self.reachable(np.array([fx * width, fy * height, z])) for fx, fy in points)

    def home_tool_position(self) -> np.ndarray:
        """Above the middle of the board, clear of the object (or as high as reachable)."""
        width, height = self.board_size
        z = self.object_height + self.clearance + 0.05
        point = np.array([width / 2, height / 2, z])
        while z > self.object_height + self.clearance and not self.reachable(point):
            z -= 0.005
            point[2] = z
        return point

    def home_yaw(self) -> float:
        """The tool yaw (radians about board z) that puts the last joint, the tool's roll on a
        table arm, in the middle of its range over the board's middle: where a knife's cuts turn
        from, so that the roll has room both ways (the Panda's seventh joint lacks 28 degrees of
        a whole turn). 0 for an arm whose roll turns a whole turn either way (a UR) or that
        cannot point the tool down there."""
        low, high = float(self.lower[-1]), float(self.upper[-1])
        if high - low >= 2 * math.tau:
            return 0.0
        try:
            q = self.tool_down_seed(self.home_tool_position(), 0.0)
        except KeympsError:
            return 0.0
        turned = q.copy()
        turned[-1] += 0.1 if turned[-1] + 0.1 <= high else -0.1
        gain = _wrap(self._yaw_of(turned) - self._yaw_of(q)) / (turned[-1] - q[-1])
        if abs(gain) < 0.5:  # the last joint is no roll about the tool's axis
            return 0.0
        return _wrap(((low + high) / 2 - q[-1]) * math.copysign(1.0, gain))

    def configuration_problem(self, q: np.ndarray) -> str | None:
        """Why `q` is not a configuration paths may use (None when it is): inside the joint
        limits, and for a UR arm elbow up with the wrist outward."""
        if self.arm is not None:
            if q[2] <= 0.05:
                return "elbow down or stretched"
            if math.sin(q[4]) > -0.2:
                return "wrist flipped or singular"
        if np.any(q < self.lower) or np.any(q > self.upper):
            return "outside the joint limits"
        return None

    def check_reachable(self, tool_path: ToolPath) -> None:
        """Raise a KeympsError naming the piece furthest out of a UR arm's reach, and by how
        much (any other arm: its IK names the first point it cannot reach)."""
        if self.arm is None:
            return
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
        """IK along consecutive points, continuous from `seed`: (n, dof) joints, max position
        and rotation error. `method` 'auto' takes the closed form when it exists and every
        solution checks out, else the iterative solver; 'iterative' forces the latter."""
        if method not in ("auto", "iterative"):
            raise ValueError(f"solve_points: unknown method {method!r}")
        if method == "auto" and self.closed_form is not None and len(points):
            solved = self.solve_closed_form(points, yaws, seed)
            if solved is not None:
                return solved
        return self._solve_iterative(points, yaws, seed, where)

    def solve_closed_form(
        self, points: np.ndarray, yaws: np.ndarray, seed: np.ndarray
    ) -> tuple[np.ndarray, float, float] | None:
        """IK of consecutive points by the closed form: every analytic branch at once, the one
        continuous with `seed` kept, each point verified by Pinocchio's forward kinematics.

        Args:
            points: (n, 3) tool points in the base frame, metres.
            yaws: (n,) tool yaw about the vertical, radians.
            seed: (dof,) joints the path starts near, radians.

        Returns:
            (n, dof) joints, the worst position error (m) and rotation error (rad); None when
            any point is doubtful (no continuous branch, a joint limit, a configuration the
            iterative solver words better), so the caller falls back to `solve_points`.
        """
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
        qs = np.empty((len(points), self.dof))
        previous = np.array(seed, dtype=float)
        velocity = np.zeros(self.dof)
        worst_p = worst_r = 0.0
        for i, (point, yaw) in enumerate(zip(points, yaws, strict=True)):
            result = self.ik(point, float(yaw), previous + velocity)
            if not result.converged:
                result = self.ik(point, float(yaw), previous, max_iterations=300)
            if not result.converged:
                raise KeympsError(
                    self._unreachable(point, float(yaw), result, f"{where} point {i}")
                )
            problem = self.configuration_problem(result.q)
            if problem is None and i and np.abs(result.q - previous).max() > MAX_BRANCH_STEP_RAD:
                problem = "a jump to another configuration"
            if problem is not None:
                raise KeympsError(
                    f"robot: at {where} point {i} ({point[0]:.3f}, {point[1]:.3f}, "
                    f"{point[2]:.3f}) m {self.label} would leave its configuration ({problem}); "
                    "move the base (task robot.base)"
                )
            velocity = result.q - previous if i else np.zeros(self.dof)
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


def _capped(limits: np.ndarray, cap: float | None) -> np.ndarray:
    """The arm's per-joint limits, none above the task's `cap` (None: no cap)."""
    return np.array(limits if cap is None else np.minimum(limits, float(cap)), dtype=float)


def place_arm(arm: ArmModel, base_in_board: Any, tool: Tool) -> tuple[Any, int]:
    """A copy of the arm's Pinocchio model with its root at `base_in_board` (pinocchio.SE3) and
    two frames on the tool mount: FLANGE_FRAME (ArmSpec.tip_link) and TCP_FRAME (the tool's
    tip)."""
    import pinocchio as pin

    model = arm.model.copy()
    for joint in range(1, model.njoints):
        if model.parents[joint] == 0:
            model.jointPlacements[joint] = base_in_board * model.jointPlacements[joint]
    for frame in model.frames:
        if frame.parentJoint == 0 and frame.name != "universe":
            frame.placement = base_in_board * frame.placement
    mount = arm.flange_placement
    parent = model.frames[model.getFrameId(arm.spec.tip_link)].parentFrame
    tcp = mount * se3(np.eye(3), np.array(tool.tcp))
    frame_id = model.addFrame(
        pin.Frame(TCP_FRAME, arm.flange_joint, parent, tcp, pin.FrameType.OP_FRAME)
    )
    model.addFrame(pin.Frame(FLANGE_FRAME, arm.flange_joint, parent, mount, pin.FrameType.OP_FRAME))
    return model, frame_id


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
        solved = model.solve_closed_form(points, yaws, seed)
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
