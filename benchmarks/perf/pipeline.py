"""A whole run against its floors: start-up, warm computation, each stage, recording, eval.

Run: python benchmarks/perf/pipeline.py [--repeats 5] [--eval-repeats 1] [--eval-times 3] [--skip-eval]
         [--baseline-python /path/to/venv/bin/python]

Everything is measured in this one run, interleaved (A, B, A, B ...) so that a busy machine
slows a figure and its floor alike; medians are printed with the load average (`uptime`) at the
time. Figures:

- `cli_vs_import_floor`: `keymps run tasks/cake_icing.yaml --rerun off` against a bare
  `python -c "import numpy, pinocchio, cv2"` (the imports no run can avoid).
- `warm_ms_per_trajectory_s_{icing,cutting}`: a second run of the task in one process (models
  and caches warm), every stage's time summed, per second of trajectory; with the allocator
  setting of the keymps command and its eval workers (keymps/_memory.py), and again with the C
  library's default, as a program calling run_task has it (`..._default_malloc`). No run finds
  the path grids the run before it built (a new task would not).
- per stage against its floor, same inputs: closed-form vs iterative IK, numpy vs per-call
  Ruckig sampling, batched vs per-configuration Pinocchio forward kinematics, vectorized vs
  per-point footprint test.
- `icing_recording_mb`: run.rrd of the icing run with the recording on.
- `eval_cutting_sim_runs_per_s`: `keymps eval cutting_sim` (offline, default processes), the
  median of --eval-times whole commands.

With --baseline-python (an interpreter with another version of keymps installed, e.g. a venv
with main's checkout), the CLI run, the warm computation, the recording and the eval are also
measured for that version, interleaved with this one's: before/after figures from one run, on
one machine load.

Every command runs with keymps' bytecode compiled beforehand (into the checkout's __pycache__
folders, which git ignores), as pip leaves an installed package and as a checkout is after its
first run: without that, PYTHONDONTWRITEBYTECODE and a checkout without __pycache__ make every
run compile all of keymps again (about 0.1 s per process). `--no-bytecode` measures that case.
(A PYTHONPYCACHEPREFIX would also move every installed package's bytecode, which would then be
compiled again by the first command of each kind.)

Targets: cli_vs_import_floor <= 2.5, warm_ms_per_trajectory_s <= 4, icing_recording_mb < 2,
eval_cutting_sim_runs_per_s > 8 (2 cores). The last lines are machine-readable `name: value`.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from keymps.run import RunOptions, RunOverrides

ROOT = Path(__file__).resolve().parents[2]
CLI = ["-c", "from keymps.cli import main; main()"]
KEYMPS = [sys.executable, *CLI]
TASKS = {"icing": ROOT / "tasks/cake_icing.yaml", "cutting": ROOT / "tasks/object_cutting.yaml"}


def load() -> str:
    """The 1-minute load average, as `uptime` shows it."""
    return f"{os.getloadavg()[0]:.2f}"


def interleaved(functions: dict[str, Callable[[], Any]], repeats: int) -> dict[str, float]:
    """Median seconds of each function, called in turn `repeats` times."""
    times: dict[str, list[float]] = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            started = time.perf_counter()
            function()
            times[name].append(time.perf_counter() - started)
    return {name: statistics.median(values) for name, values in times.items()}


def command(arguments: list[str], cwd: str | None = None) -> Callable[[], None]:
    def run() -> None:
        subprocess.run(arguments, check=True, capture_output=True, cwd=cwd)

    return run


def where(baseline: Path | None) -> str | None:
    """The baseline runs outside this checkout (`python -c` puts the current folder first on
    sys.path, where this checkout's keymps would shadow the baseline's)."""
    return tempfile.gettempdir() if baseline is not None else None


def keymps(baseline: Path | None) -> list[str]:
    """The `keymps` command of this interpreter, or of the baseline interpreter."""
    return [str(baseline), *CLI] if baseline is not None else KEYMPS


def startup(repeats: int, folder: Path, baseline: Path | None) -> dict[str, float]:
    python = sys.executable
    task = [str(TASKS["icing"]), "--rerun", "off", "--out"]
    functions = {
        "import_floor": command([python, "-c", "import numpy, pinocchio, cv2"]),
        "cli_run": command([*KEYMPS, "run", *task, str(folder / "cli")]),
    }
    if baseline is not None:
        functions["cli_run_baseline"] = command(
            [*keymps(baseline), "run", *task, str(folder / "cli-baseline")], where(baseline)
        )
    interleaved(functions, 1)  # warm the file cache
    return interleaved(functions, repeats)


WARM_SCRIPT = """
import json, sys, tempfile
if sys.argv[3] == "keymps":  # the allocator setting of the keymps command and eval workers
    try:
        from keymps._memory import keep_freed_memory
        keep_freed_memory()
    except ImportError:  # a baseline from before it
        pass
from keymps import load_task, run_task
try:
    from keymps.run import RunOptions, RunOverrides
except ImportError:  # a baseline from before them: its run_task took their fields by name
    RunOverrides = None

def run(task, out):
    try:  # no run finds the path grids of the run before (a new task would not)
        from keymps.robot.safety_geometry import _GRIDS
        _GRIDS.clear()
    except ImportError:
        pass
    changes = {"out": out, "backend": "offline", "executor": "sim"}
    if RunOverrides is None:
        return run_task(task, rerun="off", **changes)
    return run_task(task, options=RunOptions(rerun="off"), overrides=RunOverrides(**changes))

out = {}
with tempfile.TemporaryDirectory() as folder:
    for name, path in json.loads(sys.argv[1]).items():
        task = load_task(path)
        run(task, folder + "/cold")
        runs = [run(task, f"{folder}/{name}{i}") for i in range(int(sys.argv[2]))]
        out[name] = {
            "totals": [sum(run.timings_s.values()) for run in runs],
            "stages": [dict(run.timings_s) for run in runs],
            "duration_s": float(runs[-1].stages.time.duration_s),
        }
print(json.dumps(out))
"""


def warm_computation(
    repeats: int, baseline: Path | None, allocator: str = "keymps"
) -> dict[str, dict[str, Any]]:
    """Warm runs of each task in a fresh process (this checkout's or the baseline's), with the
    allocator setting of the keymps command ("keymps") or the C library's default."""
    import json

    tasks = json.dumps({name: str(path) for name, path in TASKS.items()})
    done = subprocess.run(
        [str(baseline or sys.executable), "-c", WARM_SCRIPT, tasks, str(repeats), allocator],
        check=True,
        capture_output=True,
        text=True,
        cwd=where(baseline),
    )
    measured: dict[str, dict[str, Any]] = json.loads(done.stdout.strip().splitlines()[-1])
    for item in measured.values():
        item["computation_s"] = statistics.median(item["totals"])
        item["stages"] = {
            k: statistics.median(s[k] for s in item["stages"]) for k in item["stages"][0]
        }
    return measured


def warm_runs(folder: Path) -> dict[str, dict[str, Any]]:
    """One warm run of each task in this process: the inputs of the stage floors."""
    from keymps import load_task, run_task

    out: dict[str, dict[str, Any]] = {}
    for name, path in TASKS.items():
        task = load_task(path)
        run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=folder / f"cold-{name}", backend="offline", executor="sim"),
        )
        run = run_task(
            task,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(out=folder / name, backend="offline", executor="sim"),
        )
        out[name] = {"run": run, "task": task}
    return out


def stage_floors(warm: dict[str, dict[str, Any]], repeats: int) -> dict[str, dict[str, float]]:
    """Each optimized stage against the implementation it replaced, on the cutting run."""
    import numpy as np

    from keymps.motion.timing import Limits, _profile
    from keymps.robot.model import RobotModel

    results: dict[str, dict[str, float]] = {}
    for name, item in warm.items():
        run, task = item["run"], item["task"]
        model = RobotModel.from_task(task)
        tool_path, trajectory = run.stages.compose, run.stages.time
        points = np.concatenate([p.points for p in tool_path.pieces])
        yaws = np.concatenate([p.yaw for p in tool_path.pieces])
        seed = model.tool_down_seed(points[0], float(yaws[0]))
        profile, duration = _profile(0.2, Limits(0.15, 1.0, 20.0), 1 / 125)
        times = np.arange(0.0, duration, 0.001)
        outline = run.outline_m
        xy = np.asarray(trajectory.tool_xyz)[:, :2]
        pairs = _stage_pairs(model, points, yaws, seed, profile, times, trajectory.q, xy, outline)
        pairs.update(_timing_pair(model, tool_path, run.stages.solve, task))
        measured = interleaved(pairs, repeats)
        results[name] = measured
    return results


def _stage_pairs(
    model: Any,
    points: Any,
    yaws: Any,
    seed: Any,
    profile: Any,
    times: Any,
    qs: Any,
    xy: Any,
    outline: Any,
) -> dict[str, Callable[[], Any]]:
    from keymps.motion.timing import _sample_profile_by_calls
    from keymps.robot.safety_geometry import outside_distance

    reference = _reference_timing()
    return {
        "ik_closed_form": lambda: model.solve_points(points, yaws, seed),
        "ik_iterative": lambda: model.solve_points(points, yaws, seed, method="iterative"),
        "profile_numpy": lambda: reference.sample_profile(profile, times),
        "profile_calls": lambda: _sample_profile_by_calls(profile, times),
        "fk_batched": lambda: model.tool_poses(qs),
        "fk_per_call": lambda: model.pinocchio_tool_poses(qs),
        "footprint_vectorized": lambda: outside_distance(xy, outline),
        "footprint_per_point": lambda: _footprint_per_point(xy, outline),
    }


def _timing_pair(
    model: Any, tool_path: Any, joint_path: Any, task: Any
) -> dict[str, Callable[[], Any]]:
    """The joint-limit timing of every stroke: all strokes at once against one by one."""
    import math

    from keymps.motion.timing import Limits, split_strokes, time_strokes_at_once

    time_stroke = _reference_timing().time_stroke
    strokes = split_strokes(model, tool_path, joint_path)
    limits = Limits(math.inf, task.robot.max_tool_acceleration, task.robot.max_tool_jerk)
    period = 1.0 / float(task.robot.rate_hz or model.rate_hz)
    return {
        "timing_at_once": lambda: time_strokes_at_once(model, strokes, limits, period),
        "timing_by_stroke": lambda: [time_stroke(model, s, limits, period) for s in strokes],
    }


def _reference_timing() -> Any:
    """tests/helpers/reference_timing.py: the timing one profile and one stroke at a time, as
    it was before the batched paths replaced it (and the reference the tests hold them to)."""
    tests = str(ROOT / "tests")
    if tests not in sys.path:
        sys.path.append(tests)
    from helpers import reference_timing

    return reference_timing


def _footprint_per_point(points: Any, polygon: Any) -> Any:
    """The footprint test as it was: one OpenCV call per point."""
    import cv2
    import numpy as np

    contour = np.asarray(polygon, dtype=np.float32).reshape(-1, 1, 2)
    return np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in points])


def recording_size(folder: Path, baseline: Path | None = None) -> float:
    target = folder / ("recorded-baseline" if baseline else "recorded")
    subprocess.run(
        [*keymps(baseline), "run", str(TASKS["icing"]), "--out", str(target)],
        check=True,
        capture_output=True,
        cwd=where(baseline),
    )
    return (target / "run.rrd").stat().st_size / 1e6


def eval_rate(
    folder: Path, repeats: int, baseline: Path | None = None, attempt: int = 0
) -> tuple[float, int]:
    """Runs per second of one whole `keymps eval cutting_sim` (a new results folder)."""
    out = folder / f"{'eval-baseline' if baseline else 'eval'}-{attempt}"
    arguments = [*keymps(baseline), "eval", "cutting_sim", "--quiet"]
    arguments += ["--out", str(out), "--repeats", str(repeats), "--backend", "offline"]
    started = time.perf_counter()
    subprocess.run(arguments, check=True, capture_output=True, cwd=where(baseline))
    elapsed = time.perf_counter() - started
    runs = sum(1 for _ in (out / "results.jsonl").open())
    return runs / elapsed, runs


def cache_bytecode(pythons: list[str]) -> None:
    """Compile each interpreter's keymps where Python keeps bytecode (its __pycache__ folders,
    ignored by git), and let every child read and write bytecode as on a user's machine."""
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    compile_keymps = (
        "import compileall, os, keymps; "
        "compileall.compile_dir(os.path.dirname(keymps.__file__), quiet=1)"
    )
    for python in pythons:
        subprocess.run([python, "-c", compile_keymps], check=True, cwd=tempfile.gettempdir())


Lines = list[tuple[str, str]]
"""The machine-readable `name: value` lines, in the order they are printed."""


def startup_lines(repeats: int, folder: Path, baseline: Path | None) -> Lines:
    """The CLI run against the import floor (and the baseline's CLI run)."""
    measured = startup(repeats, folder, baseline)
    ratio = measured["cli_run"] / measured["import_floor"]
    print(
        f"start-up (load {load()}): import floor {measured['import_floor'] * 1000:.0f} ms, "
        f"keymps run --rerun off {measured['cli_run'] * 1000:.0f} ms, ratio {ratio:.2f}"
    )
    lines = [("cli_vs_import_floor", f"{ratio:.2f}")]
    lines += [("cli_run_s", f"{measured['cli_run']:.3f}")]
    lines += [("import_floor_s", f"{measured['import_floor']:.3f}")]
    if baseline is not None:
        before = measured["cli_run_baseline"] / measured["import_floor"]
        print(
            f"  baseline keymps run {measured['cli_run_baseline'] * 1000:.0f} ms, ratio {before:.2f}"
        )
        lines += [("baseline_cli_vs_import_floor", f"{before:.2f}")]
    return lines


def warm_lines(repeats: int, sources: dict[str, Path | None]) -> Lines:
    """Warm milliseconds per second of trajectory of each task and source: as the keymps
    command and eval workers run (the headline), then with the C library's default allocator,
    as a program calling run_task has it (keymps/_memory.py)."""
    lines: Lines = []
    for allocator, suffix in (("keymps", ""), ("default", "_default_malloc")):
        warm = interleaved_warm_runs(repeats, sources, allocator)
        for prefix, measured_warm in warm.items():
            for name, item in measured_warm.items():
                computation = statistics.median(item["all"])
                per_second = computation * 1000 / item["duration_s"]
                stages = " ".join(f"{k} {v * 1000:.1f}" for k, v in item["stages"].items())
                print(
                    f"{prefix or 'this '}warm {name}, {allocator} allocator (load {load()}): "
                    f"{computation * 1000:.0f} ms for {item['duration_s']:.1f} s of "
                    f"trajectory = {per_second:.2f} ms per s; stages (ms): {stages}"
                )
                key = f"{prefix}warm_ms_per_trajectory_s_{name}{suffix}"
                lines.append((key, f"{per_second:.2f}"))
    return lines


def interleaved_warm_runs(
    repeats: int, sources: dict[str, Path | None], allocator: str
) -> dict[str, dict[str, dict[str, Any]]]:
    """warm_computation of each source, in two interleaved halves when there is a baseline;
    each task's totals of both halves gathered under "all"."""
    warm: dict[str, dict[str, dict[str, Any]]] = {prefix: {} for prefix in sources}
    for _ in range(2 if len(sources) > 1 else 1):
        for prefix, source in sources.items():
            half = warm_computation(max(1, repeats // 2), source, allocator)
            for name, item in half.items():
                kept = warm[prefix].setdefault(name, {**item, "all": []})
                kept["all"] += item["totals"]
    return warm


FLOOR_PAIRS = (
    ("ik_closed_form", "ik_iterative"),
    ("profile_numpy", "profile_calls"),
    ("fk_batched", "fk_per_call"),
    ("footprint_vectorized", "footprint_per_point"),
    ("timing_at_once", "timing_by_stroke"),
)
"""(keymps' stage, the floor it is held against), as stage_floors names them."""


def floor_lines(folder: Path, repeats: int) -> Lines:
    """Each stage's speed-up over the implementation it replaced, per task."""
    lines: Lines = []
    for name, measured_stages in stage_floors(warm_runs(folder), repeats).items():
        print(f"stages against their floors, {name} (load {load()}):")
        for fast, slow in FLOOR_PAIRS:
            a, b = measured_stages[fast], measured_stages[slow]
            print(
                f"  {fast:22s} {a * 1000:8.2f} ms   {slow:20s} {b * 1000:8.2f} ms   {b / a:6.1f}x"
            )
            lines.append((f"{fast}_speedup_{name}", f"{b / a:.1f}"))
    return lines


def recording_lines(folder: Path, sources: dict[str, Path | None]) -> Lines:
    """The size of the icing run's recording, per source."""
    lines: Lines = []
    for prefix, source in sources.items():
        size = recording_size(folder, source)
        print(f"{prefix or 'this '}icing recording (load {load()}): {size:.2f} MB")
        lines.append((f"{prefix}icing_recording_mb", f"{size:.2f}"))
    return lines


def eval_lines(folder: Path, times: int, repeats: int, sources: dict[str, Path | None]) -> Lines:
    """The median runs per second of `times` whole eval commands per source, interleaved."""
    rates: dict[str, list[float]] = {prefix: [] for prefix in sources}
    runs = 0
    for attempt in range(max(1, times)):
        for prefix, source in sources.items():
            rate, runs = eval_rate(folder, repeats, source, attempt)
            rates[prefix].append(rate)
    lines: Lines = []
    for prefix, measured in rates.items():
        shown = ", ".join(f"{rate:.2f}" for rate in measured)
        median = statistics.median(measured)
        print(
            f"{prefix or 'this '}eval cutting_sim (load {load()}): {runs} runs, "
            f"median {median:.2f} runs/s ({shown})"
        )
        lines.append((f"{prefix}eval_cutting_sim_runs_per_s", f"{median:.2f}"))
    return lines


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--eval-repeats", type=int, default=1, help="cutting_sim repeats per case")
    parser.add_argument(
        "--eval-times", type=int, default=3, help="whole eval commands measured (the median)"
    )
    parser.add_argument("--skip-eval", action="store_true")
    parser.add_argument(
        "--baseline-python", type=Path, help="an interpreter with another keymps to compare with"
    )
    parser.add_argument(
        "--no-bytecode",
        action="store_true",
        help="leave keymps' bytecode as the environment has it",
    )
    parser.add_argument(
        "--quick", action="store_true", help="one repeat of everything: checks the script runs (CI)"
    )
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.eval_times = 1, 1
    return args


def main() -> None:
    args = parse_arguments()
    baseline = args.baseline_python
    sources = {"": None} if baseline is None else {"": None, "baseline_": baseline}
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        if not args.no_bytecode:
            cache_bytecode([sys.executable] + ([str(baseline)] if baseline else []))
        cached = "not cached" if args.no_bytecode else "cached"
        print(f"load {load()} at start; {os.cpu_count()} cores; keymps bytecode {cached}")
        lines = startup_lines(args.repeats, folder, baseline)
        lines += warm_lines(args.repeats, sources)
        lines += floor_lines(folder, args.repeats)
        lines += recording_lines(folder, sources)
        if not args.skip_eval:
            lines += eval_lines(folder, args.eval_times, args.eval_repeats, sources)
        lines.append(("bytecode_cached", str(int(not args.no_bytecode))))
        lines.append(("load_average", load()))
    for name, value in lines:
        print(f"{name}: {value}")


if __name__ == "__main__":
    main()
