"""Runs a suite: every case x method x repeat, concurrently, resumably, one JSON line per result.

Each job renders its case's scene, runs the method, scores what it generated (D against the
ground truth, or the equal-parts check) and appends one record to results.jsonl, flushed and
synced at once: an interrupted evaluation loses no finished result, and a rerun into the same
folder skips every job already recorded (same case, method, repeat, backend and model).
A job that fails is recorded as a failure with its one-line error; it never stops the suite.

Jobs run in threads of this process or of worker processes (keymps.eval.pool); their VLM calls
are made by one asyncio event loop in this process (keymps.eval.broker), at most `concurrency`
at once, so the waits overlap each other and the other runs' CPU work. With litellm, a few more
runs than that are in flight, preparing their calls while the others wait
(keymps.eval.pool.runs_in_flight).
"""

from __future__ import annotations

import functools
import json
import os
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.eval.suites import Suite
from keymps.planning.backend_choice import AUTO_OFFLINE, AUTO_VLM
from keymps.planning.redaction import redact

if TYPE_CHECKING:
    from keymps.eval.broker import VlmBroker
    from keymps.eval.turn import CpuTurn
    from keymps.planning.warm.dispatch import WarmDispatch

RESULTS_FILE = "results.jsonl"


@dataclass(frozen=True)
class EvalOptions:
    out: Path
    methods: tuple[str, ...] = ("keymps",)
    repeats: int | None = None
    """Runs per case and method (the suite's `repeats` when None)."""
    concurrency: int = 1
    """VLM calls made at once."""
    backend: str | None = None
    """None: offline, or litellm when a model or an API base is given."""
    model: str | None = None
    api_base: str | None = None
    cases: tuple[str, ...] = ()
    """Only these case ids (all when empty)."""
    n: int = 100
    """Ground-truth points of the metric D."""
    no_cache: bool = False
    """Always ask the VLM (never answer a run from the planner's answer cache)."""
    image_format: str = "jpg"
    """Each run's plan and outcome images: jpg (30 KB, 0.5 ms to write) or png (300 KB, 7 ms)."""
    outcome: str = "off"
    """Plan-only suites (equal parts): off (the plan is scored), predict (through the outcome
    stage, every plan accepted; the predicted cuts are scored) or repair (`--verify-outcome`:
    a wrong plan goes back to the VLM, one still wrong is refused). Executed suites run every
    motion, its verdict recorded, except under repair."""
    processes: int | None = 1
    """Worker processes sharing the runs in flight (1: every run in this process; None: one per
    core when there are enough runs, as `keymps eval` does). See keymps.eval.pool."""
    warm_planner: str = "off"
    """Whether litellm's calls go to the warm planner (keymps.planning.warm): off, use (when
    one is up: `keymps eval`'s default) or start."""


@dataclass(frozen=True)
class Job:
    case_id: str
    method: str
    repeat: int
    seed: int

    @property
    def label(self) -> str:
        return f"case {self.case_id} / {self.method} / repeat {self.repeat}"


def resolve_backend(options: EvalOptions) -> str:
    return backend_named(options.backend, options.model, options.api_base)


def backend_named(backend: str | None, model: str | None, api_base: str | None) -> str:
    """The planner backend of `keymps eval --backend --model --api-base`."""
    if backend:
        return backend
    return AUTO_VLM if (model or api_base) else AUTO_OFFLINE


def plan_jobs(suite: Suite, options: EvalOptions) -> list[Job]:
    from keymps.eval.methods import get_method

    for method in options.methods:
        get_method(method)
    cases = [suite.case(c) for c in options.cases] if options.cases else suite.cases
    repeats = options.repeats or suite.repeats
    # the methods of one scene next to each other: they share its rendering (scene cache)
    return [
        Job(case.id, method, r, case.scene.seed + r)
        for case in cases
        for r in range(repeats)
        for method in options.methods
    ]


RUN_BASE_CUTS = 2.0
"""A run's fixed work (scene, detection, plan, files) in straight cuts' worth."""


def heaviest_first(suite: Suite, jobs: list[Job]) -> list[Job]:
    """The jobs in the order they should start: the longest expected first, so that the last
    ones to finish are short and no process waits for a long run at the end (the methods of
    one scene stay next to each other)."""
    estimates = {case.id: expected_work(suite, case) for case in suite.cases}
    return sorted(jobs, key=lambda job: -estimates.get(job.case_id, 0.0))  # (stable)


def expected_work(suite: Suite, case: Any) -> float:
    """A run's expected computation in straight cuts' worth: its ground truth's cuts, each as
    long as its primitive's path is for a straight stroke (a sawing cut is about 3), plus
    RUN_BASE_CUTS. 0 without a ground truth (the suite's order is kept)."""
    truth = case.ground_truth or next((t for t in case.ground_truths or () if t), None)
    if truth is None:
        return 0.0
    cuts = truth.cuts
    if cuts.pattern == "parallel":
        if cuts.parts is not None:
            count = cuts.parts - 1
        elif cuts.fractions is not None:
            count = len(cuts.fractions)
        else:
            length = case.scene.length or 0.2
            count = cuts.count or max(1, int(length / cuts.spacing))
    elif cuts.pattern == "tips":
        count = 2
    elif cuts.pattern == "radial":
        count = cuts.parts // 2 if cuts.parts % 2 == 0 else cuts.parts
    else:
        count = cuts.count
    return RUN_BASE_CUTS + count * _path_ratio(truth.primitive, suite.folder)


@functools.lru_cache(maxsize=64)
def _path_ratio(primitive: str, folder: Path) -> float:
    """The primitive's path length for a 10 cm stroke over 10 cm (1 when it cannot be read)."""
    from keymps.primitives.dictionary import default_search_dirs, load_primitives

    try:
        found = load_primitives([primitive], default_search_dirs(folder))[primitive]
        points = np.asarray(found.rollout((0.0, 0.0, 0.0), (0.1, 0.0, 0.0)).y)
    except Exception:  # only the order of the jobs depends on it: the run reports the problem
        return 1.0
    return max(1.0, float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) / 0.1)


def _job_key(record: dict[str, Any]) -> tuple[Any, ...]:
    return (
        record.get("case"),
        record.get("method"),
        record.get("repeat"),
        record.get("backend"),
        record.get("model"),
    )


def read_results(path: Path) -> list[dict[str, Any]]:
    """Records of results.jsonl; a line cut short by an interruption is skipped."""
    if not path.is_file():
        return []
    records = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict):
            records.append(record)
    return records


class _ResultsFile:
    """Appends one record per line, flushed and synced, from any thread."""

    def __init__(self, path: Path):
        self.path = path
        self.lock = threading.Lock()
        if path.is_file() and path.stat().st_size:
            with path.open("rb") as handle:
                handle.seek(-1, os.SEEK_END)
                ends_cleanly = handle.read(1) == b"\n"
            if not ends_cleanly:  # a line cut short by an interruption: start a fresh line
                with path.open("a", encoding="utf-8") as handle:
                    handle.write("\n")

    def append(self, record: dict[str, Any]) -> None:
        line = json.dumps(record, allow_nan=False)
        with self.lock, self.path.open("a", encoding="utf-8") as handle:
            handle.write(line + "\n")
            handle.flush()
            os.fsync(handle.fileno())


def write_task_file(suite: Suite, job: Job, out: Path) -> Path:
    """The case's task for this seed as a task file (reusable with `keymps run`)."""
    import yaml

    from keymps.eval.tasks import case_task_data

    case = suite.case(job.case_id)
    data = case_task_data(suite, case, job.seed)
    data["name"] = f"{data['name']}-r{job.repeat}"
    path = out / "tasks" / job.method / f"{job.case_id}-r{job.repeat}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    header = f"# {suite.name} case {case.id}, method {job.method}, repeat {job.repeat}\n"
    dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml's: the same text, faster
    text = yaml.dump(data, Dumper=dumper, sort_keys=False)
    path.write_text(header + text, encoding="utf-8")
    return path


def prepare(suite: Suite, options: EvalOptions) -> None:
    """Folder set-up shared by the jobs: VLM-Keypoint's zero-weight primitives."""
    from keymps.eval.methods import get_method, zero_weight_primitives
    from keymps.primitives.dictionary import default_search_dirs

    for name in options.methods:
        if get_method(name).zero_weights:
            names = sorted(
                {p for c in suite.cases for p in (c.primitives or suite.primitives)}
                | {c.ground_truth.primitive for c in suite.cases if c.ground_truth}
                | {t.primitive for c in suite.cases for t in c.ground_truths or () if t}
            )
            zero_weight_primitives(
                names,
                default_search_dirs(suite.folder),
                options.out / "tasks" / name / "primitives",
            )


def _vlm_totals(calls: tuple[dict[str, Any], ...]) -> dict[str, Any]:
    def total(key: str) -> float | None:
        values = [c[key] for c in calls if c.get(key) is not None]
        return float(sum(values)) if values else None

    return {
        "vlm_calls": len(calls),
        "cached": sum(1 for c in calls if c.get("cached")),
        "cost_usd": total("cost_usd"),
        "prompt_tokens": total("prompt_tokens"),
        "completion_tokens": total("completion_tokens"),
        "vlm_latency_s": round(total("latency_s") or 0.0, 3),
    }


def job_record(suite: Suite, job: Job, options: EvalOptions, backend: str) -> dict[str, Any]:
    """The fields that name a run in results.jsonl, first in every record, failed or not."""
    return {
        "suite": suite.name,
        "case": job.case_id,
        "method": job.method,
        "repeat": job.repeat,
        "seed": job.seed,
        "backend": backend,
        "model": options.model,
        **({"outcome": options.outcome} if options.outcome != "off" else {}),
    }


def check_planner_options(suite: Suite, job: Job, options: EvalOptions) -> None:
    """--backend, --model and --api-base checked once on a case's task, as `keymps run` checks
    them: an unknown backend or a URL that is none is one error before the first run, not a
    failed record for every run and exit status 0."""
    from keymps.config.overrides import apply_overrides
    from keymps.config.task import load_task
    from keymps.planning.backend_choice import choose_backend

    if options.backend == "replay":  # keymps run's message would point to --cassette
        raise KeympsError(
            "--backend replay: keymps eval replays no cassette (every run asks its own "
            "question); identical requests are answered from the answer cache unless --no-cache"
        )
    task = load_task(write_task_file(suite, job, options.out))
    given = {"backend": options.backend, "model": options.model, "api_base": options.api_base}
    choose_backend(apply_overrides(task, given), options.backend, options.model, options.api_base)


def run_job(
    suite: Suite,
    job: Job,
    options: EvalOptions,
    backend: str,
    dispatch: Callable[[Any, Any], Any] | None = None,
) -> dict[str, Any]:
    """Run and score one job; failures become a record with ok = False and the error.

    `dispatch(backend, request)` makes its VLM calls (the broker's event loop)."""
    from keymps.eval.context import MethodContext
    from keymps.eval.methods import PartialRunError, get_method, partial_output

    started = time.perf_counter()
    folder = options.out / "runs" / job.method / job.case_id / f"r{job.repeat}"
    record = {
        **job_record(suite, job, options, backend),
        "folder": str(folder.relative_to(options.out)),
    }
    case = suite.case(job.case_id)
    output = None
    try:
        task_path = write_task_file(suite, job, options.out)
        context = MethodContext(
            task_path, folder, backend, options.model, options.api_base,
            plan_only=suite.kind == "equal_parts", no_cache=options.no_cache,
            image_format=options.image_format, dispatch=dispatch, outcome=options.outcome,
        )  # fmt: skip
        try:
            output = get_method(job.method).run(context)
            error: str | None = None
        except PartialRunError as stopped:
            output, error = partial_output(stopped, context), str(stopped)
        record.update(_score(suite, case, job, output, options.n))
        if error is not None:
            record["ok"], record["error"] = False, " ".join(error.split())
            record["success"] = False if record.get("success") is not None else None
    except KeympsError as failure:
        record.update(ok=False, error=" ".join(str(failure).split()))
    except Exception as failure:  # a bug must not stop the suite; keep where it happened
        where = traceback.extract_tb(failure.__traceback__)[-1]
        record.update(
            ok=False,
            error=f"internal error {type(failure).__name__}: {failure} "
            f"({Path(where.filename).name}:{where.lineno})",
        )
    if output is not None:
        _write_design(folder, output)
        record.update(_vlm_totals(output.calls))
        record["images"] = {
            k: str(Path(v).relative_to(options.out)) for k, v in output.images.items()
        }
    record["seconds"] = round(time.perf_counter() - started, 3)
    return record


def _write_design(folder: Path, output: Any) -> None:
    """design.json: what the method generated, seen from above (the equal-parts check's input)."""
    folder.mkdir(parents=True, exist_ok=True)
    design = {
        "keyword": output.keyword,
        "lines_m": np.round(np.asarray(output.lines_m, dtype=float), 6).tolist(),
        "work_pieces": len(output.work_pieces),
    }
    (folder / "design.json").write_text(json.dumps(design), encoding="utf-8")


def _score(suite: Suite, case: Any, job: Job, output: Any, n: int) -> dict[str, Any]:
    from keymps.eval.metric import metric_d_both
    from keymps.eval.truth import case_truth

    truth = case_truth(suite, case, job.seed, sidecar=output.scene)
    scored: dict[str, Any] = {
        "ok": True,
        "error": None,
        "keyword": output.keyword,
        "pieces": len(output.work_pieces),
    }
    truth_primitive = case.ground_truth.primitive if case.ground_truth is not None else None
    if case.ground_truths:
        truth_primitive = next(t.primitive for t in case.ground_truths if t is not None)
    if truth_primitive is not None:
        scored["truth_keyword"] = truth_primitive
        scored["truth_pieces"] = len(truth.pieces)
        if output.work_pieces:
            d, d_optimal = metric_d_both(truth.pieces, output.work_pieces, n)
            scored["d_mm"], scored["d_optimal_mm"] = round(1000 * d, 3), round(1000 * d_optimal, 3)
    if case.ground_truths:
        scored.update(_score_objects(case, truth, output, n))
    if suite.kind == "equal_parts" and suite.parts is not None:
        scene_object = truth.scene["objects"][0]
        scored.update(_equal_parts(suite, scene_object, output.lines_m))
        if output.cut_lines_m is not None:  # what the knife cuts: the edge reaches past a start
            from keymps.outcome.predict import PARTING_M

            design = scored["success"]
            scored.update(_equal_parts(suite, scene_object, output.cut_lines_m, PARTING_M))
            scored["design_success"] = design
    return scored


def _equal_parts(
    suite: Suite, scene_object: dict[str, Any], lines_m: np.ndarray, reach_m: float | None = None
) -> dict[str, Any]:
    """Appendix F's success by the outcome stage's verifier, on the object's true outline."""
    from keymps.outcome.verdict import equal_parts_problems

    assert suite.parts is not None
    hole = scene_object.get("hole_m")
    problems, pieces = equal_parts_problems(
        np.asarray(scene_object["outline_m"]),
        lines_m,
        suite.parts,
        suite.tolerance,
        np.asarray(hole) if hole else None,
        reach_m,
    )
    ideal = 1.0 / suite.parts
    worst = (
        max(abs(p.share - ideal) / ideal for p in pieces) if len(pieces) == suite.parts else None
    )
    if len(pieces) != suite.parts:
        detail = f"{len(pieces)} pieces, not {suite.parts}"
    else:
        detail = (
            f"{suite.parts} pieces, worst {100 * (worst or 0.0):.1f} % off an equal share "
            f"(limit {100 * suite.tolerance:g} %)"
        )
    return {
        "success": not problems,
        "parts": len(pieces),
        "parts_detail": detail,
        "worst_deviation": round(worst, 4) if worst is not None else None,
    }


def _score_objects(case: Any, truth: Any, output: Any, n: int) -> dict[str, Any]:
    """Several objects: D per object and over all, each generated work piece given to the true
    object under its middle (not to the one the planner said: the eval trusts no stage)."""
    from keymps.eval.metric import metric_d
    from keymps.eval.truth import objects_left_to_right

    objects = objects_left_to_right(truth.scene)
    mine: list[list[np.ndarray]] = [[] for _ in objects]
    for piece in output.work_pieces:
        points = np.asarray(piece, dtype=float)[:, :2]
        middle = points[len(points) // 2]
        distances = [_outside_m(middle, np.asarray(o["outline_m"])) for o in objects]
        mine[int(np.argmin(distances))].append(np.asarray(piece, dtype=float))
    per_object: list[float | None] = []
    for expected, generated in zip(truth.object_pieces, mine, strict=True):
        if expected and generated:
            per_object.append(round(1000 * metric_d(expected, generated, n), 3))
        else:
            per_object.append(None)
    wanted = [bool(t) for t in truth.object_pieces]
    return {
        "objects": len(objects),
        "d_objects_mm": per_object,
        "truth_pieces_per_object": [len(t) for t in truth.object_pieces],
        "pieces_per_object": [len(g) for g in mine],
        "right_objects": wanted == [bool(g) for g in mine],
    }


def _outside_m(point: np.ndarray, outline: np.ndarray) -> float:
    import cv2

    contour = np.asarray(outline, dtype=np.float32).reshape(-1, 1, 2)
    return max(0.0, -cv2.pointPolygonTest(contour, (float(point[0]), float(point[1])), True))


ProgressCallback = Callable[[Job, dict[str, Any]], None]


def run_suite(
    suite: Suite,
    options: EvalOptions,
    on_result: ProgressCallback | None = None,
) -> list[dict[str, Any]]:
    """Run every job not yet in out/results.jsonl; return all records for these jobs.

    Jobs start heaviest first (heaviest_first): the last to end are short, so neither core
    waits long for the other."""
    backend = resolve_backend(options)
    warm = _get_going(options, backend)
    jobs = plan_jobs(suite, options)
    if jobs:
        check_planner_options(suite, jobs[0], options)
    options.out.mkdir(parents=True, exist_ok=True)
    results = _ResultsFile(options.out / RESULTS_FILE)
    done = {_job_key(r): r for r in read_results(results.path) if r.get("suite") == suite.name}

    def key(job: Job) -> tuple[Any, ...]:
        return (job.case_id, job.method, job.repeat, backend, options.model)

    todo = heaviest_first(suite, [job for job in jobs if key(job) not in done])
    prepare(suite, options)
    records = {key(job): done[key(job)] for job in jobs if key(job) in done}
    if on_result:
        for job in jobs:
            if key(job) in done:
                on_result(job, done[key(job)])

    def finished(job: Job, record: dict[str, Any]) -> None:
        record = redact(record)  # results.jsonl, the summaries and the gallery come from it
        results.append(record)
        records[key(job)] = record
        if on_result:
            on_result(job, record)

    _run_jobs(suite, todo, options, backend, warm, finished)
    return [records[key(job)] for job in jobs]


def _get_going(options: EvalOptions, backend: str) -> WarmDispatch | None:
    """Refuse a method the backend cannot run; the planner's warm-up (keymps eval began it
    earlier), or None."""
    from keymps.eval.methods import check_runnable, get_method
    from keymps.eval.pool import get_going

    for name in options.methods:
        check_runnable(get_method(name), backend)
    given = (options.model, options.api_base, options.concurrency, options.processes)
    return get_going(backend, *given, options.warm_planner)


def _run_jobs(
    suite: Suite,
    todo: list[Job],
    options: EvalOptions,
    backend: str,
    warm: WarmDispatch | None,
    finished: ProgressCallback,
) -> None:
    """Run the jobs in processes, or in threads of this one, all through one VLM broker."""
    from keymps.eval.broker import BROKERED_BACKEND, VlmBroker
    from keymps.eval.pool import OFFLINE_BACKENDS, JobRunner, default_processes, run_in_processes
    from keymps.eval.turn import CpuTurn

    processes = options.processes or default_processes(options.concurrency, len(todo), backend)
    if backend not in OFFLINE_BACKENDS:  # more processes than VLM calls would only wait
        processes = min(processes, options.concurrency)
    # given up by the broker while a run of this process waits for the VLM
    turn = CpuTurn(active=backend == BROKERED_BACKEND)
    warm_up = backend == BROKERED_BACKEND and bool(todo) and warm is None
    broker = VlmBroker(options.concurrency, warm_up=warm_up, turn=turn, via=warm)
    try:
        if processes > 1:
            runner = JobRunner(run=run_job, record=job_record)
            run_in_processes(suite, todo, options, backend, processes, finished, broker, runner)
        else:
            _run_in_threads(suite, todo, options, backend, finished, broker, turn)
    finally:
        broker.close()


def _run_in_threads(
    suite: Suite,
    jobs: list[Job],
    options: EvalOptions,
    backend: str,
    finished: ProgressCallback,
    broker: VlmBroker,
    turn: CpuTurn,
) -> None:
    """Run `jobs` in threads of this process, taking turns to compute."""
    from keymps.eval.pool import runs_in_flight

    pool = ThreadPoolExecutor(max_workers=runs_in_flight(options.concurrency, 1, backend))
    try:
        futures = {
            pool.submit(turn.run, run_job, suite, job, options, backend, broker.complete): job
            for job in jobs
        }
        for future in as_completed(futures):
            finished(futures[future], future.result())
    finally:
        broker.close()  # on an interruption, the runs waiting for the VLM stop at once
        pool.shutdown(wait=True, cancel_futures=True)
