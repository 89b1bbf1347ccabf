"""The text side of a Rerun recording: VLM exchange, reports and summary, secrets redacted
(keymps.planning.redaction)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from keymps.planning.redaction import redact, redact_text

if TYPE_CHECKING:
    from keymps.run import Run
    from keymps.types import ExecutionReport, Plan, ValidatedTrajectory, VlmCall


def _shortened(value: Any) -> Any:
    """`value` with inline data (the crop as a data URL) replaced by its size."""
    if isinstance(value, dict):
        return {key: _shortened(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_shortened(item) for item in value]
    if isinstance(value, str) and value.startswith("data:") and len(value) > 200:
        return f"[inline data: {len(value)} characters]"
    return value


def _markdown(rr: Any, text: str) -> Any:
    return rr.TextDocument(redact_text(text), media_type=rr.MediaType.MARKDOWN)


def _render_request(request: dict[str, Any]) -> str:
    """A request as readable markdown: chat messages as sections, images by size only."""
    request = redact(_shortened(request))
    messages = request.get("messages") if isinstance(request, dict) else None
    if not isinstance(messages, list):
        return "```json\n" + json.dumps(request, indent=2, default=str) + "\n```"
    parts = []
    settings = {k: v for k, v in request.items() if k != "messages"}
    if settings:
        parts.append("```json\n" + json.dumps(settings, indent=2, default=str) + "\n```")
    for message in messages:
        if not isinstance(message, dict):
            parts.append(str(message))
            continue
        content = message.get("content")
        if isinstance(content, list):
            texts = []
            for item in content:
                if isinstance(item, dict) and item.get("type") == "text":
                    texts.append(str(item.get("text", "")))
                elif isinstance(item, dict):
                    texts.append(f"*[{item.get('type', 'attachment')}]*")
                else:
                    texts.append(str(item))
            content = "\n\n".join(texts)
        parts.append(f"### {message.get('role', 'message')}\n\n{content}")
    return "\n\n".join(parts)


def _step(call: VlmCall) -> str:
    step = call.request.get("step") if isinstance(call.request, dict) else None
    return str(step) if step else "plan"


def _final_calls_per_step(calls: tuple[VlmCall, ...]) -> list[VlmCall]:
    """The last attempt of each planning step (keyword, pairs or combined), in order."""
    last: dict[str, VlmCall] = {}
    for call in calls:
        last[_step(call)] = call
    return list(last.values())


def log_vlm(rec: Any, plan: Plan) -> None:
    """The VLM exchange: the final request of each step, the answer, every attempt."""
    import rerun as rr

    model = f" ({plan.model})" if plan.model else ""
    finals = _final_calls_per_step(plan.calls)
    prompt = [f"## Request to {plan.backend}{model}"]
    for call in finals:
        prompt.append(f"\n## step {_step(call)}, attempt {call.attempt}\n")
        prompt.append(_render_request(call.request))
    if not finals:
        prompt.append("\n*no request recorded*")
    rec.log("vlm/prompt", _markdown(rr, "\n".join(prompt)))
    answer = [
        f"## Answer from {plan.backend}{model}",
        f"- keyword: **{plan.keyword}**",
        f"- pairs: {plan.num_pairs}",
    ]
    if plan.rationale:
        answer.append(f"- rationale: {plan.rationale}")
    for call in finals:
        answer.append(f"\nstep {_step(call)}:\n```\n" + call.answer_text + "\n```")
    rec.log("vlm/answer", _markdown(rr, "\n".join(answer)))
    lines = [f"## {len(plan.calls)} call(s)"]
    for call in plan.calls:
        facts = [f"latency {call.latency_s:.2f} s"]
        if call.prompt_tokens is not None:
            facts.append(f"{call.prompt_tokens} prompt tokens")
        if call.completion_tokens is not None:
            facts.append(f"{call.completion_tokens} completion tokens")
        if call.cost_usd is not None:
            facts.append(f"${call.cost_usd:.4f}")
        if call.cached:
            facts.append("cached")
        lines.append(f"\n### step {_step(call)}, attempt {call.attempt}: {', '.join(facts)}")
        if call.error:
            lines.append(f"\n**error:** {call.error}")
        lines.append("\n```\n" + call.answer_text + "\n```")
    rec.log("vlm/attempts", _markdown(rr, "\n".join(lines)))


def log_validation(rec: Any, validated: ValidatedTrajectory) -> None:
    import rerun as rr

    report = validated.report
    lines = [f"## Safety check: {'passed' if report.ok else 'FAILED'}"]
    lines.extend(f"- problem: {problem}" for problem in report.problems)
    if report.figures:
        lines.append("\n| figure | value |\n|---|---|")
        lines.extend(f"| {name} | {value:.6g} |" for name, value in sorted(report.figures.items()))
    trajectory = validated.trajectory
    lines.append(f"\n{trajectory.samples} samples, {trajectory.duration_s:.2f} s")
    rec.log("check/report", _markdown(rr, "\n".join(lines)))


def _in_run_folder(name: str, run: Run) -> str:
    """A file path relative to the run folder when it is inside it (the report reads the same
    wherever the run folder is)."""
    try:
        return str(Path(name).resolve().relative_to(run.folder.resolve()))
    except ValueError:
        return name


def log_execution(rec: Any, report: ExecutionReport, run: Run) -> None:
    import rerun as rr

    lines = [f"## Executor {report.executor}: {'ok' if report.ok else 'FAILED'}"]
    if report.message:
        lines.append(f"\n{report.message}")
    lines.extend(f"- file: {_in_run_folder(name, run)}" for name in report.files)
    if report.figures:
        lines.append("\n| figure | value |\n|---|---|")
        lines.extend(f"| {name} | {value:.6g} |" for name, value in sorted(report.figures.items()))
    rec.log("execute/report", _markdown(rr, "\n".join(lines)))


def log_finished(rec: Any, error: BaseException | None, run: Run) -> None:
    import rerun as rr

    status = "succeeded" if error is None else "failed"
    lines = [f"## Run {run.folder.name} {status}", f"\ntask: **{run.task.name}**"]
    lines.append(f"\ninstruction: {run.task.instruction}")
    if error is not None:
        lines.append(f"\n**error:** {type(error).__name__}: {error}")
    if run.timings_s:
        lines.append("\n| stage | seconds |\n|---|---|")
        lines.extend(f"| {name} | {seconds:.3f} |" for name, seconds in run.timings_s.items())
    lines.extend(f"- warning: {warning}" for warning in run.warnings)
    rec.log("run/summary", _markdown(rr, "\n".join(lines)))
    if error is not None:
        rec.log(
            "run/error",
            rr.TextLog(
                redact_text(f"{type(error).__name__}: {error}"), level=rr.TextLogLevel.ERROR
            ),
        )
