"""A whole run against its floors: start-up, warm computation, each stage, recording, eval.

Run: python benchmarks/perf/pipeline.py [--repeats 5] [--eval-repeats 1] [--skip-eval]

Everything is measured in this one run, interleaved (A, B, A, B ...) so that a busy machine
slows a figure and its floor alike; medians are printed with the load average (`uptime`) at the
time. Figures:

- `cli_vs_import_floor`: `keymps run tasks/cake_icing.yaml --rerun off` against a bare
  `python -c "import numpy, pinocchio, cv2"` (the imports no run can avoid).
- `warm_ms_per_trajectory_s_{icing,cutting}`: a second run of the task in one process (models
  and caches warm), every stage's time summed, per second of trajectory.
- per stage against its floor, same inputs: closed-form vs iterative IK, numpy vs per-call
  Ruckig sampling, batched vs per-configuration Pinocchio forward kinematics, vectorized vs
  per-point footprint test.
- `icing_recording_mb`: run.rrd of the icing run with the recording on.
- `eval_cutting_sim_runs_per_s`: `keymps eval cutting_sim` (offline, default processes).

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

ROOT = Path(__file__).resolve().parents[2]
KEYMPS = [sys.executable, "-c", "from keymps.cli import main; main()"]
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


def command(arguments: list[str]) -> Callable[[], None]:
    def run() -> None:
        subprocess.run(arguments, check=True, capture_output=True)

    return run


def startup(repeats: int, folder: Path) -> dict[str, float]:
    python = sys.executable
    cli = [*KEYMPS, "run", str(TASKS["icing"]), "--rerun", "off"]
    cli += ["--out", str(folder / "cli")]
    measured = interleaved(
        {
            "import_floor": command([python, "-c", "import numpy, pinocchio, cv2"]),
            "cli_run": command(cli),
        },
        repeats,
    )
    return measured


def warm_runs(repeats: int, folder: Path) -> dict[str, dict[str, Any]]:
    from keymps import load_task, run_task

    out: dict[str, dict[str, Any]] = {}
    for name, path in TASKS.items():
        task = load_task(path)
        run_task(task, out=folder / f"cold-{name}", rerun="off", backend="offline", executor="sim")
        totals, stages = [], []
        for repeat in range(repeats):
            run = run_task(
                task,
                out=folder / f"{name}-{repeat}",
                rerun="off",
                backend="offline",
                executor="sim",
            )
            stages.append(dict(run.timings_s))
            totals.append(sum(run.timings_s.values()))
        duration = float(run.results["time"].duration_s)
        median = statistics.median(totals)
        out[name] = {
            "run": run,
            "task": task,
            "duration_s": duration,
            "computation_s": median,
            "stages": {k: statistics.median(s[k] for s in stages) for k in stages[0]},
        }
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
        tool_path, trajectory = run.results["compose"], run.results["time"]
        points = np.concatenate([p.points for p in tool_path.pieces])
        yaws = np.concatenate([p.yaw for p in tool_path.pieces])
        seed = model.tool_down_seed(points[0], float(yaws[0]))
        profile, duration = _profile(0.2, Limits(0.15, 1.0, 20.0), 1 / 125)
        times = np.arange(0.0, duration, 0.001)
        from keymps.perception.frames import object_outline_m

        outline = object_outline_m(run.results["detect"], task, run.results["image"].size_px)
        xy = np.asarray(trajectory.tool_xyz)[:, :2]
        pairs = _stage_pairs(model, points, yaws, seed, profile, times, trajectory.q, xy, outline)
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
    from keymps.motion.timing import _sample_profile, _sample_profile_by_calls
    from keymps.robot.safety_geometry import outside_distance

    return {
        "ik_closed_form": lambda: model.solve_points(points, yaws, seed),
        "ik_iterative": lambda: model.solve_points(points, yaws, seed, method="iterative"),
        "profile_numpy": lambda: _sample_profile(profile, times),
        "profile_calls": lambda: _sample_profile_by_calls(profile, times),
        "fk_batched": lambda: model.tool_poses(qs),
        "fk_per_call": lambda: model.pinocchio_tool_poses(qs),
        "footprint_vectorized": lambda: outside_distance(xy, outline),
        "footprint_per_point": lambda: _footprint_per_point(xy, outline),
    }


def _footprint_per_point(points: Any, polygon: Any) -> Any:
    """The footprint test as it was: one OpenCV call per point."""
    import cv2
    import numpy as np

    contour = np.asarray(polygon, dtype=np.float32).reshape(-1, 1, 2)
    return np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in points])


def recording_size(folder: Path) -> float:
    target = folder / "recorded"
    subprocess.run(
        [*KEYMPS, "run", str(TASKS["icing"]), "--out", str(target)],
        check=True,
        capture_output=True,
    )
    return (target / "run.rrd").stat().st_size / 1e6


def eval_rate(folder: Path, repeats: int) -> tuple[float, int]:
    out = folder / "eval"
    arguments = [*KEYMPS, "eval", "cutting_sim", "--quiet"]
    arguments += ["--out", str(out), "--repeats", str(repeats), "--backend", "offline"]
    started = time.perf_counter()
    subprocess.run(arguments, check=True, capture_output=True)
    elapsed = time.perf_counter() - started
    runs = sum(1 for _ in (out / "results.jsonl").open())
    return runs / elapsed, runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--eval-repeats", type=int, default=1, help="cutting_sim repeats per case")
    parser.add_argument("--skip-eval", action="store_true")
    args = parser.parse_args()
    lines: list[tuple[str, str]] = []
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        print(f"load {load()} at start; {os.cpu_count()} cores")

        measured = startup(args.repeats, folder)
        ratio = measured["cli_run"] / measured["import_floor"]
        print(
            f"start-up (load {load()}): import floor {measured['import_floor'] * 1000:.0f} ms, "
            f"keymps run --rerun off {measured['cli_run'] * 1000:.0f} ms, ratio {ratio:.2f}"
        )
        lines += [("cli_vs_import_floor", f"{ratio:.2f}")]
        lines += [("cli_run_s", f"{measured['cli_run']:.3f}")]
        lines += [("import_floor_s", f"{measured['import_floor']:.3f}")]

        warm = warm_runs(args.repeats, folder)
        for name, item in warm.items():
            per_second = item["computation_s"] * 1000 / item["duration_s"]
            stages = " ".join(f"{k} {v * 1000:.1f}" for k, v in item["stages"].items())
            print(
                f"warm {name} (load {load()}): {item['computation_s'] * 1000:.0f} ms for "
                f"{item['duration_s']:.1f} s of trajectory = {per_second:.2f} ms per s; "
                f"stages (ms): {stages}"
            )
            lines.append((f"warm_ms_per_trajectory_s_{name}", f"{per_second:.2f}"))

        floors = stage_floors(warm, args.repeats)
        for name, measured_stages in floors.items():
            print(f"stages against their floors, {name} (load {load()}):")
            for fast, slow in (
                ("ik_closed_form", "ik_iterative"),
                ("profile_numpy", "profile_calls"),
                ("fk_batched", "fk_per_call"),
                ("footprint_vectorized", "footprint_per_point"),
            ):
                a, b = measured_stages[fast], measured_stages[slow]
                print(
                    f"  {fast:22s} {a * 1000:8.2f} ms   {slow:20s} {b * 1000:8.2f} ms   {b / a:6.1f}x"
                )
                lines.append((f"{fast}_speedup_{name}", f"{b / a:.1f}"))

        size = recording_size(folder)
        print(f"icing recording (load {load()}): {size:.2f} MB")
        lines.append(("icing_recording_mb", f"{size:.2f}"))

        if not args.skip_eval:
            rate, runs = eval_rate(folder, args.eval_repeats)
            print(f"eval cutting_sim (load {load()}): {runs} runs, {rate:.2f} runs/s")
            lines.append(("eval_cutting_sim_runs_per_s", f"{rate:.2f}"))
        lines.append(("load_average", load()))
    for name, value in lines:
        print(f"{name}: {value}")


if __name__ == "__main__":
    main()
