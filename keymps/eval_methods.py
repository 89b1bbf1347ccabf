"""The methods `keymps eval` compares (the paper's Experiments 1-2 and Appendix F).

- keymps: the full pipeline (detector, VLM keyword + 2D keypoint pairs, primitive, robot checks).
- vlm-keypoint: the same with every primitive's DMP weights set to zero (straight pieces).
- keymps-text: no image; the VLM reads the object's name and shape in text and answers pairs
  in the coordinates of the (unseen) crop; the rest is KeyMPs.
- vlm-keyword: the VLM picks the primitive and writes 3D keypoints in board metres directly.
- vlm-dmp / vlm-mdmp: the VLM writes one / several DMPs' parameters (start, goal, weights).

keymps and vlm-keypoint run through keymps.run_task (any backend, offline included). The others
need a VLM; they detect the object like KeyMPs, ask with their own prompt (prompts/methods/),
and are scored on the motion they generate (no robot checks, as in the paper).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from keymps.errors import KeympsError

PROMPTS_DIR = Path(__file__).resolve().parent.parent / "prompts" / "methods"


@dataclass(frozen=True)
class MethodOutput:
    """What one method generated for one case."""

    work_pieces: tuple[np.ndarray, ...]
    """The generated work motion (cuts, strokes) as 3D points, board metres; no travel."""
    lines_m: np.ndarray
    """(K, 2, 2) where each generated piece starts and ends, seen from above (board metres)."""
    keyword: str | None
    calls: tuple[dict[str, Any], ...] = ()
    """Per VLM call: latency_s, cost_usd, prompt_tokens, completion_tokens."""
    images: dict[str, str] = field(default_factory=dict)
    """plan / outcome -> PNG path, when written."""


@dataclass(frozen=True)
class MethodContext:
    """Everything a method needs to run one case once."""

    task_path: Path
    """The case's task file (written by the runner)."""
    folder: Path
    """This run's folder."""
    backend: str
    model: str | None
    api_base: str | None


MethodRunner = Callable[[MethodContext], MethodOutput]


class MethodNeedsVlm(KeympsError):
    """A method that only a VLM can run was asked to run offline."""


# --------------------------------------------------------------------------- pipeline methods


def _run_pipeline(context: MethodContext) -> MethodOutput:
    from keymps.engine import run_task

    results: dict[str, Any] = {}

    def keep(stage: str, seconds: float, result: Any) -> None:
        results[stage] = result

    overrides: dict[str, Any] = {"backend": context.backend}
    if context.model:
        overrides["model"] = context.model
    if context.api_base:
        overrides["api_base"] = context.api_base
    try:
        run_task(
            context.task_path,
            on_stage=keep,
            out=context.folder,
            rerun="off",
            quiet=True,
            **overrides,
        )
    except KeympsError as error:
        raise PartialRunError(str(error), results) from None
    return _pipeline_output(results, context.folder)


class PartialRunError(KeympsError):
    """A pipeline run that stopped at a stage; the results of the stages before it are kept."""

    def __init__(self, message: str, results: dict[str, Any]):
        super().__init__(message)
        self.results = results


def _pipeline_output(results: dict[str, Any], folder: Path) -> MethodOutput:
    plan = results.get("plan")
    grounding = results.get("ground")
    tool_path = results.get("compose")
    pieces = tuple(p.points for p in tool_path.pieces if p.kind == "work") if tool_path else ()
    lines = grounding.segments_m[:, :, :2] if grounding is not None else np.zeros((0, 2, 2))
    calls = tuple(_call_summary(c) for c in plan.calls) if plan is not None else ()
    images = {
        name: str(folder / f"{name}.png")
        for name in ("plan", "outcome")
        if (folder / f"{name}.png").is_file()
    }
    return MethodOutput(
        work_pieces=pieces,
        lines_m=np.asarray(lines, dtype=float),
        keyword=plan.keyword if plan is not None else None,
        calls=calls,
        images=images,
    )


def partial_output(error: PartialRunError, folder: Path) -> MethodOutput:
    """What a stopped pipeline run had produced (e.g. a plan refused later by the safety check)."""
    return _pipeline_output(error.results, folder)


def _call_summary(call: Any) -> dict[str, Any]:
    return {
        "latency_s": float(getattr(call, "latency_s", 0.0) or 0.0),
        "cost_usd": getattr(call, "cost_usd", None),
        "prompt_tokens": getattr(call, "prompt_tokens", None),
        "completion_tokens": getattr(call, "completion_tokens", None),
        "cached": bool(getattr(call, "cached", False)),
    }


def zero_weight_primitives(names: list[str], search_dirs: list[Path], folder: Path) -> None:
    """Write copies of the primitives with every DMP weight zero (VLM-Keypoint's dictionary)."""
    from keymps.primitives import load_primitives, save_primitive

    folder.mkdir(parents=True, exist_ok=True)
    for name, primitive in load_primitives(names, search_dirs).items():
        flat = replace(primitive.dmp, weights=np.zeros_like(primitive.dmp.weights))
        save_primitive(
            replace(primitive, dmp=flat, demo=None, fit_rmse=0.0), folder / f"{name}.yaml"
        )


# --------------------------------------------------------------------------- direct VLM methods


_PLACEHOLDER = re.compile(r"\{\{\s*([a-z_]+)\s*\}\}")


def render_prompt(path: Path, values: dict[str, str]) -> str:
    """A method prompt with its {{placeholders}} filled; an unknown one names file and line."""
    text = path.read_text(encoding="utf-8")
    for number, line in enumerate(text.splitlines(), start=1):
        for match in _PLACEHOLDER.finditer(line):
            if match.group(1) not in values:
                raise KeympsError(
                    f"{path}:{number}: unknown placeholder {{{{{match.group(1)}}}}} "
                    f"(known: {', '.join(sorted(values))})"
                )
    return _PLACEHOLDER.sub(lambda m: values[m.group(1)], text)


@dataclass(frozen=True)
class _Seen:
    """The case as the direct methods see it: the task, the scene, the detection, the crop."""

    task: Any
    scene: Any
    detection: Any
    crop_box_m: tuple[float, float, float, float]
    """Board metres covered by the crop: x_min, y_min, x_max, y_max."""
    metres_per_px: tuple[float, float]
    primitives: dict[str, Any]


def _look(context: MethodContext) -> _Seen:
    from keymps.geometry import ImageFrame
    from keymps.planning import crop_metres_per_px
    from keymps.plugins import create_component
    from keymps.primitives import default_search_dirs, load_primitives
    from keymps.run import Run
    from keymps.task import load_task

    task = load_task(context.task_path)
    run = Run(task=task, folder=context.folder)
    source = create_component("image_source", task.scene.source, task.scene.source_options)
    scene = source.load(run)
    detector = create_component("detector", task.detector.name, task.detector.options)
    detection = detector.detect(scene)
    frame = ImageFrame.from_task(task, scene.size_px)
    x0, y0 = detection.crop_origin_px
    w, h = detection.crop_size_px
    corners = frame.to_board(np.array([[x0, y0], [x0 + w, y0 + h]], dtype=float))
    box = (
        float(corners[:, 0].min()),
        float(corners[:, 1].min()),
        float(corners[:, 0].max()),
        float(corners[:, 1].max()),
    )
    primitives = load_primitives(task.primitives, default_search_dirs(task.folder))
    return _Seen(
        task=task,
        scene=scene,
        detection=detection,
        crop_box_m=box,
        metres_per_px=crop_metres_per_px(task, detection, scene),
        primitives=primitives,
    )


def _shape_words(kind: str) -> str:
    from keymps.scenes import KINDS

    spec = KINDS[kind]
    family = spec.shape.family
    if family == "disk":
        return "round (a disc seen from above)"
    if family == "ring":
        return "round with a hole in the middle (a ring seen from above)"
    if family == "rrect":
        if abs(spec.length - spec.width) < 0.01:
            return "square (seen from above)"
        return "rectangular, longer than wide (seen from above)"
    return "elongated, lying along the image's x axis (seen from above)"


def _values(seen: _Seen, context: MethodContext) -> dict[str, str]:
    from keymps.scenes import KINDS

    task = seen.task
    options = task.scene.source_options
    kinds = options["object"] if isinstance(options["object"], list) else [options["object"]]
    mx, my = (1000 * m for m in seen.metres_per_px)
    x0, y0, x1, y1 = seen.crop_box_m
    w, h = seen.detection.crop_size_px
    return {
        "instruction": task.instruction,
        "object": " and ".join(KINDS[k].description for k in kinds),
        "shape": _shape_words(kinds[0]),
        "primitives": "\n".join(f"- {n}: {p.description}" for n, p in seen.primitives.items()),
        "primitive_names": ", ".join(seen.primitives),
        "crop_width": str(w),
        "crop_height": str(h),
        "mm_per_pixel": f"{mx:.3g}" if abs(mx - my) <= 0.01 * mx else f"{mx:.3g} x {my:.3g}",
        "object_height_cm": f"{100 * task.scene.object_height:.3g}",
        "object_height_m": f"{task.scene.object_height:.4f}",
        "x_min": f"{x0:.4f}",
        "x_max": f"{x1:.4f}",
        "y_min": f"{y0:.4f}",
        "y_max": f"{y1:.4f}",
        "max_pairs": str(task.planner.max_pairs),
    }


def _ask(
    context: MethodContext,
    seen: _Seen,
    method: str,
    with_image: bool,
    schema: dict[str, Any],
    validate: Callable[[Any], tuple[Any, list[str]]],
) -> tuple[Any, list[dict[str, Any]]]:
    """Ask the VLM with the method's prompt, repairing invalid answers; (answer, call records)."""
    from keymps.plan_answer import extract_json
    from keymps.plan_prompt import png_data_url
    from keymps.planning import BackendAnswer, PlanRequest, backend_options
    from keymps.plugins import create_component

    task = seen.task
    if context.model:
        task = task.model_copy(
            update={"planner": task.planner.model_copy(update={"model": context.model})}
        )
    if context.api_base:
        task = task.model_copy(
            update={"planner": task.planner.model_copy(update={"api_base": context.api_base})}
        )
    backend = create_component("vlm_backend", context.backend, backend_options(task))
    values = _values(seen, context)
    system = render_prompt(PROMPTS_DIR / f"{method}.md", values)
    user_text = f"Instruction: {task.instruction}"
    content: Any = user_text
    if with_image:
        content = [
            {"type": "text", "text": user_text},
            {"type": "image_url", "image_url": {"url": png_data_url(seen.detection.crop)}},
        ]
    messages: list[dict[str, Any]] = [
        {"role": "system", "content": system},
        {"role": "user", "content": content},
    ]
    calls: list[dict[str, Any]] = []
    vlm_folder = context.folder / "vlm"
    vlm_folder.mkdir(parents=True, exist_ok=True)
    problems: list[str] = []
    for attempt in range(1, task.planner.attempts + 1):
        request = PlanRequest(
            instruction=task.instruction,
            crop=seen.detection.crop,
            crop_mask=None,
            metres_per_px=seen.metres_per_px,
            primitives={n: p.description for n, p in seen.primitives.items()},
            object_height=task.scene.object_height,
            max_pairs=task.planner.max_pairs,
            messages=list(messages),
            schema=schema,
            attempt=attempt,
            model=task.planner.model,
            temperature=task.planner.temperature,
            timeout_s=task.planner.timeout_s,
            task_name=task.name,
        )
        answer: BackendAnswer = backend.complete(request)
        calls.append(
            {
                "latency_s": answer.latency_s,
                "cost_usd": answer.cost_usd,
                "prompt_tokens": answer.prompt_tokens,
                "completion_tokens": answer.completion_tokens,
                "cached": False,
            }
        )
        try:
            parsed, problems = validate(extract_json(answer.text))
        except ValueError as error:
            parsed, problems = None, [f"the answer is not a JSON object ({error})"]
        record = {
            "method": method,
            "attempt": attempt,
            "messages": _without_images(messages),
            "answer": answer.text,
            "problems": problems,
        }
        (vlm_folder / f"{method}-attempt{attempt}.json").write_text(
            json.dumps(record, indent=2), encoding="utf-8"
        )
        if parsed is not None:
            return parsed, calls
        messages += [
            {"role": "assistant", "content": answer.text},
            {
                "role": "user",
                "content": "Your answer was invalid:\n"
                + "\n".join(f"- {p}" for p in problems)
                + "\nAnswer again with the corrected JSON object only.",
            },
        ]
    raise KeympsError(
        f"{method}: no valid answer after {task.planner.attempts} attempts: {'; '.join(problems)}"
    )


def _without_images(messages: list[dict[str, Any]]) -> list[Any]:
    cleaned = []
    for message in messages:
        content = message["content"]
        if isinstance(content, list):
            content = [
                {"type": "image_url", "image_url": {"url": "<crop.png>"}}
                if part.get("type") == "image_url"
                else part
                for part in content
            ]
        cleaned.append({**message, "content": content})
    return cleaned


def _number_list(value: Any, length: int, what: str) -> tuple[list[float] | None, str | None]:
    if (
        not isinstance(value, list)
        or len(value) != length
        or not all(isinstance(v, (int, float)) and np.isfinite(v) for v in value)
    ):
        return None, f"{what} must be a list of {length} finite numbers"
    return [float(v) for v in value], None


def _schema(name: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": name,
        "strict": True,
        "schema": {
            "type": "object",
            "properties": properties,
            "required": list(properties),
            "additionalProperties": False,
        },
    }


_NUMBERS = {"type": "array", "items": {"type": "number"}}
_RATIONALE = {"type": "string", "description": "one or two sentences"}


def _compose(seen: _Seen, keyword: str, starts: np.ndarray, goals: np.ndarray) -> MethodOutput:
    from keymps.motion import compose_tool_path
    from keymps.robot import RobotModel
    from keymps.stages import Segment

    task = seen.task
    segments = [
        Segment(start=s, goal=g, start_px=(0.0, 0.0), goal_px=(0.0, 0.0))
        for s, g in zip(starts, goals, strict=True)
    ]
    robot = RobotModel.from_task(task)
    path = compose_tool_path(
        segments,
        seen.primitives[keyword],
        object_top=task.scene.object_height,
        clearance=task.motion.clearance,
        work_speed=task.motion.work_speed,
        travel_speed=task.motion.travel_speed,
        yaw_mode=robot.tool.yaw,
        home=robot.home_tool_position(),
    )
    pieces = tuple(p.points for p in path.pieces if p.kind == "work")
    lines = np.stack([starts[:, :2], goals[:, :2]], axis=1)
    return MethodOutput(work_pieces=pieces, lines_m=lines, keyword=keyword)


def _keymps_text(context: MethodContext) -> MethodOutput:
    """KeyMPs-text: the pairs from text only, then Appendix B/C grounding and the primitive."""
    from keymps.geometry import ImageFrame, height_pair
    from keymps.plan_answer import answer_schema, parse_and_validate

    seen = _look(context)
    keywords = list(seen.primitives)
    size = seen.detection.crop_size_px
    max_pairs = seen.task.planner.max_pairs

    def validate(data: Any) -> tuple[Any, list[str]]:
        return parse_and_validate(json.dumps(data), "combined", keywords, size, max_pairs)

    answer, calls = _ask(
        context,
        seen,
        "keymps-text",
        False,
        answer_schema("combined", keywords, max_pairs),
        validate,
    )
    pairs_px = np.asarray(answer.pairs, dtype=float).reshape(-1, 2, 2)
    pairs_px = pairs_px + np.asarray(seen.detection.crop_origin_px, dtype=float)
    frame = ImageFrame.from_task(seen.task, seen.scene.size_px)
    board = frame.to_board(pairs_px.reshape(-1, 2)).reshape(-1, 2, 2)
    z_start, z_goal = height_pair(seen.task)
    starts = np.column_stack([board[:, 0], np.full(len(board), z_start)])
    goals = np.column_stack([board[:, 1], np.full(len(board), z_goal)])
    output = _compose(seen, answer.keyword, starts, goals)
    return replace(output, calls=tuple(calls))


def _vlm_keyword(context: MethodContext) -> MethodOutput:
    """VLM-Keyword: the primitive is chosen, but the 3D keypoints come from the VLM directly."""
    seen = _look(context)
    keywords = list(seen.primitives)
    point3 = {**_NUMBERS, "description": "[x, y, z] in metres, board frame"}
    schema = _schema(
        "keymps_vlm_keyword_answer",
        {
            "keyword": {"type": "string", "enum": keywords},
            "pairs": {"type": "array", "items": {"type": "array", "items": point3}},
            "rationale": _RATIONALE,
        },
    )

    def validate(data: Any) -> tuple[Any, list[str]]:
        problems = []
        keyword = data.get("keyword") if isinstance(data, dict) else None
        if keyword not in keywords:
            problems.append(f"keyword must be one of {', '.join(keywords)}")
        pairs = data.get("pairs") if isinstance(data, dict) else None
        points = []
        if not isinstance(pairs, list) or not pairs:
            problems.append("pairs must be a non-empty list of [[x, y, z], [x, y, z]]")
        else:
            for index, pair in enumerate(pairs):
                if not isinstance(pair, list) or len(pair) != 2:
                    problems.append(f"pairs[{index}] must be [[x, y, z], [x, y, z]]")
                    continue
                for end in pair:
                    value, problem = _number_list(end, 3, f"pairs[{index}] points")
                    if problem:
                        problems.append(problem)
                    else:
                        points.append(value)
        if problems:
            return None, problems
        return (keyword, np.asarray(points, dtype=float).reshape(-1, 2, 3)), []

    (keyword, pairs), calls = _ask(context, seen, "vlm-keyword", True, schema, validate)
    output = _compose(seen, keyword, pairs[:, 0], pairs[:, 1])
    return replace(output, calls=tuple(calls))


def _dmp_from(entry: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    start = np.asarray(entry["start"], dtype=float)
    goal = np.asarray(entry["goal"], dtype=float)
    weights = np.asarray(entry["weights"], dtype=float).reshape(-1, 3)
    return start, goal, weights


def _validate_dmp(entry: Any, where: str) -> list[str]:
    if not isinstance(entry, dict):
        return [f"{where} must be an object with start, goal, weights"]
    problems = []
    for key in ("start", "goal"):
        _, problem = _number_list(entry.get(key), 3, f"{where}.{key}")
        if problem:
            problems.append(problem)
    weights = entry.get("weights")
    if not isinstance(weights, list) or not 2 <= len(weights) <= 100:
        problems.append(f"{where}.weights must be a list of 2 to 100 [wx, wy, wz] rows")
    else:
        for row in weights:
            _, problem = _number_list(row, 3, f"{where}.weights rows")
            if problem:
                problems.append(problem)
                break
    return problems


def _rollout_dmps(entries: list[dict[str, Any]]) -> MethodOutput:
    from keymps.dmp import DMP

    pieces, lines = [], []
    for entry in entries:
        start, goal, weights = _dmp_from(entry)
        dmp = DMP(weights=weights, demo_start=start, demo_goal=goal, demo_duration=1.0)
        pieces.append(np.asarray(dmp.rollout(start, goal, num=1000).y))
        lines.append([start[:2], goal[:2]])
    return MethodOutput(
        work_pieces=tuple(pieces), lines_m=np.asarray(lines, dtype=float), keyword=None
    )


def _dmp_schema(name: str, several: bool) -> dict[str, Any]:
    properties: dict[str, Any] = {
        "start": {**_NUMBERS, "description": "[x, y, z] metres"},
        "goal": {**_NUMBERS, "description": "[x, y, z] metres"},
        "weights": {"type": "array", "items": _NUMBERS},
    }
    dmp = {
        "type": "object",
        "properties": properties,
        "required": list(properties),
        "additionalProperties": False,
    }
    if several:
        return _schema(name, {"dmps": {"type": "array", "items": dmp}, "rationale": _RATIONALE})
    return _schema(name, {**properties, "rationale": _RATIONALE})


def _vlm_dmp(context: MethodContext) -> MethodOutput:
    """VLM-DMP: one DMP (start, goal, forcing weights) written by the VLM is the whole motion."""
    seen = _look(context)

    def validate(data: Any) -> tuple[Any, list[str]]:
        problems = _validate_dmp(data, "answer")
        return (None, problems) if problems else ([data], [])

    entries, calls = _ask(
        context, seen, "vlm-dmp", True, _dmp_schema("keymps_vlm_dmp_answer", False), validate
    )
    return replace(_rollout_dmps(entries), calls=tuple(calls))


def _vlm_mdmp(context: MethodContext) -> MethodOutput:
    """VLM-MDMP: several DMPs written by the VLM, each one a piece of the motion."""
    seen = _look(context)

    def validate(data: Any) -> tuple[Any, list[str]]:
        dmps = data.get("dmps") if isinstance(data, dict) else None
        if not isinstance(dmps, list) or not dmps:
            return None, ["dmps must be a non-empty list of {start, goal, weights}"]
        problems = [p for i, d in enumerate(dmps) for p in _validate_dmp(d, f"dmps[{i}]")]
        return (None, problems) if problems else (dmps, [])

    entries, calls = _ask(
        context, seen, "vlm-mdmp", True, _dmp_schema("keymps_vlm_mdmp_answer", True), validate
    )
    return replace(_rollout_dmps(entries), calls=tuple(calls))


@dataclass(frozen=True)
class Method:
    name: str
    summary: str
    needs_vlm: bool
    run: MethodRunner
    zero_weights: bool = False


METHODS: dict[str, Method] = {
    m.name: m
    for m in [
        Method("keymps", "KeyMPs: VLM keyword + 2D keypoint pairs + primitives", False, _run_pipeline),
        Method(
            "vlm-keypoint", "KeyMPs with all DMP weights zero (straight pieces)", False,
            _run_pipeline, zero_weights=True,
        ),
        Method("keymps-text", "KeyMPs without the image (object and shape in text)", True, _keymps_text),
        Method("vlm-keyword", "primitive chosen, 3D keypoints written by the VLM", True, _vlm_keyword),
        Method("vlm-dmp", "one DMP's parameters written by the VLM", True, _vlm_dmp),
        Method("vlm-mdmp", "several DMPs' parameters written by the VLM", True, _vlm_mdmp),
    ]
}  # fmt: skip


def get_method(name: str) -> Method:
    if name not in METHODS:
        raise KeympsError(f"unknown method {name!r} (methods: {', '.join(METHODS)})")
    return METHODS[name]


def check_runnable(method: Method, backend: str) -> None:
    """A one-line error when a VLM-only method is asked to run on the offline planner."""
    if method.needs_vlm and backend == "offline":
        raise MethodNeedsVlm(
            f"method {method.name} needs a VLM ({method.summary}); the offline planner cannot "
            "answer its prompt: pass --model (e.g. openai/gpt-4o) or --api-base URL --model NAME"
        )
