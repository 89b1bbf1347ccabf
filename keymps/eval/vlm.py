"""Asking a VLM the way the direct methods do: look at the case, fill the method's prompt,
ask, repair invalid answers, record every call (keymps.eval.direct uses it)."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from keymps.bundled import bundled_dir
from keymps.errors import KeympsError
from keymps.eval.context import MethodContext

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
    """The case as the direct methods see it: the task, the scene, the detection, the crop."""

    task: Any
    scene: Any
    detection: Any
    crop_box_m: tuple[float, float, float, float]
    """Board metres covered by the crop: x_min, y_min, x_max, y_max."""
    metres_per_px: tuple[float, float]
    primitives: dict[str, Any]
    truth: dict[str, Any] | None = None
    """The synthetic scene's sidecar, when the image source rendered one."""


def look(context: MethodContext) -> Seen:
    from keymps.config.task import load_task
    from keymps.perception.frames import ImageFrame
    from keymps.planning.planner import crop_metres_per_px
    from keymps.plugin.manager import create_detector, create_image_source
    from keymps.primitives.dictionary import default_search_dirs, load_primitives
    from keymps.run import Run

    task = load_task(context.task_path)
    run = Run(task=task, folder=context.folder)
    source = create_image_source(task.scene.source, task.scene.source_options)
    scene = source.load(run)
    detector = create_detector(task.detector.name, task.detector.options)
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
    return Seen(
        task=task,
        scene=scene,
        detection=detection,
        crop_box_m=box,
        metres_per_px=crop_metres_per_px(task, detection, scene),
        primitives=primitives,
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
    """Ask the VLM with the method's prompt through the planner's own session (repair, cache,
    cassette, redaction, vlm/ records); return (answer, call summaries)."""
    from keymps.config.overrides import apply_overrides
    from keymps.planning.answer import extract_json
    from keymps.planning.backend_choice import keys_the_task_may_send
    from keymps.planning.planner import backend_options
    from keymps.planning.prompt import png_data_url
    from keymps.planning.redaction import remember
    from keymps.planning.session import PlanSession
    from keymps.plugin.manager import create_vlm_backend
    from keymps.run import Run, RunOptions
    from keymps.types import PlanRequest

    task = apply_overrides(seen.task, {"model": context.model, "api_base": context.api_base})
    remember(*keys_the_task_may_send(task))
    backend = create_vlm_backend(context.backend, backend_options(task))
    system = render_prompt(PROMPTS_DIR / f"{method}.md", _values(seen, context))
    image_url = png_data_url(seen.detection.crop)
    user_text = f"Instruction: {task.instruction}"
    content: Any = user_text
    if with_image:
        content = [
            {"type": "text", "text": user_text},
            {"type": "image_url", "image_url": {"url": image_url}},
        ]
    first: list[dict[str, Any]] = [
        {"role": "system", "content": system},
        {"role": "user", "content": content},
    ]
    base = PlanRequest(
        instruction=task.instruction,
        crop=seen.detection.crop,
        crop_mask=None,
        metres_per_px=seen.metres_per_px,
        primitives={n: p.description for n, p in seen.primitives.items()},
        object_height=task.scene.object_height,
        max_pairs=task.planner.max_pairs,
        messages=first,
        schema=schema,
        step="direct",
        model=task.planner.model,
        temperature=task.planner.temperature,
        timeout_s=task.planner.timeout_s,
        task_name=task.name,
    )
    session = PlanSession(
        task=task,
        run=Run(
            task,
            context.folder,
            RunOptions(no_cache=context.no_cache, dispatch=context.dispatch),
        ),
        backend_name=context.backend,
        backend=backend,
        base=base,
        system_template=system,
        template_source=str(PROMPTS_DIR / f"{method}.md"),
        image_url=image_url,
    )

    def request_for(history: list[tuple[str, list[str]]]) -> PlanRequest:
        messages = list(first)
        for answer_text, problems in history:
            messages += [
                {"role": "assistant", "content": answer_text},
                {"role": "user", "content": _repair(problems)},
            ]
        return session.request_with(messages, schema, attempt=len(history) + 1)

    def parse(text: str) -> tuple[Any, list[str]]:
        try:
            return validate(extract_json(text))
        except ValueError as error:
            return None, [f"the answer is not a JSON object ({error})"]

    parsed = session.ask_until_valid(f"{method} answer", request_for, parse)
    calls = [
        {
            "latency_s": call.latency_s,
            "cost_usd": call.cost_usd,
            "prompt_tokens": call.prompt_tokens,
            "completion_tokens": call.completion_tokens,
            "cached": call.cached,
        }
        for call in session.calls
    ]
    return parsed, calls


def _repair(problems: list[str]) -> str:
    return (
        "Your answer was invalid:\n"
        + "\n".join(f"- {p}" for p in problems)
        + "\nAnswer again with the corrected JSON object only."
    )
