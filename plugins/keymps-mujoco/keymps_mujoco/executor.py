"""The `mujoco` executor: the UR3 follows the validated trajectory in MuJoCo, with contact.

It builds the task's scene (keymps_mujoco.model), steps it along the trajectory
(keymps_mujoco.simulate), paints what the tool did on the food (keymps_mujoco.marks), renders
the video from the top-down and perspective cameras, and writes outcome.png from the top-down
camera with the arm hidden. It fails (ok: false) when the simulation diverges, a joint needs
more torque than the UR3 has, an arm link touches the board, or the tip strays more than
`max_tracking_error_mm` from the plan.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from keymps.plugin import parse_options, require_validated
from keymps.types import (
    CutEffect,
    Effect,
    ExecutionReport,
    ToolPath,
    Trajectory,
    ValidatedTrajectory,
)
from keymps_mujoco import NAME
from keymps_mujoco.model import PERSPECTIVE_CAMERA, TOP_CAMERA, Settings
from keymps_mujoco.scene_inputs import SceneInputs, scene_from_run

if TYPE_CHECKING:
    from keymps.run import Run

VIDEO_FILE = "execution.mp4"
REACHED_BOARD_M = 0.001
"""A cut reached the board when the blade's edge came within this of the board surface."""
BELOW_TOP_M = 0.0001
DEPOSIT_GAP_M = 0.012
"""The nozzle deposits icing when it moves at most this far above the surface under it."""


class MujocoOptions(BaseModel):
    """The executor section of a task file for `mujoco` (every key but `name`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    timestep_s: float = Field(0.002, ge=0.0001, le=0.008)
    """Physics step (rounded down to a whole number of steps per controller period)."""
    bandwidth_hz: float = Field(12.0, ge=1, le=60)
    """Natural frequency of the joint position servos."""
    damping_ratio: float = Field(1.0, gt=0, le=4)
    video: bool = True
    """Write execution.mp4."""
    video_fps: float = Field(10.0, ge=1, le=60)
    """Frames per second of simulated time (the video plays in real time)."""
    video_cameras: tuple[Literal["top", "perspective"], ...] = Field(
        ("top", "perspective"), min_length=1
    )
    """Side by side, left to right."""
    video_height_px: int = Field(300, ge=64, le=1080)
    shadows: bool = False
    """Shadows in the perspective view: nicer, but they triple its render time with Mesa's
    software renderer (the top-down camera, like the task's, never has them)."""
    perspective_aspect: float = Field(4 / 3, ge=0.5, le=3)
    outcome: bool = True
    """Write outcome.png from the top-down camera (arm hidden)."""
    top_px_per_m: float = Field(2000.0, ge=100, le=10_000)
    """Top-down camera resolution when the run has no scene image (else the image's size)."""
    max_tracking_error_mm: float = Field(5.0, gt=0, le=100)
    """Fail when the simulated tool tip strays further than this from the planned one."""
    divergence_mm: float = Field(50.0, gt=0, le=1000)
    """Stop at once (diverged) beyond this."""
    torque_limit_fraction: float = Field(1.0, gt=0, le=2)
    """Fail above this fraction of the UR3's peak joint torques."""
    icing_radius_m: float = Field(0.003, gt=0, le=0.02)
    cut_width_m: float = Field(0.0015, gt=0, le=0.02)


class MujocoExecutor:
    """Physics simulation of a validated trajectory in MuJoCo."""

    name = NAME

    def __init__(self, options: MujocoOptions):
        self.options = options

    def execute(self, validated: ValidatedTrajectory, run: Run) -> ExecutionReport:
        trajectory = require_validated(validated, self.name)
        inputs = scene_from_run(run, self.options.top_px_per_m)
        return Execution(self.options, inputs, trajectory, run).simulate()


class Execution:
    """One simulated execution: the scene, the painter, the video, the figures."""

    def __init__(
        self, options: MujocoOptions, inputs: SceneInputs, trajectory: Trajectory, run: Run
    ):
        self.options = options
        self.inputs = inputs
        self.trajectory = trajectory
        self.context = run
        self.folder = Path(run.folder)
        self.food_top = max((prop.height for prop in inputs.props), default=0.0)
        pieces = np.asarray(trajectory.piece_index)
        self.piece_start = {
            int(p): np.asarray(trajectory.tool_xyz)[int(np.argmax(pieces == p)), :2]
            for p in np.unique(pieces)
        }
        self.cut_lines = _cut_lines(run.stages.compose)

    def simulate(self) -> ExecutionReport:
        """Follow the trajectory in the scene; the paint, video and outcome image, judged."""
        from keymps_mujoco.model import build_scene
        from keymps_mujoco.render import Renderer

        inputs, trajectory = self.inputs, self.trajectory
        settings = self._settings()
        scene = build_scene(
            inputs.robot,
            inputs.board_size,
            inputs.board_shift,
            inputs.props,
            inputs.texture_rgb,
            settings,
        )
        painter = self._painter()
        blade = float(inputs.robot.tool.blade_length)
        kind = np.asarray(trajectory.kind)
        pieces = np.asarray(trajectory.piece_index)
        renderer = Renderer(scene)
        video = self._video(renderer, settings, painter)
        lowest = np.full(len(kind), np.inf)  # the tip's height at each working sample

        def on_step(step: Any) -> None:
            if kind[step.index] == "work":
                self._mark(step, painter, blade, lowest)
            if video is not None and video.due(step.t):
                if painter.changed and scene.texture_id >= 0:
                    renderer.upload_texture(painter.texture())
                video.frame(step.t)

        try:
            if video is not None:
                scene.set_joints(trajectory.q[0])  # the first frame shows the start
                video.frame(0.0)
            result = self._follow(scene, on_step)
            files = [str(video.close())] if video is not None else []
            if self.options.outcome:
                files.append(self._outcome_image(scene, renderer, painter))
        finally:
            if video is not None:
                video.close()
            renderer.close()
        figures = self._figures(result, lowest, kind, pieces, painter, video)
        measured = self._measured(lowest, kind, pieces, painter)
        problems = self._problems(result, figures)
        message = "; ".join(problems) if problems else self._summary(figures)
        return ExecutionReport(
            NAME, not problems, message, tuple(files), figures, measured=measured
        )

    def _settings(self) -> Settings:
        """The physics and camera settings from the options and the scene."""
        options = self.options
        return Settings(
            timestep_s=options.timestep_s,
            bandwidth_hz=options.bandwidth_hz,
            damping_ratio=options.damping_ratio,
            top_size_px=self.inputs.top_size_px,
            perspective_size_px=(
                round(options.video_height_px * options.perspective_aspect),
                options.video_height_px,
            ),
        )

    def _painter(self) -> Any:
        """A painter over the scene's texture (plain grey without one)."""
        from keymps_mujoco.marks import Painter

        inputs = self.inputs
        return Painter(
            inputs.texture_rgb
            if inputs.texture_rgb is not None
            else np.full((inputs.top_size_px[1], inputs.top_size_px[0], 3), 200, np.uint8),
            inputs.board_size,
            inputs.board_shift,
            inputs.footprint_masks,
            self.options.cut_width_m,
            self.options.icing_radius_m,
        )

    def _video(self, renderer: Any, settings: Settings, painter: Any) -> Any:
        """The video recorder, or None when the options ask for no video."""
        from keymps_mujoco.video import VideoRecorder

        options = self.options
        if not options.video:
            return None
        return VideoRecorder(
            self.folder / VIDEO_FILE,
            renderer,
            options.video_fps,
            [self._camera_size(name, settings) for name in options.video_cameras],
            lambda mjv: self._decorate(mjv, painter),
            options.shadows,
        )

    def _follow(self, scene: Any, on_step: Any) -> Any:
        """Step the scene along the trajectory within the options' limits (a SimResult)."""
        from keymps_mujoco.simulate import simulate

        options, robot, trajectory = self.options, self.inputs.robot, self.trajectory
        return simulate(
            scene,
            trajectory.t,
            trajectory.q,
            trajectory.qd,
            trajectory.qdd,
            trajectory.tool_xyz,
            trajectory.rate_hz,
            divergence_m=options.divergence_mm / 1000,
            torque_limits=tuple(
                float(v) * options.torque_limit_fraction for v in robot.effort_limits
            ),
            joint_names=tuple(robot.joint_names),
            on_step=on_step,
        )

    def _outcome_image(self, scene: Any, renderer: Any, painter: Any) -> str:
        """outcome.png: the painted food from the top-down camera, the arm hidden; its path."""
        if scene.texture_id >= 0:
            renderer.upload_texture(painter.texture())
        image = renderer.render(
            TOP_CAMERA,
            self.inputs.top_size_px,
            show_arm=False,
            extra=lambda mjv: self._decorate(mjv, painter),
        )
        return str(self.context.write_image("outcome", image))

    def _summary(self, figures: dict[str, float]) -> str:
        """One line: what was simulated and how closely the arm followed."""
        summary = (
            f"simulated {self.trajectory.duration_s:.1f} s in MuJoCo: max tracking error "
            f"{figures['max_tracking_error_mm']:.2f} mm, max torque "
            f"{100 * figures['max_torque_ratio']:.0f}% of the UR3's, max tool-board force "
            f"{figures['max_contact_force_n']:.1f} N"
        )
        if "cuts" in figures:
            summary += f", {figures['cuts_reached_board']:.0f}/{figures['cuts']:.0f} cuts reached the board"
        return summary

    def _camera_size(self, camera: str, settings: Settings) -> tuple[str, tuple[int, int]]:
        height = self.options.video_height_px
        if camera == TOP_CAMERA:
            width_px, height_px = settings.top_size_px
            return camera, (max(2, round(width_px * height / height_px)), height)
        return PERSPECTIVE_CAMERA, settings.perspective_size_px

    def _mark(self, step: Any, painter: Any, blade: float, lowest: np.ndarray) -> None:
        """Paint what the tool does at this step, and keep the lowest height it reached."""
        tip = step.tip
        lowest[step.index] = tip[2]
        if blade > 0:
            # the edge is horizontal at the tip's height: in the food wherever it is inside a
            # footprint, even where the tip itself has left it
            if self.inputs.props and tip[2] < self.food_top - BELOW_TOP_M:
                direction = np.asarray(step.tool_x[:2], dtype=float)
                far = tip[:2] - blade * direction / max(float(np.linalg.norm(direction)), 1e-9)
                piece = int(self.trajectory.piece_index[step.index])
                origin, axis = self.cut_lines.get(piece, (self.piece_start[piece], None))
                painter.cut(tip[:2], far, piece, origin, axis)
            return
        top, _ = self.inputs.surface_under(tip[:2])
        if tip[2] - top <= DEPOSIT_GAP_M:
            painter.deposit(np.array([tip[0], tip[1], top + 0.5 * painter.icing_radius_m]))

    def _decorate(self, mjv: Any, painter: Any) -> None:
        from keymps_mujoco.marks import add_spheres

        add_spheres(mjv, painter.spheres, painter.icing_radius_m)

    def _figures(
        self,
        result: Any,
        lowest: np.ndarray,
        kind: np.ndarray,
        pieces: np.ndarray,
        painter: Any,
        video: Any,
    ) -> dict[str, float]:
        trajectory = self.trajectory
        n = len(result.t)
        errors = np.linalg.norm(result.tip - np.asarray(trajectory.tool_xyz)[:n], axis=1)
        work = kind[:n] == "work"
        limits = np.asarray(self.inputs.robot.effort_limits, dtype=float)
        ratios = result.torque_max_nm / limits
        worst = int(np.argmax(ratios))
        contact_index = int(np.argmax(result.contact_force_n)) if n else 0
        figures: dict[str, float] = {
            "duration_s": float(trajectory.duration_s),
            "simulated_s": float(result.t[-1] - result.t[0]) if n else 0.0,
            "wall_time_s": round(result.wall_s, 3),
            "physics_steps": float(result.steps),
            "max_tracking_error_mm": float(errors.max() * 1000),
            "mean_tracking_error_mm": float(errors.mean() * 1000),
            "max_work_tracking_error_mm": float(errors[work].max() * 1000) if work.any() else 0.0,
            "max_torque_ratio": float(ratios[worst]),
            "max_torque_joint": float(worst + 1),
            "max_contact_force_n": float(result.contact_force_n.max()) if n else 0.0,
            "max_contact_force_t_s": float(result.t[contact_index]) if n else 0.0,
            "tool_board_contact_s": float(
                (result.contact_force_n > 0).sum() / float(trajectory.rate_hz)
            ),
            "arm_board_contact_n": float(result.arm_contact_n),
            "min_tool_z_mm": float(result.tip[:, 2].min() * 1000),
        }
        for index, name in enumerate(self.inputs.robot.joint_names):
            figures[f"max_torque_{name}_nm"] = float(result.torque_max_nm[index])
        if self.inputs.robot.tool.blade_length > 0:
            self._cut_figures(figures, lowest[:n], kind[:n], pieces[:n], result, painter)
        else:
            figures["icing_deposits"] = float(len(painter.spheres))
        if video is not None:
            figures["video_frames"] = float(video.frames)
            figures["video_fps"] = float(self.options.video_fps)
        return figures

    def _cut_figures(
        self,
        figures: dict[str, float],
        lowest: np.ndarray,
        kind: np.ndarray,
        pieces: np.ndarray,
        result: Any,
        painter: Any,
    ) -> None:
        """Per cut (a work piece that went below an object's top): depth and board reach."""
        cuts = 0
        reached = 0
        top = self.food_top
        for piece in np.unique(pieces[kind == "work"]):
            mine = (pieces == piece) & (kind == "work")
            heights = lowest[mine]
            heights = heights[np.isfinite(heights)]
            if not len(heights) or not self.inputs.props:
                continue
            bottom = float(heights.min())
            if bottom >= top - BELOW_TOP_M:
                continue
            cuts += 1
            touched = bool(bottom <= REACHED_BOARD_M)
            reached += touched
            figures[f"cut_{cuts}_depth_mm"] = round(min(top, top - bottom) * 1000, 2)
            figures[f"cut_{cuts}_reached_board"] = float(touched)
            figures[f"cut_{cuts}_length_mm"] = round(painter.cut_length_m(int(piece)) * 1000, 1)
            figures[f"cut_{cuts}_max_force_n"] = round(float(result.contact_force_n[mine].max()), 2)
        figures["cuts"] = float(cuts)
        figures["cuts_reached_board"] = float(reached)

    def _measured(
        self, lowest: np.ndarray, kind: np.ndarray, pieces: np.ndarray, painter: Any
    ) -> Effect | None:
        """Each cut's length through the food and depth (keymps.types.Effect), by the keypoint
        pair it was made for: what the outcome stage compares with its prediction."""
        if self.inputs.robot.tool.blade_length <= 0 or not self.inputs.props:
            return None
        tool_path = self.context.stages.compose
        n = len(lowest)
        made: dict[int, tuple[int, list[int], float]] = {}  # a pair's strokes make one cut
        for piece in np.unique(pieces[:n][kind[:n] == "work"]):
            heights = lowest[(pieces[:n] == piece) & (kind[:n] == "work")]
            heights = heights[np.isfinite(heights)]
            if not len(heights) or float(heights.min()) >= self.food_top - BELOW_TOP_M:
                continue
            owner = tool_path.pieces[int(piece)] if tool_path is not None else None
            pair = owner.pair_index if owner is not None else len(made)
            depth = float(np.clip(self.food_top - heights.min(), 0.0, self.food_top))
            _, strokes, deepest = made.get(pair, (1, [], 0.0))
            object_id = owner.object_id if owner is not None else 1
            made[pair] = (object_id, [*strokes, int(piece)], max(deepest, depth))
        cuts = [
            CutEffect(
                pair_index=pair,
                object_id=object_id,
                length_m=painter.cut_length_m(*strokes),
                depth_m=depth,
            )
            for pair, (object_id, strokes, depth) in made.items()
        ]
        return Effect(cuts=tuple(cuts))

    def _problems(self, result: Any, figures: dict[str, float]) -> list[str]:
        problems = []
        if result.stopped:
            problems.append(f"stopped: {result.stopped}")
        if figures["max_tracking_error_mm"] > self.options.max_tracking_error_mm:
            problems.append(
                f"the tool tip strayed {figures['max_tracking_error_mm']:.1f} mm from the plan "
                f"(at most {self.options.max_tracking_error_mm:g} mm)"
            )
        if figures["arm_board_contact_n"] > 0:
            problems.append(
                f"an arm link touched the board ({figures['arm_board_contact_n']:.1f} N)"
            )
        return problems


def _cut_lines(tool_path: ToolPath | None) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per work piece, the line its cut is measured along: (origin (2,), unit axis (2,)) of its
    pair's first stroke, shared by the pair's strokes (a cut longer than the blade is cut from
    both ends) so that together they measure the stretch they cover."""
    if tool_path is None:
        return {}
    lines: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    first: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for index, piece in enumerate(tool_path.pieces):
        if piece.kind != "work":
            continue
        points = np.asarray(piece.points, float)[:, :2]
        step = points[-1] - points[0]
        length = float(np.linalg.norm(step))
        if length < 1e-6:
            continue  # a plunge: measured along its edge, as before
        line = first.setdefault(piece.pair_index, (points[0], step / length))
        lines[index] = line
    return lines


def make_executor(options: dict[str, Any]) -> MujocoExecutor:
    return MujocoExecutor(parse_options(MujocoOptions, options, "executor mujoco"))
