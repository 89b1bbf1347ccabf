"""Asking a VLM the way the direct methods do: look at the case, fill the method's prompt,
ask, repair invalid answers, record every call (keymps.eval.direct uses it)."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.bundled import bundled_dir
from keymps.errors import KeympsError
from keymps.eval.context import MethodContext

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.planning.session import PlanSession
    from keymps.types import PlanRequest, VlmCall

PROMPTS_DIR = bundled_dir("prompts") / "methods"


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
class Seen:
    """The case as the direct methods see it: what `keymps run` perceives, and the primitives."""

    task: Any
    scene: Any
    """The scene as the stages see it (rectified with board corners)."""
    detection: Any
    frame: Any
    """The scene's image frame (keymps.perception.frames.ImageFrame.for_scene)."""
    crop_box_m: tuple[float, float, float, float]
    """Board metres covered by the crop: x_min, y_min, x_max, y_max."""
    metres_per_px: tuple[float, float]
    primitives: dict[str, Any]
    truth: dict[str, Any] | None = None
    """The synthetic scene's sidecar, when the image source rendered one."""


def look(context: MethodContext) -> Seen:
    """The case's image and detect stages, run the way `keymps run` runs them."""
    from keymps.config.task import load_task
    from keymps.perception.frames import ImageFrame
    from keymps.pipeline.stages import load_primitives, perceive
    from keymps.planning.planner import crop_metres_per_px
    from keymps.run import Run

    task = load_task(context.task_path)
    perception = perceive(task, Run(task=task, folder=context.folder))
    scene, detection = perception.scene, perception.detection
    frame = ImageFrame.for_scene(task, scene)
    x0, y0 = detection.crop_origin_px
    w, h = detection.crop_size_px
    corners = frame.to_board(np.array([[x0, y0], [x0 + w, y0 + h]], dtype=float))
    box = (
        float(corners[:, 0].min()),
        float(corners[:, 1].min()),
        float(corners[:, 0].max()),
        float(corners[:, 1].max()),
    )
    return Seen(
        task=task,
        scene=scene,
        detection=detection,
        frame=frame,
        crop_box_m=box,
        metres_per_px=crop_metres_per_px(task, detection, scene),
        primitives=load_primitives(task),
        truth=scene.truth,
    )


def _shape_words(kind: str) -> str:
    from keymps.scenes.render import KINDS

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


def _values(seen: Seen, context: MethodContext) -> dict[str, str]:
    from keymps.scenes.render import KINDS

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


def ask(
    context: MethodContext,
    seen: Seen,
    method: str,
    with_image: bool,
    schema: dict[str, Any],
    validate: Callable[[Any], tuple[Any, list[str]]],
) -> tuple[Any, list[dict[str, Any]]]:
    """Ask the VLM with the method's prompt through the planner's own session (messages,
    repair, cache, cassette, redaction, vlm/ records); return (answer, call summaries).

    `validate(data)` checks the answer's JSON object: (parsed or None, problems)."""
    from keymps.config.overrides import apply_overrides
    from keymps.planning.backend_choice import keys_the_task_may_send
    from keymps.planning.redaction import remember

    task = apply_overrides(seen.task, {"model": context.model, "api_base": context.api_base})
    remember(*keys_the_task_may_send(task))
    session = _session(context, seen, task, method, schema)
    user_text = f"Instruction: {task.instruction}"
    parsed = session.ask_own_prompt(f"{method} answer", user_text, with_image, schema, validate)
    return parsed, [_call_summary(call) for call in session.calls]


def _session(
    context: MethodContext, seen: Seen, task: Task, method: str, schema: dict[str, Any]
) -> PlanSession:
    """The plan session a run of `task` would open, with the method's prompt as its system
    message and the case's crop as its image."""
    from keymps.planning.planner import backend_options
    from keymps.planning.prompt import png_data_url
    from keymps.planning.session import PlanSession
    from keymps.plugin.manager import create_vlm_backend
    from keymps.run import Run, RunOptions

    prompt = PROMPTS_DIR / f"{method}.md"
    return PlanSession(
        task=task,
        run=Run(
            task,
            context.folder,
            RunOptions(no_cache=context.no_cache, dispatch=context.dispatch),
        ),
        backend_name=context.backend,
        backend=create_vlm_backend(context.backend, backend_options(task)),
        base=_base_request(seen, task, schema),
        system_template=render_prompt(prompt, _values(seen, context)),
        template_source=str(prompt),
        image_url=png_data_url(seen.detection.crop),
    )


def _base_request(seen: Seen, task: Task, schema: dict[str, Any]) -> PlanRequest:
    """The request every call of the session starts from (its messages are the session's)."""
    from keymps.types import PlanRequest

    return PlanRequest(
        instruction=task.instruction,
        crop=seen.detection.crop,
        crop_mask=None,
        metres_per_px=seen.metres_per_px,
        primitives={n: p.description for n, p in seen.primitives.items()},
        object_height=task.scene.object_height,
        max_pairs=task.planner.max_pairs,
        messages=[],
        schema=schema,
        step="direct",
        model=task.planner.model,
        temperature=task.planner.temperature,
        timeout_s=task.planner.timeout_s,
        task_name=task.name,
    )


def _call_summary(call: VlmCall) -> dict[str, Any]:
    """What the method's result keeps of one call: latency, cost, tokens, whether cached."""
    return {
        "latency_s": call.latency_s,
        "cost_usd": call.cost_usd,
        "prompt_tokens": call.prompt_tokens,
        "completion_tokens": call.completion_tokens,
        "cached": call.cached,
    }
