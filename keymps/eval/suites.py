"""Benchmark suite files (benchmarks/suites/*.yaml): pydantic models and located loading.

A suite lists cases; each case names a synthetic scene object, how its scene is randomized, the
sentence, and (where the sentence determines one) a ground-truth cut design stated geometrically.
See docs/benchmarks.md for the format and the reasoning behind every ground truth.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from keymps.bundled import bundled_dir
from keymps.config.yaml_positions import PositionedYaml, YamlSyntaxError, load_yaml_with_positions
from keymps.errors import KeympsError

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Fraction = Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)]
SuiteKind = Literal["metric", "gallery", "equal_parts"]


class SuiteError(KeympsError):
    """A suite file that cannot be read or validated (one located line per problem)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SceneSettings(_Strict):
    """How a case's synthetic scene is made; each repeat r renders seed + r."""

    seed: int = Field(default=0, ge=0)
    length: PositiveFloat | None = None
    """Nominal length of the object, metres (the kind's default when omitted)."""
    width: PositiveFloat | None = None
    height: PositiveFloat | None = None
    jitter: Annotated[float, Field(ge=0, le=0.2)] = 0.04
    """Dimension randomization: length, width and height each scaled by U(1 - j, 1 + j)."""
    rotation: Annotated[float, Field(ge=-180, le=180)] | None = None
    """Degrees of the object's length axis from the board's x axis (random when omitted)."""


class ParallelCuts(_Strict):
    """Straight cuts across the object, perpendicular to `along`, spanning the whole object.

    `along` is the direction in which the slices follow one another: x (cuts vertical in the
    image), y (cuts horizontal) or the object's long axis. Positions are measured from the low
    end (the left end, or the bottom of the image for y). Give exactly one of parts, fractions,
    spacing.
    """

    pattern: Literal["parallel"]
    along: Literal["x", "y", "long"]
    parts: Annotated[int, Field(ge=2, le=100)] | None = None
    """Equal parts: parts - 1 cuts at equal spacing."""
    fractions: list[Fraction] | None = None
    """Cut positions as fractions of the object's extent along `along`."""
    spacing: PositiveFloat | None = None
    """Metres between cuts, from the low end."""
    count: Annotated[int, Field(ge=1, le=100)] | None = None
    """With spacing: exactly this many cuts (else every cut leaving an end piece of at least
    half the spacing)."""

    @model_validator(mode="after")
    def _one_rule(self) -> ParallelCuts:
        given = [k for k in ("parts", "fractions", "spacing") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of parts, fractions, spacing")
        if self.count is not None and self.spacing is None:
            raise ValueError("count goes with spacing")
        return self


class TipCuts(_Strict):
    """Two cuts, `inset` metres in from each end of the object's body along `along`; on an end
    with a cap or stem beyond the body (the scene's `body_m`), `cap_inset` in from the body's
    end (the cap comes off at its base)."""

    pattern: Literal["tips"]
    along: Literal["x", "y", "long"] = "long"
    inset: PositiveFloat
    cap_inset: PositiveFloat | None = None


class RadialCuts(_Strict):
    """`parts` equal wedges around the object's centre: parts/2 full cuts through the centre
    for an even count, `parts` cuts from the centre outwards for an odd one."""

    pattern: Literal["radial"]
    parts: Annotated[int, Field(ge=2, le=64)]
    first_deg: Annotated[float, Field(ge=-360, le=360)] = -90.0
    """Direction of the first cut in the board frame (-90: from the top of the image down);
    the next ones follow counter-clockwise."""


class DotsRing(_Strict):
    """`count` icing dots evenly spaced on a ring around a round object's centre, `fraction`
    of its radius out, the first at `first_deg` (90: at the top of the image, 12 o'clock)."""

    pattern: Literal["dots_ring"]
    count: Annotated[int, Field(ge=1, le=200)]
    fraction: Annotated[float, Field(gt=0, lt=1)] = 0.78
    first_deg: Annotated[float, Field(ge=-360, le=360)] = 90.0


CutDesign = Annotated[
    ParallelCuts | TipCuts | RadialCuts | DotsRing, Field(discriminator="pattern")
]


class GroundTruth(_Strict):
    primitive: str
    """The primitive the ground-truth cuts are made with (scaled into 3D by the object's height)."""
    cuts: CutDesign
    overshoot: Annotated[float, Field(ge=0, le=0.05)] = 0.005
    """How far each cut reaches past the object's edge, metres (the blade must clear it)."""


class Case(_Strict):
    id: str = Field(min_length=1, max_length=40, pattern=r"^[A-Za-z0-9_.-]+$")
    object: str | list[str]
    """A keymps.scenes.render object kind, or several (placed left to right)."""
    instruction: str = Field(min_length=1, max_length=2000)
    scene: SceneSettings = SceneSettings()
    primitives: list[str] | None = None
    """Primitives offered to the planner (the suite's when omitted)."""
    ground_truth: GroundTruth | None = None
    ground_truths: list[GroundTruth | None] | None = None
    """Several objects: one ground truth per object, left to right (null: nothing is done to
    that object). Scored with D per object and over all of them."""
    task: dict[str, Any] = Field(default_factory=dict)
    """Task-file sections merged over the suite's (e.g. height, motion, robot)."""

    @field_validator("id", mode="before")
    @classmethod
    def _id_text(cls, value: Any) -> Any:
        return str(value) if isinstance(value, int) else value

    @field_validator("object")
    @classmethod
    def _known_objects(cls, value: str | list[str]) -> str | list[str]:
        from keymps.scenes.render import check_kinds

        try:
            names = check_kinds([value] if isinstance(value, str) else value, where="object")
        except KeympsError as error:
            raise ValueError(str(error).removeprefix("object: ")) from None
        return names[0] if isinstance(value, str) else names

    @property
    def kinds(self) -> list[str]:
        return [self.object] if isinstance(self.object, str) else list(self.object)

    @property
    def has_truth(self) -> bool:
        return self.ground_truth is not None or bool(self.ground_truths)

    @model_validator(mode="after")
    def _one_truth_per_object(self) -> Case:
        if self.ground_truths is None:
            return self
        if self.ground_truth is not None:
            raise ValueError("give ground_truth (one object) or ground_truths (several), not both")
        if len(self.ground_truths) != len(self.kinds):
            raise ValueError(
                f"ground_truths has {len(self.ground_truths)} entries for "
                f"{len(self.kinds)} objects (one per object, left to right; null for none)"
            )
        return self


class Suite(_Strict):
    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    kind: SuiteKind = "metric"
    """metric: D against the ground truth; gallery: images only; equal_parts: area check."""
    board: tuple[PositiveFloat, PositiveFloat] = (0.30, 0.18)
    """Workspace (width along x, height along y) in metres; the scene image spans it."""
    px_per_m: Annotated[float, Field(ge=500, le=10_000)] = 2000.0
    repeats: Annotated[int, Field(ge=1, le=1000)] = 1
    """Runs per case and method (each on the case's scene seed + repeat index)."""
    parts: Annotated[int, Field(ge=2, le=64)] | None = None
    """equal_parts: the number of equal pieces asked for."""
    tolerance: Annotated[float, Field(gt=0, lt=1)] = 0.05
    """equal_parts: each piece's area within this fraction of the object's area / parts."""
    primitives: list[str] = Field(min_length=1)
    task: dict[str, Any] = Field(default_factory=dict)
    """Task-file sections every case's task starts from (height, motion, robot, detector ...)."""
    cases: list[Case] = Field(min_length=1)
    path: Path | None = Field(default=None, exclude=True)

    @model_validator(mode="after")
    def _consistent(self) -> Suite:
        ids = [c.id for c in self.cases]
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ValueError(f"duplicate case ids: {', '.join(duplicates)}")
        if self.kind == "equal_parts" and self.parts is None:
            raise ValueError("an equal_parts suite needs parts")
        if self.kind == "metric":
            missing = [c.id for c in self.cases if not c.has_truth]
            if len(missing) == len(self.cases):
                raise ValueError("a metric suite needs a ground_truth in at least one case")
        return self

    def case(self, case_id: str) -> Case:
        for case in self.cases:
            if case.id == case_id:
                return case
        raise SuiteError(f"suite {self.name}: no case {case_id!r} (cases: {self.case_ids()})")

    def case_ids(self) -> str:
        return ", ".join(c.id for c in self.cases)

    @property
    def folder(self) -> Path:
        return self.path.parent if self.path else Path.cwd()


def _field_name(path: tuple[Any, ...]) -> str:
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else (("." if text else "") + str(part))
    return text or "(suite)"


def _problems(source: str, parsed: PositionedYaml, error: ValidationError) -> list[str]:
    lines = []
    for item in error.errors(include_url=False):
        # pydantic inserts union tags and validator names that are not keys of the YAML
        path = tuple(
            p
            for p in item["loc"]
            if isinstance(p, int)
            or not (p in ("parallel", "tips", "radial", "dots_ring") or "[" in p)
        )
        if path and isinstance(path[-1], str) and path[-1] in ("str", "list"):
            path = path[:-1]
        line, column = parsed.locate(path, at_key=item["type"] == "extra_forbidden")
        message = {"extra_forbidden": "unknown key", "missing": "field required"}.get(
            item["type"], item["msg"].removeprefix("Value error, ")
        )
        lines.append(f"{source}:{line}:{column}: {_field_name(path)}: {' '.join(message.split())}")
    return lines


def parse_suite(text: str, source: str = "<suite>", path: Path | None = None) -> Suite:
    """Validate suite YAML text; SuiteError with one file:line:col line per problem."""
    try:
        parsed = load_yaml_with_positions(text)
    except YamlSyntaxError as error:
        line, column = error.location
        raise SuiteError(f"{source}:{line}:{column}: invalid YAML: {error}") from None
    if not isinstance(parsed.data, dict):
        raise SuiteError(f"{source}:1:1: expected a mapping with name, primitives and cases")
    if "instruction" in parsed.data and "cases" not in parsed.data:
        raise SuiteError(
            f"{source}:1:1: a task file (it has an instruction and no cases), not an eval suite: "
            f"run it with `keymps run {source}`, or make it a case of a suite (docs/benchmarks.md)"
        )
    try:
        suite = Suite.model_validate({**parsed.data, "path": path})
    except ValidationError as error:
        raise SuiteError("\n".join(_problems(source, parsed, error))) from None
    _check_tasks(suite, source, parsed)
    return suite


def _check_tasks(suite: Suite, source: str, parsed: PositionedYaml) -> None:
    """Every case's task (suite task + case task) must be a valid task file section set."""
    from keymps.config.task import Task
    from keymps.eval.tasks import case_task_data

    for index, case in enumerate(suite.cases):
        data = case_task_data(suite, case, seed=case.scene.seed)
        try:
            Task.model_validate(data)
        except ValidationError as error:
            item = error.errors(include_url=False)[0]
            loc = tuple(item["loc"])
            in_case = bool(case.task) and loc[:1] and loc[0] in case.task
            yaml_path: tuple[Any, ...] = (
                ("cases", index, "task", *loc) if in_case else ("task", *loc)
            )
            line, column = parsed.locate(yaml_path)
            message = item["msg"].removeprefix("Value error, ")
            raise SuiteError(
                f"{source}:{line}:{column}: case {case.id}: task.{_field_name(loc)}: {message}"
            ) from None


def load_suite(path: str | Path) -> Suite:
    """Read and validate a suite file; a bare name looks in benchmarks/suites/."""
    path = resolve_suite_path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise SuiteError(f"{path}: cannot read suite: {error.strerror}") from None
    except UnicodeDecodeError:
        raise SuiteError(f"{path}: not a UTF-8 text file") from None
    return parse_suite(text, source=str(path), path=path.resolve())


SUITES_DIR = bundled_dir("suites")


def resolve_suite_path(path: str | Path) -> Path:
    """A suite file path, or the name of a shipped suite (cutting_sim -> its YAML)."""
    candidate = Path(path)
    if candidate.is_file():
        return candidate
    for folder in (Path.cwd() / "benchmarks" / "suites", SUITES_DIR):
        named = folder / f"{candidate.stem if candidate.suffix else candidate.name}.yaml"
        if named.is_file():
            return named
    shipped = sorted(p.stem for p in SUITES_DIR.glob("*.yaml"))
    raise SuiteError(
        f"{path}: suite file not found (shipped suites: {', '.join(shipped) or 'none'})"
    )
