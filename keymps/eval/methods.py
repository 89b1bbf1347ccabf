"""The methods `keymps eval` compares (the paper's Experiments 1-2 and Appendix F).

- keymps: the full pipeline (detector, VLM keyword + 2D keypoint pairs, primitive, robot checks).
- keymps-design: the same, the VLM naming a design of the offline catalogue (planner.answer:
  design) that keymps lays out exactly: the ablation of "understands" against "draws".
- vlm-keypoint: the same with every primitive's DMP weights set to zero (straight pieces).
- keymps-text: no image; the VLM reads the object's name and shape in text and answers pairs
  in the coordinates of the (unseen) crop; the rest is KeyMPs.
- vlm-keyword: the VLM picks the primitive and writes 3D keypoints in board metres directly.
- vlm-dmp / vlm-mdmp: the VLM writes one / several DMPs' parameters (start, goal, weights).

keymps, keymps-design and vlm-keypoint run through keymps.run_task (any backend, offline included). The others
need a VLM; they perceive through keymps run's own stages (keymps.pipeline.stages), ask with
their own prompt (prompts/methods/) through the planning session,
and are scored on the motion they generate (no robot checks, as in the paper).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from keymps.errors import KeympsError
from keymps.eval.context import MethodContext, MethodOutput
from keymps.planning.backend_choice import NO_SERVER
from keymps.run import RunOptions, RunOverrides, StageResults
from keymps.types import AnswerMode

MethodRunner = Callable[[MethodContext], MethodOutput]


class MethodNeedsVlm(KeympsError):
    """A method that only a VLM can run was asked to run offline."""


# --------------------------------------------------------------------------- pipeline methods


def _pipeline(answer: AnswerMode) -> MethodRunner:
    """The pipeline with planner.answer set: pairs (the paper's KeyMPs) or a named design."""

    def run(context: MethodContext) -> MethodOutput:
        return _run_pipeline(context, answer)

    return run


def _run_pipeline(context: MethodContext, answer: AnswerMode | None = None) -> MethodOutput:
    """A whole keymps run (or, plan-only, its stages through grounding) in the case's folder."""
    from keymps.pipeline.engine import run_task

    results = StageResults()

    def keep(stage: str, seconds: float, result: Any) -> None:
        results.record(stage, result)

    try:
        run_task(
            context.task_path,
            on_stage=keep,
            options=RunOptions(
                rerun="off",
                quiet=True,
                no_cache=context.no_cache,
                image_format=context.image_format,
                dispatch=context.dispatch,
                # the paper scores every method on the motion it makes: only --verify-outcome
                # refuses
                accept_outcome=context.outcome != "repair",
            ),
            overrides=RunOverrides(
                backend=context.backend,
                model=context.model or None,
                api_base=context.api_base or None,
                answer=answer,
                out=context.folder,
            ),
            through=_through(context),
        )
    except KeympsError as error:
        raise PartialRunError(str(error), results) from None
    return _pipeline_output(results, context)


def _through(context: MethodContext) -> str:
    """How far a run goes: execute; plan-only ones ground, or the outcome stage."""
    if not context.plan_only:
        return "execute"
    return "ground" if context.outcome == "off" else "outcome"


class PartialRunError(KeympsError):
    """A pipeline run that stopped at a stage; the results of the stages before it are kept."""

    def __init__(self, message: str, results: StageResults):
        super().__init__(message)
        self.results = results


def _pipeline_output(results: StageResults, context: MethodContext) -> MethodOutput:
    from keymps.run_files import image_file

    plan, grounding, tool_path = results.plan, results.ground, results.compose
    pieces = tuple(p.points for p in tool_path.pieces if p.kind == "work") if tool_path else ()
    lines = grounding.segments_m[:, :, :2] if grounding is not None else np.zeros((0, 2, 2))
    calls = tuple(_call_summary(c) for c in plan.calls if c.model_call) if plan is not None else ()
    paths = {
        name: image_file(context.folder, name, context.image_format) for name in ("plan", "outcome")
    }
    images = {name: str(path) for name, path in paths.items() if path.is_file()}
    outcome = results.outcome
    cut = None
    if outcome is not None:
        swept = [c.swept_m for c in outcome.predicted.cuts]
        cut = np.concatenate(swept).reshape(-1, 2, 2) if swept else np.zeros((0, 2, 2))
    return MethodOutput(
        cut_lines_m=cut,
        work_pieces=pieces,
        lines_m=np.asarray(lines, dtype=float),
        keyword=plan.keyword if plan is not None else None,
        calls=calls,
        images=images,
        scene=results.image.truth if results.image is not None else None,
    )


def partial_output(error: PartialRunError, context: MethodContext) -> MethodOutput:
    """What a stopped pipeline run had produced (e.g. a plan refused later by the safety check)."""
    return _pipeline_output(error.results, context)


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
    from keymps.primitives.dictionary import load_primitives, save_primitive

    folder.mkdir(parents=True, exist_ok=True)
    for name, primitive in load_primitives(names, search_dirs).items():
        flat = replace(primitive.dmp, weights=np.zeros_like(primitive.dmp.weights))
        save_primitive(
            replace(primitive, dmp=flat, demo=None, fit_rmse=0.0), folder / f"{name}.yaml"
        )


def _direct(name: str) -> MethodRunner:
    """A method of keymps.eval.direct, imported when it runs."""

    def run(context: MethodContext) -> MethodOutput:
        from keymps.eval import direct as eval_direct

        runner: MethodRunner = getattr(eval_direct, name)
        return runner(context)

    return run


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
        Method("keymps", "KeyMPs: VLM keyword + 2D keypoint pairs + primitives", False, _pipeline("pairs")),
        Method(
            "keymps-design", "KeyMPs with a named design the VLM picks, laid out by keymps",
            False, _pipeline("design"),
        ),
        Method(
            "vlm-keypoint", "KeyMPs with all DMP weights zero (straight pieces)", False,
            _pipeline("pairs"), zero_weights=True,
        ),
        Method("keymps-text", "KeyMPs without the image (object and shape in text)", True, _direct("keymps_text")),
        Method("vlm-keyword", "primitive chosen, 3D keypoints written by the VLM", True, _direct("vlm_keyword")),
        Method("vlm-dmp", "one DMP's parameters written by the VLM", True, _direct("vlm_dmp")),
        Method("vlm-mdmp", "several DMPs' parameters written by the VLM", True, _direct("vlm_mdmp")),
    ]
}  # fmt: skip


def get_method(name: str) -> Method:
    if name not in METHODS:
        raise KeympsError(f"unknown method {name!r} (methods: {', '.join(METHODS)})")
    return METHODS[name]


def check_runnable(method: Method, backend: str) -> None:
    """A one-line error when a VLM-only method is asked to run on the offline planner."""
    if method.needs_vlm and backend in NO_SERVER:
        raise MethodNeedsVlm(
            f"method {method.name} needs a VLM ({method.summary}); the offline planner cannot "
            "answer its prompt: pass --model (e.g. openai/gpt-4o) or --api-base URL --model NAME"
        )
