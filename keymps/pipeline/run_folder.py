"""run.json: the machine-readable record of a run (schema documented in docs/run-folder.md)."""

from __future__ import annotations

import json
import math
from typing import Any

from keymps._version import __version__
from keymps.run import Run

SCHEMA_VERSION = "1.0"


def _rounded(values: Any, digits: int = 6) -> Any:
    if isinstance(values, float):
        return round(values, digits) if math.isfinite(values) else None
    if isinstance(values, (list, tuple)):
        return [_rounded(v, digits) for v in values]
    return values


def _vlm_summary(plan: Any) -> dict[str, Any]:
    calls = list(plan.calls) if plan is not None else []

    def total(attr: str) -> float | None:
        values = [getattr(c, attr) for c in calls if getattr(c, attr) is not None]
        return sum(values) if values else None

    return {
        "calls": len(calls),
        "cached": sum(1 for c in calls if c.cached),
        "prompt_tokens": total("prompt_tokens"),
        "completion_tokens": total("completion_tokens"),
        "cost_usd": total("cost_usd"),
        "latency_s": _rounded(total("latency_s") or 0.0, 3),
    }


def run_record(run: Run, error: BaseException | None) -> dict[str, Any]:
    """Everything run.json holds, as plain JSON data."""
    results = run.results
    task = run.task
    detection = results.get("detect")
    plan = results.get("plan")
    grounding = results.get("ground")
    trajectory = results.get("time")
    checked = results.get("check")
    executed = results.get("execute")
    return {
        "schema_version": SCHEMA_VERSION,
        "keymps_version": __version__,
        "ok": error is None,
        "error": None if error is None else str(error),
        "task": task.name,
        "task_file": str(task.path) if task.path else None,
        "instruction": task.instruction,
        "backend": run.notes.get("backend"),
        "backend_reason": run.notes.get("backend_reason"),
        "model": plan.model if plan is not None else task.planner.model,
        "image": {"source": results["image"].source, "size_px": list(results["image"].size_px)}
        if "image" in results
        else None,
        "detection": None
        if detection is None
        else {
            "bbox_px": [int(v) for v in detection.bbox_px],
            "crop_origin_px": [int(v) for v in detection.crop_origin_px],
            "crop_size_px": list(detection.crop_size_px),
            "warnings": list(detection.warnings),
        },
        "keyword": plan.keyword if plan is not None else None,
        "rationale": plan.rationale if plan is not None else None,
        "pairs_px": _rounded(plan.pairs_px.tolist(), 2) if plan is not None else None,
        "pairs_crop_px": _rounded(plan.pairs_crop_px.tolist(), 2) if plan is not None else None,
        "segments_m": _rounded(grounding.segments_m.tolist()) if grounding is not None else None,
        "timings_s": {k: _rounded(v, 4) for k, v in run.timings_s.items()},
        "vlm": _vlm_summary(plan),
        "trajectory": None
        if trajectory is None
        else {
            "duration_s": _rounded(trajectory.duration_s, 4),
            "samples": trajectory.samples,
            "rate_hz": trajectory.rate_hz,
            "joint_names": list(trajectory.joint_names),
        },
        "validation": None
        if checked is None
        else {
            "verdict": "pass" if checked.report.ok else "fail",
            "problems": list(checked.report.problems),
            "figures": {k: _rounded(float(v)) for k, v in checked.report.figures.items()},
        },
        "execution": None
        if executed is None
        else {
            "executor": executed.executor,
            "ok": executed.ok,
            "message": executed.message,
            "files": list(executed.files),
            "figures": {k: _rounded(float(v)) for k, v in executed.figures.items()},
        },
        "warnings": list(run.warnings),
    }


def write_run_json(run: Run, error: BaseException | None = None) -> None:
    path = run.path("run.json")
    path.write_text(json.dumps(run_record(run, error), indent=2) + "\n", encoding="utf-8")
