"""The data passed between pipeline stages: typed, immutable, numpy inside.

Frames and units, used everywhere in keymps:

- image pixels: origin at the top-left corner of the full image, x right, y down;
- crop pixels: the same, with the origin at the top-left corner of the crop sent to the VLM;
- board frame: metres, origin at the bottom-left corner of the workspace as seen in the image,
  x to the image's right, y to the image's top, z up out of the board (right-handed).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

__all__ = [
    "EQUAL_PARTS_TOLERANCE",
    "STAGES",
    "AnswerMode",
    "BackendAnswer",
    "CutEffect",
    "CutOrientation",
    "DepositEffect",
    "DetectedObject",
    "Detection",
    "Effect",
    "EqualBy",
    "ExecutionReport",
    "GroundedObject",
    "Grounding",
    "IntentFamily",
    "IntentSource",
    "JointPath",
    "Outcome",
    "OutcomeVerdict",
    "Piece",
    "PieceEffect",
    "PieceKind",
    "PieceShape",
    "Plan",
    "PlanIntent",
    "PlanObject",
    "PlanRequest",
    "Rectification",
    "SceneImage",
    "Segment",
    "Step",
    "ToolPath",
    "Trajectory",
    "ValidatedTrajectory",
    "ValidationReport",
    "VlmCall",
]

PieceKind = Literal["work", "travel"]
"""A piece of the tool path: `work` (a re-targeted primitive on the object) or `travel` (a
straight move between pieces, clear of the object)."""
Step = Literal["combined", "keyword", "pairs", "direct"]
"""A planning call: the combined answer, the keyword or pairs alone, or an eval method's own
prompt (keymps.eval.vlm)."""
AnswerMode = Literal["pairs", "design", "either"]
"""What form of answer a planning call asks for (`planner.answer`): keypoint pairs, a named
design from the offline planner's catalogue, or either of them."""


@dataclass(frozen=True)
class Rectification:
    """How a photo became the metric top-down image the stages work in (scene.camera)."""

    photo: np.ndarray
    """The photo as the image source gave it (BGR, uint8)."""
    mm_per_px: float
    """Size of a rectified pixel on the board (scene.camera.mm_per_px)."""
    plane_z: float
    """Height (metres) of the plane keypoints are grounded on: 0 (the board), or the object's
    top when intrinsics give the camera's position (the image always shows the board plane)."""
    to_photo: np.ndarray
    """3x3: rectified pixels -> undistorted photo pixels (continuous coordinates)."""
    board_polygon_px: np.ndarray
    """(4, 2) the board's corners (bottom-left first) in the rectified image."""
    camera_matrix: np.ndarray | None = None
    """3x3 intrinsics (OpenCV convention), when given."""
    distortion: np.ndarray | None = None
    """OpenCV's distortion coefficients (k1, k2, p1, p2[, k3 ...]), when given."""
    camera_position_m: tuple[float, float, float] | None = None
    """The camera's centre in the board frame (solvePnP on the corners), with intrinsics."""
    camera_foot_px: tuple[float, float] | None = None
    """The point of the board straight below the camera, in rectified pixels."""


@dataclass(frozen=True)
class SceneImage:
    """The environment image (BGR, uint8) and where it came from: the `image` stage's result."""

    image: np.ndarray
    """(H, W, 3) BGR, uint8: the top-down image every later stage works in (rectified to the
    board when the task gives scene.camera)."""
    source: str
    """Where it came from: a file path, `synthetic:<objects>:seed=<n>`, `opencv:<camera>` ..."""
    truth: dict[str, Any] | None = None
    """A synthetic scene's true geometry (its JSON sidecar, keymps.scenes); None for photos."""
    rectification: Rectification | None = None
    """Set when `image` is the photo rectified to the board (scene.camera.board_corners_px)."""

    @property
    def size_px(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])


@dataclass(frozen=True)
class DetectedObject:
    """One object on the board, as a detector found it (several objects: issue 20)."""

    id: int
    """1-based; numbered left to right, then top to bottom (by bbox centre)."""
    bbox_px: tuple[int, int, int, int]
    """[x0, y0, x1, y1] in full-image pixels; x1 and y1 are exclusive."""
    contour_px: np.ndarray
    """(N, 2) outline in full-image pixels."""
    area_px: float
    """Its area in full-image pixels (the contour's, or the mask's pixel count)."""
    mask: np.ndarray | None = None
    """(H, W) boolean mask over the full image, if the detector made one."""


@dataclass(frozen=True)
class Detection:
    """The object found in the scene image (Appendix A): the `detect` stage's result."""

    bbox_px: tuple[int, int, int, int]
    """[x0, y0, x1, y1] in full-image pixels; x1 and y1 are exclusive."""
    crop: np.ndarray
    """(h, w, 3) BGR, uint8: the image sent to the planner (the bbox plus padding, clipped to
    the image)."""
    crop_origin_px: tuple[int, int]
    """Top-left corner of the crop in full-image pixels (the paper's b_offset)."""
    contour_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """(N, 2) the object's outline in full-image pixels (empty when the detector gives none)."""
    mask: np.ndarray | None = None
    """(H, W) boolean mask of the object over the full image, if the detector made one."""
    others_px: tuple[tuple[int, int, int, int], ...] = ()
    """Bounding boxes of other large regions, largest first."""
    warnings: tuple[str, ...] = ()
    """What the detector doubts (an object touching the side of the searched area, say), one
    line each; the run prints them and run.json keeps them."""
    objects: tuple[DetectedObject, ...] = ()
    """Every object found (the one in bbox_px included), in id order; empty from a detector
    that reports one object only."""
    report: dict[str, Any] = field(default_factory=dict)
    """What the detector decided and why (its background model, threshold, the regions it
    considered): JSON-ready, written to run.json's detection.report."""

    @property
    def crop_size_px(self) -> tuple[int, int]:
        """(width, height) of the crop in pixels."""
        return int(self.crop.shape[1]), int(self.crop.shape[0])


@dataclass(frozen=True)
class VlmCall:
    """One request/answer exchange with a planner backend (secrets already redacted)."""

    attempt: int
    """1-based: the first answer, then one per repair."""
    request: dict[str, Any]
    """The request as sent (messages, model, schema), JSON-ready, secrets redacted."""
    answer_text: str
    """The answer exactly as the backend gave it."""
    error: str | None = None
    """Why the answer was refused (and repaired or given up on); None when it was used."""
    latency_s: float = 0.0
    """Wall-clock time of the call, seconds (0 for a cached answer)."""
    prompt_tokens: int | None = None
    """Tokens of the request, as the provider counted them; None when unknown."""
    completion_tokens: int | None = None
    """Tokens of the answer, as the provider counted them; None when unknown."""
    cost_usd: float | None = None
    """The call's price in US dollars; None where the price is unknown."""
    cached: bool = False
    """The answer came from the on-disk cache or a cassette: no call was made."""
    model_call: bool = True
    """False for backends that ask no model (the offline planner): not counted as VLM calls."""


@dataclass(frozen=True)
class PlanObject:
    """One object in the crop sent to the planner."""

    id: int
    """Its DetectedObject.id."""
    name: str | None
    """What the task calls it (scene.objects), e.g. "banana"; None when unnamed."""
    height: float
    """Top surface above the board, metres."""
    bbox_px: tuple[int, int, int, int]
    """[x0, y0, x1, y1] in crop pixels (exclusive ends)."""
    mask: np.ndarray | None
    """Its pixels in the crop (bool), when known."""
    size_m: tuple[float, float]
    """Width and height of its box on the board, metres."""

    @property
    def label(self) -> str:
        """'#2 banana' (or '#2' without a name): how prompts and messages name it."""
        return f"#{self.id} {self.name}" if self.name else f"#{self.id}"

    @property
    def centre_px(self) -> tuple[float, float]:
        """(x, y) centre of its box in crop pixels."""
        x0, y0, x1, y1 = self.bbox_px
        return (x0 + x1) / 2, (y0 + y1) / 2

    @property
    def area_px(self) -> float:
        """Its area in crop pixels: the mask's pixel count, else its box's area."""
        if self.mask is not None:
            return float(self.mask.sum())
        x0, y0, x1, y1 = self.bbox_px
        return float((x1 - x0) * (y1 - y0))


@dataclass(frozen=True)
class PlanRequest:
    """Everything a backend may use to answer one planning call."""

    instruction: str
    """The user's sentence ("cut it into 8 equal slices")."""
    crop: np.ndarray
    """(h, w, 3) BGR, uint8: the image sent, the object's crop."""
    crop_mask: np.ndarray | None
    """(h, w) bool: the object's pixels in the crop, when the detector gives them."""
    metres_per_px: tuple[float, float]
    """Metres per crop pixel along x and y."""
    primitives: Mapping[str, str]
    """Primitive name -> description (the keyword must be one of the names)."""
    object_height: float
    """The object's top surface above the board, metres."""
    max_pairs: int
    """The most keypoint pairs an answer may hold (more is refused and repaired)."""
    messages: list[dict[str, Any]]
    """The rendered chat: system prompt, the sentence with the crop as a PNG data URL, repairs."""
    schema: dict[str, Any]
    """The answer's JSON schema ({"name", "strict", "schema"}, OpenAI response_format style)."""
    step: Step = "combined"
    """Which planning call this is (see Step)."""
    keyword: str | None = None
    """For step 'pairs': the primitive chosen by the 'keyword' call."""
    previous_errors: tuple[str, ...] = ()
    """Problems with the previous attempt's answer (empty on the first attempt)."""
    attempt: int = 1
    """1 for the first ask, 2 and on for repairs."""
    model: str | None = None
    """The model to ask (litellm's name, e.g. `openai/gpt-4o`); None for backends without one."""
    temperature: float = 0.0
    """Sampling temperature passed to the model."""
    timeout_s: float = 60.0
    """The longest the backend may take for this call, seconds."""
    task_name: str = ""
    """The task's name (for records and cassettes)."""
    line_width_mm: float = 0.0
    """Width of the icing line the task's tool draws (0: not an icing tool, or unknown)."""
    share_key: str | None = None
    """Set when answers may be shared (the answer cache is on): identical requests out at the
    same time then share one answer (keymps.eval.broker)."""
    objects: tuple[PlanObject, ...] = ()
    """Every object in the crop, in id order (empty: the crop holds one object, crop_mask)."""
    answer_mode: AnswerMode = "pairs"
    """The form of answer asked for: `pairs`, a named `design` or `either` (the schema allows
    exactly the same: a backend that reads no schema answers from this)."""

    @property
    def crop_size_px(self) -> tuple[int, int]:
        """(width, height) of the crop in pixels."""
        return int(self.crop.shape[1]), int(self.crop.shape[0])


@dataclass(frozen=True)
class BackendAnswer:
    """A backend's raw answer and what it cost: what `VlmBackend.complete` returns."""

    text: str
    """The answer's text: the planner's JSON (keymps parses and checks it)."""
    prompt_tokens: int | None = None
    """Tokens of the request, as the provider counted them; None when unknown."""
    completion_tokens: int | None = None
    """Tokens of the answer, as the provider counted them; None when unknown."""
    latency_s: float = 0.0
    """Wall-clock time of the call, seconds."""
    cost_usd: float | None = None
    """None where the price is unknown (e.g. a local model without a registered price)."""
    model: str | None = None
    """The model that answered, as the provider names it."""
    retries: tuple[str, ...] = ()
    """Failed tries before this answer (rate limits, server errors ...), one line each."""
    finish_reason: str | None = None
    """Why the answer ended before the model meant it to: "length" (its output token limit),
    "content_filter" or "tool_calls"; None for a natural end, or when the backend cannot tell."""
    refusal: str | None = None
    """The model's refusal message, when it refused instead of answering."""
    shared: bool = False
    """The answer to an identical request of another run, out at the same time: no call of its
    own (recorded as cached)."""


IntentFamily = Literal["cut", "icing"]
"""The work a plan does: cut, or icing."""
CutOrientation = Literal["vertical", "horizontal", "lengthwise", "crosswise"]
"""A direction of cuts in the object's own frame (PlanIntent.orientation)."""
EqualBy = Literal["area", "width"]
"""What equal pieces compare: their areas, or their widths across parallel cuts."""
PieceShape = Literal["square", "wedge", "strip", "round"]
"""The shape asked of pieces (PlanIntent.piece_shape): squares of a grid, wedges meeting at the
centre, strips between parallel cuts (along a long object), rounds across a long object."""
IntentSource = Literal["offline", "design", "answer", "sentence", "expect"]
"""Who stated an intent: the offline planner, a named design, a VLM answer, the task file."""
EQUAL_PARTS_TOLERANCE = 0.05
"""Appendix F's success criterion stated as a number: each of N pieces within 5 % of the
object's area / N (or, by width, of its extent / N)."""


@dataclass(frozen=True)
class PlanIntent:
    """What a plan claims to achieve on one object, stated as data (docs/outcome.md).

    Every field is optional: None (or False) states nothing, and the outcome stage checks only
    what is stated, beside the checks every plan gets (a cut that misses the food or stops short
    of its edge, a deposit off the top surface, deposits that merge). Lengths are millimetres
    on the board; counts are per object.
    """

    family: IntentFamily | None = None
    """"cut" or "icing": the work the plan does."""
    design: str | None = None
    """The named design it comes from (keymps.designs.grammar.DESIGNS: equal, parallel, width,
    middle, tips, dot, dots_ring, rings, ...), when one."""
    pieces: int | None = None
    """How many pieces the cuts leave (fragments under 1 % of the object's area are crumbs)."""
    equal: float | None = None
    """The pieces are equal within this fraction of an equal share: 0.05 is Appendix F's
    criterion (every piece within 5 % of the object's area / pieces)."""
    equal_by: EqualBy | None = None
    """What `equal` compares: "area", or "width" (each piece's extent across parallel cuts);
    None: width on an elongated object, area on a round or square one."""
    slice_width_mm: float | None = None
    """Slices this wide (mm, across the cuts), from one end of the object."""
    object_length_mm: float | None = None
    """The object's length as the user states it (mm): slice widths scale by the measured
    length over this one."""
    orientation: CutOrientation | None = None
    """Direction of the cuts in the object's own frame: "vertical" / "horizontal" along the
    object's side nearest the image's vertical / horizontal (the image's own axes for a round
    object); "lengthwise" / "crosswise" along / across its long axis."""
    piece_shape: PieceShape | None = None
    """The pieces' shape ("3 strips", "8 wedges", "9 squares", "half-inch rounds"): "strip",
    pieces between parallel cuts (along a long object's length); "wedge", cuts whose lines
    meet at the object's centre; "square", every piece's sides within 1.25:1; "round", cuts
    across a long object."""
    edge_distance_mm: float | None = None
    """Icing: how far in from the object's edge (mm, board) the outer ring of dots or icing
    line runs, measured to the dots' centres or the line's centreline ("1 inch from the
    edge")."""
    dots: int | None = None
    """Icing dots on the object, every ring of dots together."""
    rings: int | None = None
    """Closed icing lines around the object (concentric rings)."""
    digits: str | None = None
    """Digits drawn in seven-segment icing strokes."""
    object_id: int | None = None
    """The object it is for (DetectedObject.id); None: the plan's one object, or each."""
    source: IntentSource | None = None
    """Who stated it: the offline planner's reading ("offline"), a named design ("design"), a
    VLM answer's `intent` field ("answer"), the instruction itself as the offline grammar reads
    it, held against a VLM's plan ("sentence"), or the task file's `expect:` block ("expect")."""

    def describe(self) -> str:
        """What it states, in words.

        Returns:
            One phrase: '3 pieces, equal within 5 %, cut vertically'.
        """
        parts: list[str] = []
        if self.pieces is not None:
            parts.append(f"{self.pieces} piece" + ("" if self.pieces == 1 else "s"))
        if self.equal is not None:
            by = f" {self.equal_by}" if self.equal_by else ""  # "equal width within 5 %"
            parts.append(f"equal{by} within {100 * self.equal:g} %")
        if self.slice_width_mm is not None:
            parts.append(f"slices {self.slice_width_mm / 10:g} cm wide")
        if self.object_length_mm is not None:
            parts.append(f"of an object {self.object_length_mm / 10:g} cm long")
        if self.orientation is not None:
            parts.append(f"cut {self.orientation}" + ("ly" if self.orientation[-1] == "l" else ""))
        if self.piece_shape is not None:
            parts.append(f"{self.piece_shape} pieces")
        if self.dots is not None:
            parts.append(f"{self.dots} dot" + ("" if self.dots == 1 else "s"))
        if self.rings is not None:
            parts.append(f"{self.rings} ring" + ("" if self.rings == 1 else "s"))
        if self.digits is not None:
            parts.append(f"the digits {self.digits!r}")
        if self.edge_distance_mm is not None:
            parts.append(f"{self.edge_distance_mm:.1f} mm in from the edge")
        if not parts and self.design is not None:
            parts.append(self.design.replace("_", " "))
        if not parts:
            parts.append(f"{self.family or 'work'} with no stated result")
        where = f" on object {self.object_id}" if self.object_id is not None else ""
        return ", ".join(parts) + where


@dataclass(frozen=True)
class Plan:
    """Which primitive, and which K keypoint pairs (Sec. IV-B/C): the `plan` stage's result."""

    keyword: str
    """The chosen primitive's name (one of the task's primitives)."""
    pairs_crop_px: np.ndarray
    """(K, 2, 2): K pairs of (start, end) points in crop pixels."""
    pairs_px: np.ndarray
    """(K, 2, 2): the same pairs in full-image pixels."""
    backend: str
    """The planner backend that answered (offline, litellm, replay ...)."""
    model: str | None = None
    """The model asked; None for the offline planner."""
    rationale: str = ""
    """The backend's own explanation of its plan, if it gave one."""
    calls: tuple[VlmCall, ...] = ()
    """Every exchange with the backend, repairs included, in order."""
    coordinates: str = "pixels"
    """How the backend wrote its points (pixels, xy_1000, yx_1000); pairs_* are pixels."""
    design: dict[str, Any] | None = None
    """The named design the backend answered with (keymps laid it out), else None."""
    image_sent_px: tuple[int, int] | None = None
    """(width, height) of the image sent when the crop was downscaled for the provider."""
    pair_objects: tuple[int, ...] = ()
    """Per pair, the id of the object it lies on (empty: every pair on the one object)."""
    intents: tuple[PlanIntent, ...] = ()
    """What the plan claims to achieve, per object (empty: it states nothing)."""

    @property
    def num_pairs(self) -> int:
        """K, the number of keypoint pairs."""
        return int(self.pairs_px.shape[0])


@dataclass(frozen=True)
class Segment:
    """One grounded keypoint pair: DMP start and goal in the board frame (metres)."""

    start: np.ndarray
    """(3,) the DMP's start y0 in the board frame, metres (height integrated, Appendix C)."""
    goal: np.ndarray
    """(3,) the DMP's goal g in the board frame, metres."""
    start_px: tuple[float, float]
    """(x, y) of the pair's start in full-image pixels."""
    goal_px: tuple[float, float]
    """(x, y) of the pair's end in full-image pixels."""
    object_id: int = 1
    """The object this pair works on (DetectedObject.id)."""


@dataclass(frozen=True)
class GroundedObject:
    """One object on the board in metres: what the motion must clear and the work stay on."""

    id: int
    """Its DetectedObject.id."""
    name: str | None
    """What the task calls it (scene.objects); None when unnamed."""
    height: float
    """Its top surface above the board, metres."""
    outline_m: np.ndarray
    """(N, 2) footprint polygon in the board frame, counter-clockwise."""

    @property
    def label(self) -> str:
        """'#2 banana' (or '#2' without a name)."""
        return f"#{self.id} {self.name}" if self.name else f"#{self.id}"


@dataclass(frozen=True)
class Grounding:
    """The plan in the board frame: the `ground` stage's result.

    The segments, and the heights the motion works at.
    """

    segments: tuple[Segment, ...]
    """K grounded keypoint pairs, in the plan's order."""
    object_height: float
    """The tallest object's height (every object's, with one object), metres."""
    workspace_size: tuple[float, float]
    """(width, height) of the board area the image spans (s_env), metres."""
    objects: tuple[GroundedObject, ...] = ()
    """Every object on the board (the ones without work too), in id order."""

    @property
    def segments_m(self) -> np.ndarray:
        """(K, 2, 3): each segment's start and goal in the board frame, metres."""
        return np.array([[s.start, s.goal] for s in self.segments], dtype=float).reshape(-1, 2, 3)


@dataclass(frozen=True)
class Piece:
    """A continuous part of the tool path that starts and ends at rest."""

    kind: PieceKind
    """`work` (a re-targeted primitive) or `travel` (a move between pieces)."""
    pair_index: int
    """Index of the keypoint pair this piece belongs to (travel moves lead to that pair)."""
    points: np.ndarray
    """(n, 3) tool-tip positions in the board frame, metres."""
    yaw: np.ndarray
    """(n,) tool yaw about the board's z axis, radians."""
    speed: float
    """Requested tool speed along the path, m/s."""
    object_id: int = 1
    """The object of the pair this piece belongs to."""
    pairs: tuple[int, ...] = ()
    """For a work piece, the keypoint pairs it pipes, in order: several when icing lines that
    meet are one continuous stroke (then `pair_index` is the first); empty: `pair_index` only."""

    @property
    def piped_pairs(self) -> tuple[int, ...]:
        """The keypoint pairs this piece works on (`pairs`, or `pair_index` alone)."""
        return self.pairs or (self.pair_index,)

    def pairs_label(self) -> str:
        """The pairs this piece works on, for messages.

        Returns:
            'pair 3', 'pairs 14-61' or 'pairs 1, 2, 5, 3': numbered from 1, as in plan.png.
        """
        numbers = [k + 1 for k in self.piped_pairs]
        if len(numbers) == 1:
            return f"pair {numbers[0]}"
        if numbers == list(range(numbers[0], numbers[0] + len(numbers))):
            return f"pairs {numbers[0]}-{numbers[-1]}"
        return "pairs " + ", ".join(str(n) for n in numbers)

    @property
    def length_m(self) -> float:
        """Length of the piece's polyline, metres."""
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


@dataclass(frozen=True)
class ToolPath:
    """The composed Cartesian path (Eq. 6): the `compose` stage's result.

    Travel moves and re-targeted primitives, in execution order.
    """

    pieces: tuple[Piece, ...]
    """The pieces in execution order, each starting where the one before it ended."""
    keyword: str
    """The primitive the work pieces were re-targeted from."""

    @property
    def points(self) -> np.ndarray:
        """(n, 3) every piece's points end to end, board frame, metres."""
        return np.concatenate([p.points for p in self.pieces], axis=0)


@dataclass(frozen=True)
class JointPath:
    """Inverse-kinematics solution of a ToolPath: the `solve` stage's result.

    One joint vector per path point.
    """

    pieces: tuple[np.ndarray, ...]
    """Per piece, (n, 6) joint angles in radians aligned with the piece's points."""
    joint_names: tuple[str, ...]
    """The arm's joint names, base to wrist (the columns of each piece)."""
    max_position_error_m: float
    """The largest distance between a solved pose's tool tip and its path point, metres."""
    max_rotation_error_rad: float
    """The largest angle between a solved pose's tool orientation and the one asked, radians."""


@dataclass(frozen=True)
class Trajectory:
    """A joint trajectory sampled at the controller rate: the `time` stage's result.

    Jerk-limited, within the arm's joint limits and the tool's speed limits.
    """

    t: np.ndarray
    """(n,) sample times, seconds from the start, 1 / rate_hz apart."""
    q: np.ndarray
    """(n, 6) joint angles, radians."""
    qd: np.ndarray
    """(n, 6) joint velocities, rad/s."""
    qdd: np.ndarray
    """(n, 6) joint accelerations, rad/s^2."""
    tool_xyz: np.ndarray
    """(n, 3) planned tool-tip positions in the board frame, metres."""
    piece_index: np.ndarray
    """(n,) index into ToolPath.pieces."""
    kind: np.ndarray
    """(n,) 'work' or 'travel'."""
    joint_names: tuple[str, ...]
    """The arm's joint names, base to wrist (the columns of q, qd, qdd)."""
    rate_hz: float
    """The controller rate the samples are spaced for, Hz (125 for CB3, 500 for e-Series)."""
    warnings: tuple[str, ...] = ()
    """What the timing noticed, e.g. a work piece the joints slowed far below work_speed."""

    @property
    def duration_s(self) -> float:
        """From the first sample to the last, seconds."""
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    @property
    def samples(self) -> int:
        """n, the number of samples."""
        return int(len(self.t))


@dataclass(frozen=True)
class ValidationReport:
    """The safety check's verdict, its problems (one line each) and its figures."""

    ok: bool
    """True when nothing was found: the trajectory may be executed."""
    problems: tuple[str, ...]
    """Every finding, one line each (empty when ok)."""
    figures: dict[str, float]
    """What was measured, by name with its unit (`min_tool_z_mm`,
    `max_deviation_from_tool_path_mm`, `max_joint_velocity_ratio` of the limit ...): run.json's
    `validation`."""


@dataclass(frozen=True)
class ValidatedTrajectory:
    """A Trajectory that passed keymps.robot.safety: the `check` stage's result.

    Executors accept only this type, through `keymps.plugin.require_validated`.
    """

    trajectory: Trajectory
    """The trajectory as checked, its arrays read-only."""
    report: ValidationReport
    """The check's verdict and figures."""


@dataclass(frozen=True)
class CutEffect:
    """One cut: where a knife's edge went through the food (board frame, metres)."""

    pair_index: int
    """The keypoint pair (0-based) whose work piece made it."""
    object_id: int
    """The object it cuts (DetectedObject.id)."""
    length_m: float
    """Length of the cut's line inside the food that the edge swept below the object's top."""
    depth_m: float
    """How far below the object's top the edge went (the object's height: down to the board)."""
    severed_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    """(m, 2, 2) the stretches of the cut's line the edge swept on the board inside the food:
    there the food is cut through. Predicted only (executors leave it empty)."""
    chord_m: float | None = None
    """The food's extent along the cut's line (edge to edge, where the cut runs): what a cut
    through the whole object sweeps. Predicted only."""
    swept_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    """(m, 2, 2) where the edge lay on the board, inside the food or beyond its measured
    outline (what an evaluation against the true outline cuts with). Predicted only."""

    @property
    def severed_length_m(self) -> float:
        """Metres of the cut's line cut through (the severed stretches' total length)."""
        return float(np.linalg.norm(self.severed_m[:, 1] - self.severed_m[:, 0], axis=1).sum())


@dataclass(frozen=True)
class PieceEffect:
    """One piece the cuts leave (fragments under 1 % of the object's area excluded)."""

    object_id: int
    """The object it is a piece of."""
    area_m2: float
    """Its area, square metres."""
    share: float
    """Its fraction of the object's area."""
    outline_m: np.ndarray
    """(n, 2) its outline in the board frame, metres."""


@dataclass(frozen=True)
class DepositEffect:
    """One icing deposit: a dot (a disc) or a line (a band of the tool's line width)."""

    kind: Literal["dot", "line"]
    """A dot where the nozzle stayed in place, else a line along its path."""
    pair_index: int
    """The keypoint pair (0-based) whose work piece piped it."""
    object_id: int
    """The object it lies on (0: none known)."""
    path_m: np.ndarray
    """(n, 2) board metres: the dot's centre (n = 1) or the line's centreline."""
    width_m: float
    """The disc's diameter or the band's width."""
    stroke: int
    """The stroke it is piped in: deposits joined end to end share one (0-based)."""
    on_top: bool
    """Whether it lies on the object's top surface (inside its footprint)."""
    pairs: tuple[int, ...] = ()
    """Every keypoint pair (0-based, in order) its work piece pipes: several where lines that
    meet are one continuous stroke (`pair_index` is the first); empty: `pair_index` only."""

    @property
    def piped_pairs(self) -> tuple[int, ...]:
        """The keypoint pairs it was piped from (`pairs`, or `pair_index` alone)."""
        return self.pairs or (self.pair_index,)


@dataclass(frozen=True)
class Effect:
    """What a motion does (predicted) or did (measured) to the food."""

    cuts: tuple[CutEffect, ...] = ()
    """One per work piece of a cutting tool, in plan order."""
    pieces: tuple[PieceEffect, ...] = ()
    """The pieces the cuts leave, object by object, largest first (predicted only)."""
    deposits: tuple[DepositEffect, ...] = ()
    """The icing, in plan order (a work piece that deposits nothing has none)."""
    strokes: int = 0
    """Icing strokes: connected chains of deposits."""
    loops: int = 0
    """Strokes that close on themselves (rings)."""


OutcomeVerdict = Literal["pass", "fail", "accepted"]
"""The outcome stage's verdict: pass, fail, or accepted (failed, executed on the expert's
--accept-outcome)."""


@dataclass(frozen=True)
class Outcome:
    """The outcome stage's result: the predicted effect held against the plan's intent."""

    verdict: OutcomeVerdict
    """pass; fail (the run stops before execute); accepted (failed, executed anyway on the
    expert's --accept-outcome)."""
    intents: tuple[PlanIntent, ...]
    """What was checked, per object (the plan's intents with the task's `expect:` applied;
    for a model's plan on one object, also the sentence's own reading, source "sentence")."""
    predicted: Effect
    """What the validated trajectory does to the food (keymps.outcome.predict)."""
    problems: tuple[str, ...]
    """One line each; empty when the verdict is pass."""
    tolerances: dict[str, float] = field(default_factory=dict)
    """The numbers the checks used (keymps.outcome.verdict.TOLERANCES, metres and fractions)."""
    measured: Effect | None = None
    """What the executor measured, when it measures (set after the execute stage)."""
    measured_problems: tuple[str, ...] = ()
    """Where the measured result falls short of the prediction (the run is then not ok)."""

    @property
    def ok(self) -> bool:
        """Whether the run goes on to execute: the verdict is pass or accepted."""
        return self.verdict != "fail"


@dataclass(frozen=True)
class ExecutionReport:
    """What an executor did: its verdict, message, the files it wrote and its figures."""

    executor: str
    """The executor's registered name (sim, file, ur-rtde ...)."""
    ok: bool
    """True when it did what it was asked (a simulated or exported run, a completed motion)."""
    message: str = ""
    """One line for the user: what it did, or why it stopped."""
    files: tuple[str, ...] = ()
    """Paths of the files it wrote (outcome.png, execution.mp4 ...)."""
    figures: dict[str, float] = field(default_factory=dict)
    """What it measured, by name with its unit (`max_tracking_error_mm`, `min_tool_z_mm` ...);
    run.json keeps them."""
    dry_run: bool | None = None
    """For an executor that drives a real robot: True when it only checked (no --confirm),
    False when it was allowed to move; None for the others (simulation, file export)."""
    measured: Effect | None = None
    """What an executor that measures the physical result found (the cuts it made), in the
    form the outcome stage predicts; None when it measures nothing."""


STAGES: tuple[str, ...] = (
    "image",
    "detect",
    "plan",
    "ground",
    "compose",
    "solve",
    "time",
    "check",
    "outcome",
    "execute",
)
"""The stages of a run in execution order: the names of run.json's timings_s, of
`keymps.run.StageResults`' fields and of `keymps_stage_done`'s stage."""
