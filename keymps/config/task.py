"""Task files: pydantic models and YAML loading with file:line:col errors."""

from __future__ import annotations

import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)

from keymps.config.yaml_positions import PositionedYaml, YamlSyntaxError, load_yaml_with_positions
from keymps.errors import TaskFileError


def _not_a_boolean(value: Any) -> Any:
    # YAML's true/false would pass as 1 and 0 (object_height: true was a 1 m tall object)
    if isinstance(value, bool):
        raise ValueError(f"a number is needed here, not {str(value).lower()}")
    return value


NUMBER = BeforeValidator(_not_a_boolean)
"""In every numeric field of a task file: a boolean is an error, not 1 or 0."""


class Unit:
    """The unit of a numeric task field, named when a value is out of its bounds ("60" for
    scene.object_height is a height in millimetres, not the 60 m the field would read)."""

    def __init__(self, name: str) -> None:
        self.name = name


METRES = Unit("metres")
METRES_PER_SECOND = Unit("metres per second")

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False), NUMBER]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False), NUMBER]
Point2 = tuple[FiniteFloat, FiniteFloat]


class StrictModel(BaseModel):
    """Unknown keys are errors; every value is finite."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class PluginSection(BaseModel):
    """A section naming a plugin; every other key is an option for that plugin."""

    model_config = ConfigDict(extra="allow", frozen=True)
    name: str

    @property
    def options(self) -> dict[str, Any]:
        return dict(self.model_extra or {})


MAX_BOARD_M = 3.0
"""No tabletop arm works on a board larger than this, or from further away: a bigger number in
a task file is millimetres, caught where it is written."""
BoardSide = Annotated[float, Field(gt=0, le=MAX_BOARD_M, allow_inf_nan=False), NUMBER, METRES]
"""A side of the imaged board, metres."""
BaseOffset = Annotated[
    float, Field(ge=-MAX_BOARD_M, le=MAX_BOARD_M, allow_inf_nan=False), NUMBER, METRES
]
"""A coordinate of the robot base (or of the board frame's origin) on the board, metres."""
MAX_PIXEL_COORDINATE = 2**20
"""OpenCV reads no image wider or taller than this (OPENCV_IO_MAX_IMAGE_WIDTH's default)."""
PixelCoordinate = Annotated[
    float, Field(ge=-MAX_PIXEL_COORDINATE, le=MAX_PIXEL_COORDINATE, allow_inf_nan=False), NUMBER
]
Degrees = Annotated[float, Field(ge=-360, le=360, allow_inf_nan=False), NUMBER]
ToolOffset = Annotated[float, Field(ge=-1.0, le=1.0, allow_inf_nan=False), NUMBER, METRES]
"""A tool tip coordinate in the flange frame, metres: no UR3 tool is a metre long."""
MAX_IMAGE_PIXELS_LIMIT = 2**30
"""OpenCV's own ceiling (OPENCV_IO_MAX_IMAGE_PIXELS' default): scene.max_image_pixels' bound."""


class Workspace(StrictModel):
    size: tuple[BoardSide, BoardSide] = (0.30, 0.18)
    """s_env: (width, height) of the area the image spans, metres."""
    shift: tuple[BaseOffset, BaseOffset] = (0.0, 0.0)
    """g_shift: offset of the board frame's origin, metres."""


PixelPoint = tuple[PixelCoordinate, PixelCoordinate]
FocalLength = Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False), NUMBER]
"""Pixels: a million is a telephoto lens on a 20000-pixel sensor, beyond any table camera."""
DistortionCoefficient = Annotated[float, Field(ge=-1e4, le=1e4, allow_inf_nan=False), NUMBER]


class Intrinsics(StrictModel):
    """A calibrated pinhole camera (OpenCV's convention: pixel centres at integers)."""

    fx: FocalLength
    fy: FocalLength
    cx: PixelCoordinate
    cy: PixelCoordinate
    distortion: tuple[DistortionCoefficient, ...] = ()
    """k1, k2, p1, p2[, k3[, k4, k5, k6]] as cv2.calibrateCamera gives them; empty: none."""

    @field_validator("distortion")
    @classmethod
    def _opencv_lengths(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        if len(value) not in (0, 4, 5, 8):
            raise ValueError(
                f"needs 4, 5 or 8 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]), got {len(value)}"
            )
        return value


class Camera(StrictModel):
    board_corners_px: tuple[PixelPoint, PixelPoint, PixelPoint, PixelPoint] | None = None
    """Pixels of the workspace corners: bottom-left, bottom-right, top-right, top-left."""
    mm_per_px: Annotated[float, Field(ge=0.05, le=10, allow_inf_nan=False), NUMBER] = 0.5
    """Resolution of the rectified top-down image the stages work in (with board corners)."""
    intrinsics: Intrinsics | None = None
    """With board corners: undistort, find the camera's pose, ground on the object's top."""


class SceneObjectSpec(StrictModel):
    """One object the task describes (scene.objects), matched to a detected object."""

    name: str = Field(min_length=1, max_length=60, pattern=r"^[A-Za-z][A-Za-z0-9 _-]*$")
    """What it is ("banana"); the offline planner reads it ("cut the banana in half")."""
    height: Annotated[float, Field(ge=0, le=1.0, allow_inf_nan=False), NUMBER, METRES] | None = None
    """Its top surface above the board, metres; scene.object_height when omitted."""
    at: tuple[BaseOffset, BaseOffset] | None = None
    """A board point (metres, within MAX_BOARD_M) on or near it: pins it to the detected object nearest there
    instead of matching left to right."""


class Scene(StrictModel):
    image: Path | None = None
    source: str = "file"
    """Image source plugin: file, synthetic, opencv, or one from a plugin package."""
    source_options: dict[str, Any] = Field(default_factory=dict)
    workspace: Workspace = Workspace()
    object_height: Annotated[float, Field(ge=0, le=1.0, allow_inf_nan=False), NUMBER, METRES] = 0.05
    objects: list[SceneObjectSpec] | None = Field(default=None, min_length=1, max_length=32)
    """The objects on the board, left to right (keymps.perception.scene_objects matches them
    to the detected ones); without it every object has object_height."""
    camera: Camera = Camera()
    max_image_pixels: Annotated[int, Field(ge=1, le=MAX_IMAGE_PIXELS_LIMIT), NUMBER] = 64_000_000
    """Larger images are refused from their header, before decoding (keymps.config.limits)."""

    @model_validator(mode="after")
    def _image_for_file_source(self) -> Scene:
        if self.source == "file" and self.image is None:
            raise ValueError("scene.image is required when scene.source is 'file'")
        return self

    @property
    def tallest_object_height(self) -> float:
        """The highest top surface of any object on the board, metres."""
        declared = [o.height for o in self.objects or () if o.height is not None]
        defaulted = any(o.height is None for o in self.objects) if self.objects else True
        return max([*declared, *([self.object_height] if defaulted else [])])


class Planner(StrictModel):
    backend: str = "auto"
    """auto | offline | litellm | replay, or a backend from a plugin package."""
    model: str | None = None
    prompt: Path | None = None
    api_base: str | None = None
    api_key_env: str | None = None
    """Name of the environment variable holding the key (never the key itself)."""
    temperature: Annotated[float, Field(ge=0, le=2, allow_inf_nan=False), NUMBER] = 0.0
    timeout_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False), NUMBER] = 60.0
    max_tokens: Annotated[int | None, Field(ge=1, le=1_000_000), NUMBER] = None
    """The longest answer asked for, in tokens; none: the server's own limit."""
    max_pairs: Annotated[int, Field(ge=1, le=10_000), NUMBER] = 64
    attempts: Annotated[int, Field(ge=1, le=10), NUMBER] = 2
    combined: bool = True
    """One VLM call for keyword and pairs (the paper's choice) or two calls."""
    cache: bool = True
    cassette: Path | None = None
    coordinates: Literal["auto", "pixels", "xy_1000", "yx_1000"] = "auto"
    """How the model writes points: auto picks by model family (docs/vlm.md)."""
    answer: Literal["pairs", "design", "either"] = "either"
    """Keypoint pairs, a named design from the offline catalogue, or either of them."""

    @field_validator("api_base")
    @classmethod
    def _a_server_url(cls, value: str | None) -> str | None:
        # litellm would retry a scheme-less or host-less base for seconds, then report HTTP 500
        from urllib.parse import urlsplit

        if value is None:
            return value
        try:
            parts = urlsplit(value.strip())
            usable = parts.scheme in ("http", "https") and bool(parts.hostname)
        except ValueError:  # a malformed IPv6 host, a port that is no number
            usable = False
        if not usable:
            raise ValueError(
                f"{value!r} is not an http(s) URL with a host (e.g. http://127.0.0.1:8000/v1)"
            )
        return value


class Height(StrictModel):
    mode: Literal["both", "start", "end"] = "both"
    margin: Annotated[float, Field(ge=-0.05, le=0.1, allow_inf_nan=False), NUMBER, METRES] = 0.005
    """Added to the object's top surface wherever the height is integrated, metres."""


MAX_PATH_LENGTH_M = 1000.0
"""motion.max_path_length's own bound: a kilometre of strokes is no kitchen task."""
MAX_DURATION_S = 4 * 3600.0
"""motion.max_duration_s' own bound: at 500 Hz, 4 h is 7.2 million samples (about 1 GB)."""


class Motion(StrictModel):
    clearance: Annotated[float, Field(ge=0.005, le=0.3, allow_inf_nan=False), NUMBER, METRES] = 0.03
    """Travel moves rise this far above the object's top, metres."""
    work_speed: Annotated[
        float, Field(gt=0, le=0.5, allow_inf_nan=False), NUMBER, METRES_PER_SECOND
    ] = 0.03
    travel_speed: Annotated[
        float, Field(gt=0, le=1.0, allow_inf_nan=False), NUMBER, METRES_PER_SECOND
    ] = 0.15
    max_path_length: Annotated[
        float, Field(gt=0, le=MAX_PATH_LENGTH_M, allow_inf_nan=False), NUMBER, METRES
    ] = 50.0
    """Longer tool paths are refused before inverse kinematics, metres (keymps.config.limits)."""
    max_duration_s: Annotated[
        float, Field(gt=0, le=MAX_DURATION_S, allow_inf_nan=False), NUMBER
    ] = 1800.0
    """Longer motions are refused (estimated before IK, measured after timing), seconds."""


class ToolSpec(StrictModel):
    """A tool: a built-in name (knife, piping_bag) alone, or a name with its own TCP."""

    name: str
    tcp: tuple[ToolOffset, ToolOffset, ToolOffset] | None = None
    """Tool tip in the flange frame, metres; None takes the built-in tool's."""
    yaw: Literal["follow", "fixed"] | None = None
    """'follow': the blade turns with the cut direction (knife); None takes the built-in's."""
    blade_length: Annotated[float, Field(gt=0, le=0.4, allow_inf_nan=False), NUMBER] | None = None
    """A knife's straight edge, from the tip back along the cut, metres; None takes the
    built-in's (knife 0.16, piping_bag none; a custom tool has none)."""
    line_width: Annotated[float, Field(gt=0, le=0.05, allow_inf_nan=False), NUMBER] | None = None
    """Width of the icing line the tool draws, metres; None takes the built-in's (piping_bag
    0.004, knife none). The offline planner refuses designs whose strokes would merge."""


JointLimit = Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False), NUMBER]
JointAngle = Annotated[float, Field(ge=-100.0, le=100.0, allow_inf_nan=False), NUMBER]
"""radians (or metres for a prism joint): no joint turns 16 times."""
ModelName = Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")]
"""A registered robot's name (`keymps plugins` lists them): letters, digits, _ . -"""
LinkName = Annotated[str, Field(min_length=1, max_length=200)]
MAX_URDF_BYTES = 5_000_000
"""A robot's URDF is tens of kilobytes (keymps.robot.urdf_model reads at most this)."""


class RobotLimits(StrictModel):
    """A URDF arm's limits the URDF does not hold: one value for every joint, or one per joint."""

    velocity: JointLimit | list[JointLimit] | None = None
    """rad/s (a URDF's own `<limit velocity>` when omitted)."""
    acceleration: JointLimit | list[JointLimit] | None = None
    """rad/s^2 (3.0 when omitted)."""
    jerk: JointLimit | list[JointLimit] | None = None
    """rad/s^3 (100 when omitted)."""


class Robot(StrictModel):
    model: ModelName | None = None
    """A registered arm (ur3, ur5e, panda, so101, a plugin's); ur3 when neither this nor
    urdf is given."""
    urdf: Path | None = None
    """Your own arm's URDF, relative to this file and inside its folder tree."""
    tip_link: LinkName | None = None
    """With urdf: the link the tool is mounted on (its z axis the tool's direction)."""
    joints: list[LinkName] | None = Field(default=None, min_length=1, max_length=12)
    """With urdf: the arm's joints in the controller's order (default: root to tip_link)."""
    limits: RobotLimits | None = None
    home: list[JointAngle] | None = Field(default=None, min_length=1, max_length=12)
    """With urdf: the configuration the inverse kinematics starts from (radians)."""
    base: tuple[BaseOffset, BaseOffset, BaseOffset, Degrees] | None = None
    """x, y, z in metres and yaw in degrees of the robot base in the board frame; the arm's
    own default for the board when omitted."""
    tool: ToolSpec = ToolSpec(name="knife")
    rate_hz: Annotated[float, Field(ge=10, le=1000, allow_inf_nan=False), NUMBER] | None = None
    """Controller rate: the arm's own when omitted (UR: 125 Hz CB3, 500 Hz e-Series)."""
    max_joint_acceleration: (
        Annotated[float, Field(ge=0.05, le=50, allow_inf_nan=False), NUMBER] | None
    ) = None
    """rad/s^2, a cap on every joint's limit (the arm's own when omitted: UR 3.0, the maker
    publishes none)."""
    max_joint_jerk: Annotated[float, Field(ge=0.5, le=5000, allow_inf_nan=False), NUMBER] | None = (
        None
    )
    """rad/s^3, a cap on every joint's limit (the arm's own when omitted: UR 100)."""
    max_tool_acceleration: Annotated[float, Field(ge=0.01, le=10, allow_inf_nan=False), NUMBER] = (
        0.5
    )
    """m/s^2; the lower bounds keep one stroke's timing within minutes, not years."""
    max_tool_jerk: Annotated[float, Field(ge=0.05, le=1000, allow_inf_nan=False), NUMBER] = 20.0

    @field_validator("tool", mode="before")
    @classmethod
    def _tool_by_name(cls, value: Any) -> Any:
        return {"name": value} if isinstance(value, str) else value

    @model_validator(mode="after")
    def _one_arm(self) -> Robot:
        if self.model is not None and self.urdf is not None:
            raise ValueError("give either model (a registered arm) or urdf (your own), not both")
        if self.urdf is not None and self.tip_link is None:
            raise ValueError("urdf needs tip_link: the link the tool is mounted on")
        if self.urdf is None:
            given = [k for k in ("tip_link", "joints", "limits", "home") if getattr(self, k)]
            if given:
                raise ValueError(f"{', '.join(given)} describe a urdf arm; add urdf")
        return self

    def base_xy(self, workspace: Workspace) -> tuple[float, float]:
        """Where the base stands on the board, roughly: `base`, else in front of the middle of
        the workspace's near edge (where every built-in arm's default placement is)."""
        if self.base is not None:
            return self.base[0], self.base[1]
        return workspace.shift[0] + workspace.size[0] / 2, workspace.shift[1] - 0.2

    @property
    def arm_name(self) -> str:
        """The registered robot the task's arm is built by (its own URDF: `urdf`)."""
        return self.model or ("urdf" if self.urdf is not None else "ur3")

    def arm_component(self, folder: Path) -> tuple[str, dict[str, Any]]:
        """(robot name, factory options): a task's own URDF with its path resolved against the
        task's folder and its meshes kept inside the URDF's package folder."""
        if self.urdf is None:
            return self.arm_name, {}
        urdf = self.urdf if self.urdf.is_absolute() else folder / self.urdf
        package = urdf.parent.parent if urdf.parent.name == "urdf" else urdf.parent
        options: dict[str, Any] = {
            "urdf": urdf,
            "tip_link": self.tip_link,
            "package_dirs": [package],
        }
        if self.joints:
            options["joints"] = list(self.joints)
        if self.home:
            options["home"] = list(self.home)
        if self.rate_hz is not None:
            options["rate_hz"] = self.rate_hz
        for name in ("velocity", "acceleration", "jerk"):
            value = getattr(self.limits, name, None) if self.limits else None
            if value is not None:
                options[name] = [value] if isinstance(value, float) else list(value)
        return "urdf", options


Count = Annotated[int, Field(ge=0, le=1000, strict=True)]


class Expect(StrictModel):
    """What the user asserts the run must achieve (docs/tasks.md, `expect:`): checked by the
    outcome stage against the predicted result before anything moves."""

    pieces: Annotated[int, Field(ge=1, le=1000, strict=True)] | None = None
    equal: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] | bool | None = None
    """true (Appendix F's 5 %), or the fraction of an equal share each piece may be off."""
    equal_by: Literal["area", "width"] | None = None
    orientation: Literal["vertical", "horizontal", "lengthwise", "crosswise"] | None = None
    slice_width: (
        Annotated[float, Field(gt=0, le=MAX_BOARD_M, allow_inf_nan=False), NUMBER] | None
    ) = None
    """Each slice this wide across the cuts, metres."""
    object_length: (
        Annotated[float, Field(gt=0, le=MAX_BOARD_M, allow_inf_nan=False), NUMBER] | None
    ) = None
    """The object's length the slice width refers to, metres."""
    dots: Count | None = None
    rings: Count | None = None
    digits: Annotated[str, Field(pattern=r"^[0-9]{1,12}$")] | None = None

    @model_validator(mode="after")
    def _equal_needs_pieces(self) -> Expect:
        if self.equal not in (None, False) and self.pieces is None:
            raise ValueError("equal needs pieces: how many equal pieces")
        return self


@dataclass(frozen=True)
class TaskOrigin:
    """Where a task was read from: for errors found after loading, and the file's own api_base."""

    source: str = "<task>"
    """The task file as messages show it, or a name for a task built in code."""
    written: PositionedYaml | None = None
    """The file's YAML with each field's line and column (None for a task built in code)."""
    api_base: str | None = None
    """planner.api_base as the task file wrote it: a server no key is sent to unless the user
    names it too (--api-base, user config; keymps.planning.backend_choice)."""


class Task(StrictModel):
    """A validated task file: the sentence, the scene, and the components that carry it out.

    Built by `keymps.load_task` (or `parse_task` from text); unknown keys are errors and every
    error names the file, line, column and field. Every field is described in docs/tasks.md.
    """

    name: str = Field(min_length=1, max_length=200)
    """Names the run folder (`runs/<name>-<time>/`)."""
    instruction: str = Field(min_length=1, max_length=4000)
    """The sentence the planner carries out ("cut it into 8 equal slices")."""
    scene: Scene
    """The image, the workspace it spans (metres), the objects and their heights."""
    detector: PluginSection = PluginSection(name="board")
    """The detector plugin (`name`) and its options."""
    planner: Planner = Planner()
    """The planner backend (auto, offline, litellm, replay), model, prompt and answer format."""
    primitives: list[Annotated[str, Field(min_length=1, max_length=200)]] = Field(
        min_length=1, max_length=100
    )
    """The primitive names the planner may choose from (the dictionary's file names)."""
    height: Height = Height()
    """How the object's height is integrated into the segments (Appendix C)."""
    motion: Motion = Motion()
    """Clearance (metres) and speeds (m/s) of the tool path, and its bounds."""
    robot: Robot = Robot()
    """The arm's model, base pose on the board, tool, controller rate and limits."""
    executor: PluginSection = PluginSection(name="sim")
    """The executor plugin (`name`) and its options."""
    expect: Expect | None = None
    """What the run must achieve; checked before anything moves (the outcome stage)."""
    path: Path | None = Field(default=None, exclude=True)
    """The task file this was loaded from (None when built in code)."""
    _origin: TaskOrigin = PrivateAttr(default_factory=lambda: TaskOrigin())

    @field_validator("name")
    @classmethod
    def _one_folder_name(cls, value: str) -> str:
        # runs/<name>-<time>: a shared task file's name must not lead the run folder elsewhere
        if value.startswith(".") or any(c in "/\\" or ord(c) < 32 or ord(c) == 127 for c in value):
            raise ValueError(
                "the name starts the run folder's name (runs/<name>-<time>): "
                "no '/', '\\' or control characters, and no '.' first"
            )
        return value

    @field_validator("instruction")
    @classmethod
    def _printable(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("instruction is empty")
        if any(ord(c) < 32 or ord(c) == 127 for c in value):
            raise ValueError(
                "instruction contains control characters (a line break, a tab ...): write it on "
                "one line (YAML's folded style, `instruction: >`, joins lines with spaces)"
            )
        return value

    @property
    def folder(self) -> Path:
        """The task file's folder (the current folder for a task built in code)."""
        return self.path.parent if self.path else Path.cwd()

    @property
    def api_base_from_file(self) -> bool:
        """True when planner.api_base is the task file's own value, not one the user gave."""
        api_base = self.planner.api_base
        return api_base is not None and api_base == self._origin.api_base

    @property
    def origin(self) -> TaskOrigin:
        """Where this task was read from (see `remember_origin`)."""
        return self._origin

    def remember_origin(self, origin: TaskOrigin) -> Task:
        """Keep where this task was read from, for `where` and `api_base_from_file`.

        Args:
            origin: The file as messages show it, its positioned YAML, and its own api_base.

        Returns:
            This task.
        """
        self._origin = origin
        return self

    def resolve(self, relative: Path) -> Path:
        """A path from the task file, taken relative to the task file's folder.

        Args:
            relative: A path as the task file wrote it.

        Returns:
            `relative` itself when absolute, else `folder / relative`.
        """
        return relative if relative.is_absolute() else (self.folder / relative)

    def where(self, *field_path: str | int) -> str:
        """Where a field is written, for errors found after loading (e.g. a plugin's name).

        Args:
            *field_path: Keys and list indices from the top, e.g. `"detector", "name"`.

        Returns:
            `file:line:col` of the field (of its nearest written parent when the file leaves
            it out); the source's name alone for a task built in code.
        """
        origin = self._origin
        if origin.written is None:
            return origin.source
        line, column = origin.written.locate(tuple(field_path))
        return f"{origin.source}:{line}:{column}"


def _field_name(loc: tuple[Any, ...]) -> str:
    parts: list[str] = []
    for part in loc:
        if isinstance(part, int):
            parts.append(f"[{part}]")
        else:
            text = str(part)
            shown = text if text.isprintable() and text and " " not in text else repr(text)
            parts.append(("." if parts else "") + shown)
    return "".join(parts) or "(task)"


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _pydantic_loc_to_yaml_path(loc: tuple[Any, ...]) -> tuple[Any, ...]:
    # pydantic adds union-member and validator names ("str", "ToolSpec", "function-after[...]")
    # that do not exist in the YAML.
    return tuple(p for p in loc if isinstance(p, int) or not (p[:1].isupper() or "[" in p))


def _format_problems(source: str, parsed: PositionedYaml, error: ValidationError) -> list[str]:
    """One located line per problem, in the order of the file (pydantic's is the models')."""
    lines: list[tuple[int, int, str]] = []
    for item in error.errors(include_url=False):
        path = _pydantic_loc_to_yaml_path(tuple(item["loc"]))
        line, column = parsed.locate(path, at_key=item["type"] == "extra_forbidden")
        message = item["msg"]
        if item["type"] == "extra_forbidden":
            message = "unknown key" + _did_you_mean(path)
        elif _too_large(item):
            message += _unit_hint(path)
        elif item["type"] == "missing":
            message = "field required"
        elif message.startswith("Value error, "):
            message = message.removeprefix("Value error, ")
        text = f"{source}:{line}:{column}: {_field_name(path)}: {_one_line(message)}"
        lines.append((line, column, text))
    return [text for _, _, text in sorted(lines, key=lambda entry: entry[:2])]


def _too_large(item: Any) -> bool:
    """A value past its bound's far end (60 for a height at most 1 m, -200 for an offset at
    least -3 m): often another unit's number, so the message names the field's unit."""
    kind, bound = item["type"], dict(item.get("ctx") or {})
    if kind in ("less_than", "less_than_equal"):
        return True
    limit = bound.get("ge", bound.get("gt"))
    return (
        kind in ("greater_than", "greater_than_equal")
        and isinstance(limit, int | float)
        and limit < 0
    )


def _model_at(path: tuple[Any, ...]) -> tuple[type[BaseModel] | None, str | None]:
    """The task model that holds the last key of `path`, and that key (list indexes skipped)."""
    model: type[BaseModel] | None = Task
    keys = [part for part in path if isinstance(part, str)]
    for key in keys[:-1]:
        field = model.model_fields.get(key) if model else None
        model = _submodel(field.annotation) if field else None
    return model, (keys[-1] if keys else None)


def _submodel(annotation: Any) -> type[BaseModel] | None:
    """The task model inside a field's type (`Camera`, `list[SceneObjectSpec] | None` ...)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for argument in get_args(annotation):
        found = _submodel(argument)
        if found is not None:
            return found
    return None


def _did_you_mean(path: tuple[Any, ...]) -> str:
    import difflib

    model, key = _model_at(path)
    if model is None or key is None:
        return ""
    close = difflib.get_close_matches(key, list(model.model_fields), n=1, cutoff=0.8)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _unit_hint(path: tuple[Any, ...]) -> str:
    model, key = _model_at(path)
    field = model.model_fields.get(key) if model is not None and key is not None else None
    if field is None:
        return ""
    units = [
        u for u in [*field.metadata, *_annotated_metadata(field.annotation)] if isinstance(u, Unit)
    ]
    return f" (the unit is {units[0].name})" if units else ""


def _annotated_metadata(annotation: Any) -> list[Any]:
    """Metadata of every Annotated type inside a field's type (tuple items, `X | None`)."""
    found = list(getattr(annotation, "__metadata__", ()))
    for argument in get_args(annotation):
        found.extend(_annotated_metadata(argument))
    return found


def display_path(path: Path) -> str:
    """A task file's path as its errors name it: relative to the working folder when inside it.

    Args:
        path: The task file.

    Returns:
        The path relative to the working folder, or as given.
    """
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except (ValueError, OSError, RuntimeError):  # elsewhere, or a symlink loop
        return str(path)


def parse_task(text: str, source: str = "<task>", path: Path | None = None) -> Task:
    """Validate task YAML text; raise TaskFileError with one located line per problem."""
    try:
        parsed = load_yaml_with_positions(text)
    except YamlSyntaxError as error:
        line, column = error.location
        raise TaskFileError(
            [f"{source}:{line}:{column}: invalid YAML: {_one_line(str(error))}"]
        ) from None
    if not isinstance(parsed.data, dict):
        raise TaskFileError([f"{source}:1:1: (task): expected a mapping of task fields"])
    if "cases" in parsed.data and "instruction" not in parsed.data:
        raise TaskFileError(
            [
                f"{source}:1:1: (task): an eval suite (it lists cases), not a task file: run it "
                f"with `keymps eval {source}` (docs/benchmarks.md)"
            ]
        )
    data = {k: v for k, v in parsed.data.items() if k != "path"}
    try:
        task = Task.model_validate({**data, "path": path})
    except ValidationError as error:
        raise TaskFileError(_format_problems(source, parsed, error)) from None
    problems = referenced_file_problems(task, source, parsed)
    if problems:
        raise TaskFileError(problems)
    return task.remember_origin(TaskOrigin(source, parsed, task.planner.api_base))


def file_problem(path: Path) -> str | None:
    """Why `path` cannot be read as an input file (None when it is a regular file)."""
    from keymps.config.trust import shown_path

    shown = shown_path(path)
    try:
        mode = path.stat().st_mode
    except ValueError:  # a NUL character: no file can have this name
        return f"not a valid file name: {shown}"
    except OSError as error:  # ENOENT, ENAMETOOLONG, ELOOP, EACCES ...
        if isinstance(error, FileNotFoundError):
            return f"file not found: {shown}"
        return f"cannot read {shown}: {error.strerror}"
    if stat.S_ISDIR(mode):
        return f"is a folder, not a file: {shown}"
    if not stat.S_ISREG(mode):
        return f"not a regular file (a device, a pipe or a socket): {shown}"
    return None


def image_file_problem(path: Path) -> str | None:
    """Why a regular file is no image (its first bytes), before a run makes its folder."""
    from keymps.config.limits import looks_like_an_image
    from keymps.config.trust import shown_path

    try:
        with path.open("rb") as handle:
            head = handle.read(16)
    except OSError as error:
        return f"cannot read {shown_path(path)}: {error.strerror}"
    if not head:
        return f"an empty file (0 bytes), not an image: {shown_path(path)}"
    if not looks_like_an_image(head):
        return (
            f"not an image file (no PNG, JPEG, TIFF, BMP, WebP ... signature in its first "
            f"bytes): {shown_path(path)}"
        )
    return None


def referenced_file_problems(task: Task, source: str, parsed: PositionedYaml) -> list[str]:
    """What is wrong with the files a task names (its scene image), and what a shared task file
    may not do (name any variable as its key, read any file).

    Args:
        task: The validated task.
        source: The task file as its errors name it (display_path).
        parsed: The task's YAML with positions, for each problem's line and column.

    Returns:
        One `file:line:col: field: problem` line per problem; empty when there is none.
    """
    checks: list[tuple[tuple[str, ...], Path | None]] = [
        (("scene", "image"), task.scene.image if task.scene.source == "file" else None),
    ]
    problems = _check_trust(task, source, parsed)
    for key_path, relative in checks:
        if relative is None:
            continue
        resolved = task.resolve(relative)
        problem = file_problem(resolved) or image_file_problem(resolved)
        if problem:
            line, column = parsed.locate(key_path)
            problems.append(f"{source}:{line}:{column}: {'.'.join(key_path)}: {problem}")
    return problems


def _check_trust(task: Task, source: str, parsed: PositionedYaml) -> list[str]:
    """What a shared task file may not do: name any variable as its key, read any file."""
    from keymps.config import trust
    from keymps.config.user import load_user_config

    problems = []

    def problem(key_path: tuple[str, ...], message: str) -> None:
        line, column = parsed.locate(key_path)
        problems.append(f"{source}:{line}:{column}: {'.'.join(key_path)}: {message}")

    env = task.planner.api_key_env
    if env is not None:
        allowed = load_user_config().api_key_envs
        wrong = trust.api_key_env_problem(env, allowed)
        if wrong:
            problem(("planner", "api_key_env"), wrong)
    if task.robot.urdf is not None:
        wrong = trust.readable_file_problem(
            task.resolve(task.robot.urdf), [task.folder], MAX_URDF_BYTES
        )
        if wrong:
            problem(("robot", "urdf"), wrong)
    if task.planner.prompt is not None:
        wrong = trust.readable_file_problem(
            task.resolve(task.planner.prompt),
            trust.prompt_roots(task.folder),
            trust.MAX_PROMPT_BYTES,
        )
        if wrong:
            problem(("planner", "prompt"), wrong)
    if task.planner.cassette is not None:  # --cassette, the user's own, is not checked here
        wrong = trust.readable_file_problem(
            task.resolve(task.planner.cassette),
            [trust.real_path(task.folder)],
            trust.MAX_CASSETTE_BYTES,
        )
        if wrong:
            problem(("planner", "cassette"), wrong)
    return problems


MAX_TASK_FILE_BYTES = 1_000_000
"""Task files are a few hundred bytes; /dev/zero or a mistaken 4 GB file is not read."""


def read_task_text(path: Path) -> str:
    """A task file's text: a regular file of at most MAX_TASK_FILE_BYTES, UTF-8 (one located
    TaskFileError otherwise: /dev/zero or a 4 GB file is never read)."""
    source = display_path(path)
    if path.exists() and not path.is_dir() and not path.is_file():
        raise TaskFileError([f"{source}: not a regular file (a device or a pipe)"])
    if path.is_file() and path.stat().st_size > MAX_TASK_FILE_BYTES:
        raise TaskFileError(
            [f"{source}: {path.stat().st_size} bytes; a task file is at most 1 MB of YAML"]
        )
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TaskFileError([f"{source}: task file not found"]) from None
    except IsADirectoryError:
        raise TaskFileError([f"{source}: is a folder, not a task file"]) from None
    except UnicodeDecodeError as error:
        raise TaskFileError([f"{source}: not a UTF-8 text file ({error.reason})"]) from None
    except OSError as error:
        raise TaskFileError([f"{source}: cannot read: {error.strerror}"]) from None


def load_task(path: str | Path) -> Task:
    """Read and validate a task file. Errors name the file, line, column and field."""
    path = Path(path)
    text = read_task_text(path)
    source = display_path(path)
    return parse_task(text, source=source, path=path.resolve())
