"""The run folder: run.json, the machine-readable record of a run (schema documented in
docs/run-folder.md), and the removal of an earlier run's files."""

from __future__ import annotations

import errno
import json
import math
import os
import re
import shutil
from pathlib import Path
from typing import Any

from keymps._version import __version__
from keymps.errors import KeympsError, RunInterrupted, StageError
from keymps.outcome.record import outcome_record
from keymps.robot.safety import SafetyError
from keymps.run import Run
from keymps.run_files import IMAGE_FORMATS, write_atomically
from keymps.types import ExecutionReport, ToolPath, Trajectory, ValidatedTrajectory

SCHEMA_VERSION = "1.7"
"""1.1: `status` (ok, failed, interrupted). 1.2: `unfinished`, the placeholder written before the
first stage. 1.3: `pieces` (the tool path's pieces: the kind and the keypoint pairs of each).
1.4: `outcome` (the predicted result, the verdict). 1.5: `outcome`'s deposits' `pairs` (every pair
a stroke pipes). 1.6: `files` (the run's files and folders, relative to its folder)."""

RESERVED_BYTES = 16384
"""run.json's placeholder holds this much disk space until the run ends (typical records are
5-10 kB), so that a disk the run fills up still has room for its record."""

_NO_SPACE = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


def _rounded(values: Any, digits: int = 6) -> Any:
    if isinstance(values, float):
        return round(values, digits) if math.isfinite(values) else None
    if isinstance(values, (list, tuple)):
        return [_rounded(v, digits) for v in values]
    return values


def _answer_form(plan: Any) -> dict[str, Any] | None:
    """How the plan was answered: coordinates, named design, the image size sent."""
    if plan is None:
        return None
    sent = list(plan.image_sent_px) if plan.image_sent_px else None
    return {"coordinates": plan.coordinates, "design": plan.design, "image_sent_px": sent}


def _vlm_summary(plan: Any) -> dict[str, Any]:
    calls = [c for c in plan.calls if c.model_call] if plan is not None else []

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


def _validation(checked: ValidatedTrajectory | None, error: BaseException | None) -> Any:
    """The check stage's verdict: its report, or the problems of a failed check."""
    if checked is not None:
        report = checked.report
        return {
            "verdict": "pass" if report.ok else "fail",
            "problems": list(report.problems),
            "figures": {k: _rounded(float(v)) for k, v in report.figures.items()},
        }
    if isinstance(error, StageError) and isinstance(error.detail, SafetyError):
        return {"verdict": "fail", "problems": list(error.detail.problems), "figures": {}}
    return None


def _image_record(scene: Any) -> dict[str, Any]:
    record: dict[str, Any] = {"source": scene.source, "size_px": list(scene.size_px)}
    info = getattr(scene, "rectification", None)
    if info is not None:
        record["rectified"] = {
            "photo_size_px": [int(info.photo.shape[1]), int(info.photo.shape[0])],
            "mm_per_px": info.mm_per_px,
            "plane_z_m": _rounded(info.plane_z),
            "board_polygon_px": _rounded(info.board_polygon_px.tolist(), 3),
            "camera_position_m": _rounded(list(info.camera_position_m))
            if info.camera_position_m is not None
            else None,
        }
    return record


def _status(error: BaseException | None) -> str:
    """ok, failed, or interrupted (Ctrl-C, SIGTERM, SIGHUP)."""
    if error is None:
        return "ok"
    return "interrupted" if isinstance(error, (RunInterrupted, KeyboardInterrupt)) else "failed"


def run_record(run: Run, error: BaseException | None) -> dict[str, Any]:
    """Everything run.json holds, as plain JSON data."""
    stages = run.stages
    task = run.task
    scene, plan, grounding = stages.image, stages.plan, stages.ground
    return {
        "schema_version": SCHEMA_VERSION,
        "keymps_version": __version__,
        "ok": error is None,
        "status": _status(error),
        "error": None if error is None else str(error),
        "task": task.name,
        "task_file": str(task.path) if task.path else None,
        "instruction": task.instruction,
        "backend": run.backend,
        "backend_reason": run.backend_reason,
        "model": plan.model if plan is not None else task.planner.model,
        "image": _image_record(scene) if scene else None,
        "detection": _detection_record(run),
        "keyword": plan.keyword if plan is not None else None,
        "rationale": plan.rationale if plan is not None else None,
        "pairs_px": _rounded(plan.pairs_px.tolist(), 2) if plan is not None else None,
        "pair_objects": list(plan.pair_objects) if plan is not None else None,
        "pairs_crop_px": _rounded(plan.pairs_crop_px.tolist(), 2) if plan is not None else None,
        "answer": _answer_form(plan),
        "segments_m": _rounded(grounding.segments_m.tolist()) if grounding is not None else None,
        "pieces": _pieces(stages.compose),
        "timings_s": {k: _rounded(v, 4) for k, v in run.timings_s.items()},
        "vlm": _vlm_summary(plan),
        "trajectory": _trajectory_record(stages.time),
        "validation": _validation(stages.check, error),
        "outcome": outcome_record(stages.outcome, run.options.accept_outcome),
        "execution": _execution_record(stages.execute),
        "warnings": list(run.warnings),
        "files": run_files(run),
    }


def _detection_record(run: Run) -> dict[str, Any] | None:
    """The detect stage's boxes in full-image pixels, its warnings, objects and report."""
    detection = run.stages.detect
    if detection is None:
        return None
    return {
        "bbox_px": [int(v) for v in detection.bbox_px],
        "crop_origin_px": [int(v) for v in detection.crop_origin_px],
        "crop_size_px": list(detection.crop_size_px),
        "warnings": list(detection.warnings),
        "objects": _objects(run),
        "report": detection.report,
    }


def _trajectory_record(trajectory: Trajectory | None) -> dict[str, Any] | None:
    """The timed trajectory's duration, samples, rate and joints (trajectory.csv has the rest)."""
    if trajectory is None:
        return None
    return {
        "duration_s": _rounded(trajectory.duration_s, 4),
        "samples": trajectory.samples,
        "rate_hz": trajectory.rate_hz,
        "joint_names": list(trajectory.joint_names),
    }


def _execution_record(executed: ExecutionReport | None) -> dict[str, Any] | None:
    """The executor's report: who ran it, its verdict, message, files and figures."""
    if executed is None:
        return None
    return {
        "executor": executed.executor,
        "ok": executed.ok,
        "dry_run": executed.dry_run,
        "message": executed.message,
        "files": list(executed.files),
        "figures": {k: _rounded(float(v)) for k, v in executed.figures.items()},
    }


def _pieces(tool_path: ToolPath | None) -> list[dict[str, Any]] | None:
    """Per tool path piece (trajectory.csv's `piece`), its kind and the pairs it works on: a
    travel piece the pair it leads to, a work piece every pair it pipes, in order."""
    if tool_path is None:
        return None
    return [
        {
            "kind": piece.kind,
            "pairs": list(piece.piped_pairs) if piece.kind == "work" else [piece.pair_index],
        }
        for piece in tool_path.pieces
    ]


def _objects(run: Run) -> list[dict[str, Any]]:
    """Every object found: id, name, height, box and area (the task's names and heights)."""
    from keymps.perception.scene_objects import detected_objects

    detection = run.stages.detect
    if detection is None:
        return []
    boxes = {o.id: o for o in detected_objects(detection)}
    return [
        {
            "id": o.id,
            "name": o.name,
            "height_m": _rounded(o.height),
            "bbox_px": [int(v) for v in boxes[o.id].bbox_px] if o.id in boxes else None,
            "area_px": _rounded(float(boxes[o.id].area_px), 1) if o.id in boxes else None,
        }
        for o in run.objects
    ]


def write_run_json(run: Run, error: BaseException | None = None) -> None:
    """Write run.json (secrets redacted) atomically: never empty or cut. On a full disk it goes
    into the space its placeholder holds (reserve_run_json), the whole record if it fits, else
    the short one (SHORT_FIELDS)."""
    from keymps.planning.redaction import redact

    record = redact(run_record(run, error))
    text = json.dumps(record, indent=2) + "\n"
    try:
        write_atomically(run.path("run.json"), text)
    except OSError as error_writing:
        if error_writing.errno not in _NO_SPACE:
            raise
        short = {key: record[key] for key in SHORT_FIELDS} | {"short": True}
        for fallback in (text, json.dumps(short) + "\n"):
            if _overwrite_in_place(run.path("run.json"), fallback.encode()):
                return
        raise


SHORT_FIELDS = (
    "schema_version", "keymps_version", "ok", "status", "error", "task", "task_file",
    "backend", "execution", "warnings", "files",
)  # fmt: skip
"""What run.json keeps when the disk is full and the whole record does not fit its reserved
space (`"short": true` says so)."""


def reserve_run_json(run: Run) -> None:
    """Write the placeholder run.json (`"status": "unfinished"`) before the first stage, padded to
    RESERVED_BYTES (less where the disk has less room): it holds the disk space the record needs
    at the end, and says that the run never finished if its process is killed (kill -9, power
    loss). Raises OSError when not even the bare placeholder can be written."""
    record = {
        "schema_version": SCHEMA_VERSION,
        "keymps_version": __version__,
        "ok": False,
        "status": "unfinished",
        "error": "the run has not ended: it is running, or its process was killed before it "
        "could write this record (kill -9, a crash, a power loss); if it had reached its "
        "executor, a real arm may have moved",
        "task": run.task.name,
        "task_file": str(run.task.path) if run.task.path else None,
        "instruction": run.task.instruction,
    }
    text = json.dumps(record, indent=2) + "\n"
    for size in (RESERVED_BYTES, 4096, 0):
        try:
            write_atomically(run.path("run.json"), text.ljust(size - 1) + "\n" if size else text)
            return
        except OSError as error:
            if error.errno not in _NO_SPACE or not size:
                raise


def _overwrite_in_place(path: Any, data: bytes) -> bool:
    """Write `data` over the placeholder's own disk blocks (no new ones: a full disk has none);
    False when it does not fit them. Not atomic: only for a disk too full for the atomic way."""
    try:
        descriptor = os.open(path, os.O_WRONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        status = os.fstat(descriptor)
        if len(data) > max(status.st_size, status.st_blocks * 512):
            return False
        os.pwrite(descriptor, data, 0)
        os.ftruncate(descriptor, len(data))
        os.fsync(descriptor)
        return True
    except OSError:
        return False
    finally:
        os.close(descriptor)


EARLIER_RUN_FILES = (
    "trajectory.csv",
    "trajectory.json",
    "trajectory.script",
    "run.rrd",
    "execution.mp4",
    "ur_rtde.log",
    "trajectory_bag/",
    *(
        f"{stem}.{suffix}"
        for stem in ("plan", "plan_photo", "plan_outcome", "outcome")
        for suffix in IMAGE_FORMATS
    ),
)
"""What a run and the bundled plugins write beside run.json under their default names (a
folder's ends in /, docs/run-folder.md): removed from an earlier run's folder whatever its
run.json lists (it lists nothing when its run was killed, or recorded before schema 1.6)."""

RECORD_BYTES_READ = 4 << 20
"""An earlier run.json larger than this is not read for its files (a record is 5-50 kB)."""
_TEMPORARY = re.compile(r"\..+\.\d+-[0-9a-f]{8}\.tmp")
"""A hidden temporary file or folder of open_atomically (or an exporter writing the same way)
that a killed run left behind."""


def run_files(run: Run) -> list[str]:
    """The run's files and folders in its folder, relative to it, sorted (a folder's name ends
    in /): EARLIER_RUN_FILES' that are there, and every one its executor reported; run.json,
    vlm/ and the lock aside."""
    folder = run.folder
    names = {name for name in EARLIER_RUN_FILES if _kind_of(folder / name) == _kind(name)}
    executed = run.stages.execute
    for reported in executed.files if executed is not None else ():
        name = _relative(folder, Path(reported))
        if name is not None:
            names.add(name + "/" if _kind_of(folder / name) == "folder" else name)
    return sorted(names)


def _kind(name: str) -> str:
    return "folder" if name.endswith("/") else "file"


def _kind_of(path: Path) -> str | None:
    """file (a link too, never followed), folder, or None when nothing is there."""
    if path.is_symlink() or path.is_file():
        return "file"
    return "folder" if path.is_dir() else None


def _relative(folder: Path, path: Path) -> str | None:
    """`path` (absolute, or relative like `folder`) relative to `folder` (POSIX, no ..), or
    None when it is not inside it or is the folder itself."""
    for base, inside in ((folder, path), (folder.absolute(), path.absolute())):
        try:
            name = inside.relative_to(base).as_posix()
        except ValueError:
            continue
        return _safe(name)
    return None


def _safe(name: str) -> str | None:
    """`name` if it is a plain relative path inside a run folder that names no file the run
    keeps itself (run.json, vlm/, the lock), else None."""
    parts = Path(name.rstrip("/")).parts
    if not parts or Path(name).is_absolute() or any(p in ("..", ".", "") for p in parts):
        return None
    if parts[0] in ("run.json", "vlm", ".keymps.lock"):
        return None
    return name


def clear_earlier_run(folder: Path) -> None:
    """Remove an earlier run's files from a folder holding its run.json, so that no file of that
    run passes for the new run's (a failed run left the old trajectory.csv beside its own
    run.json; a run without the rosbag executor the old bag): EARLIER_RUN_FILES, the files and
    folders its run.json lists, vlm/'s files, a killed run's temporaries, run.json last. Nothing
    is reached through a link or outside the folder. A folder without run.json is left as it
    is. Call with the folder's lock held."""
    record = folder / "run.json"
    if not record.is_file():
        return
    names = dict.fromkeys([*EARLIER_RUN_FILES, *_recorded_files(folder, record)])
    names.update(dict.fromkeys(_temporaries(folder)))
    for name in names:
        _remove(folder, name)
    answers = folder / "vlm"
    try:
        if answers.is_dir() and not answers.is_symlink():
            for entry in answers.iterdir():
                if entry.is_file() or entry.is_symlink():  # a link itself, never its target
                    entry.unlink()
        record.unlink()
    except OSError as error:
        what = Path(error.filename).name if error.filename else "files"
        raise KeympsError(
            f"{folder}: cannot remove the earlier run's {what}: {error.strerror}"
        ) from None


def _recorded_files(folder: Path, record: Path) -> list[str]:
    """The files and folders an earlier run.json lists: `files` (1.6), else its executor's
    (`execution.files`, paths as that run named them); none from a record that cannot be read."""
    try:
        if record.stat().st_size > RECORD_BYTES_READ:
            return []
        data = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    if not isinstance(data, dict):
        return []
    listed = data.get("files")
    if isinstance(listed, list):
        return [name for name in listed if isinstance(name, str) and _safe(name)]
    execution = data.get("execution")
    reported = execution.get("files") if isinstance(execution, dict) else None
    names = []
    for path in reported if isinstance(reported, list) else ():
        name = _relative(folder, Path(path)) if isinstance(path, str) else None
        if name is not None:
            names.append(name + "/" if _kind_of(folder / name) == "folder" else name)
    return names


def _temporaries(folder: Path) -> list[str]:
    """A killed run's hidden temporary files and folders at the top of its folder."""
    try:
        entries = [entry for entry in folder.iterdir() if _TEMPORARY.fullmatch(entry.name)]
    except OSError:
        return []
    return [e.name + "/" if _kind_of(e) == "folder" else e.name for e in entries]


def _remove(folder: Path, name: str) -> None:
    """Remove file or folder `name` of an earlier run (a link itself, never what it leads to),
    then the folders it leaves empty; nothing through a link. One line naming it if it cannot."""
    path = folder / name.rstrip("/")
    if any(parent.is_symlink() for parent in _parents(folder, path)):
        return
    try:
        if _kind(name) == "folder" and _kind_of(path) == "folder":
            shutil.rmtree(path)
        elif _kind_of(path) is not None:
            path.unlink()
        else:
            return
    except OSError as error:
        raise KeympsError(
            f"{folder}: cannot remove the earlier run's {name.rstrip('/')}: {error.strerror}"
        ) from None
    for parent in _parents(folder, path):
        try:
            parent.rmdir()
        except OSError:  # not empty (or gone): it holds other files
            break


def _parents(folder: Path, path: Path) -> list[Path]:
    """The folders between `folder` and `path`, innermost first."""
    return list(path.parents)[: len(path.relative_to(folder).parts) - 1]
