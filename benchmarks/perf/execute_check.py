"""The check and execute stages and trajectory.csv, this checkout against an earlier commit's,
interleaved in one process on the same warm runs.

Run: python benchmarks/perf/execute_check.py [--baseline a668308] [--repeats 15]

The baseline's sim executor, cut sweep, safety check, distances, batched forward kinematics,
trajectory CSV writer and PNG writer are loaded from `git show <baseline>:<file>` as modules of
their own; everything else (task loading, the planned runs, the robot model) is this checkout's.
Each repeat times `validate`, `write_trajectory_csv` and `SimExecutor.execute` of both versions
in turn (the order alternating), on the icing and the cutting run of the offline planner. The
first round is a warm-up whose reports are compared: the sim and validation figures of the two
versions, to 1e-9 relative.

Prints medians and minimums (the minimum is the steadier figure on a shared machine) and, last,
machine-readable `name: value` lines of the median speed-ups.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from keymps.run import RunOptions, RunOverrides

ROOT = Path(__file__).resolve().parents[2]
TASKS = {"icing": "tasks/cake_icing.yaml", "cutting": "tasks/object_cutting.yaml"}
STAGES = ("check", "csv", "execute")


MOVED = {
    b"from keymps.run import write_atomically": b"from keymps.run_files import write_atomically"
}
"""Imports of names that have moved since the baseline, as this checkout spells them."""


def baseline_module(name: str, path: str, commit: str, folder: Path) -> ModuleType:
    """keymps/<path> as it was at `commit`, imported as module `name`."""
    source = subprocess.run(
        ["git", "show", f"{commit}:keymps/{path}"], cwd=ROOT, check=True, capture_output=True
    ).stdout
    for old, new in MOVED.items():
        source = source.replace(old, new)
    file = folder / f"{name}.py"
    file.write_bytes(source)
    spec = importlib.util.spec_from_file_location(name, file)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


class Baseline:
    """The baseline's modules, wired to each other instead of to this checkout's."""

    def __init__(self, commit: str, folder: Path):
        def load(name: str, path: str) -> ModuleType:
            return baseline_module(f"baseline_{name}", path, commit, folder)

        self.geometry = load("safety_geometry", "robot/safety_geometry.py")
        self.batch_fk = load("batch_fk", "robot/batch_fk.py")
        self.cut_sweep = load("cut_sweep", "default_plugins/sim/cut_sweep.py")
        self.run_module = load("run", "run.py")
        self.trajectory_io = load("trajectory_io", "motion/trajectory_io.py")
        # the baseline's executor imports its cut_sweep by the path it had then (now
        # keymps.outcome.cut_sweep): that name is the baseline's module while it loads
        sys.modules.setdefault("keymps.default_plugins.sim.cut_sweep", self.cut_sweep)
        self.executor = load("executor", "default_plugins/sim/executor.py")
        self.executor.covered_length = self.cut_sweep.covered_length
        self.executor.Footprint = self.cut_sweep.Footprint
        self.safety = load("safety", "robot/safety.py")
        self.safety.distance_to_polylines = self.geometry.distance_to_polylines
        self.safety.outside_distance = self.geometry.outside_distance

    @contextlib.contextmanager
    def installed(self, run: Any) -> Iterator[None]:
        """The baseline's distances, PNG writer and forward kinematics for the block."""
        import keymps.run_files as files

        saved = sys.modules["keymps.robot.safety_geometry"], files.write_image, run.robot
        sys.modules["keymps.robot.safety_geometry"] = self.geometry  # imported inside functions
        files.write_image = self.run_module.write_image
        run.robot = BaselineKinematics(run.robot, self.batch_fk)
        try:
            yield
        finally:
            sys.modules["keymps.robot.safety_geometry"], files.write_image, run.robot = saved


class BaselineKinematics:
    """A robot model whose batched forward kinematics are the baseline's."""

    def __init__(self, model: Any, batch_fk: ModuleType):
        self._model = model
        self._batch = batch_fk.BatchKinematics.for_model(model.model)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._model, name)

    def tool_poses(self, qs: Any, *_: Any) -> Any:
        frame = self._model._tcp_frame
        return self._batch.frame_poses(qs, frame.parentJoint, frame.placement)

    def joint_origins_many(self, qs: Any) -> Any:
        flange = self._model._flange
        return self._batch.origins(qs, (flange.parentJoint, flange.placement))


def stages_once(run: Any, version: str, baseline: Baseline) -> tuple[dict[str, float], Any]:
    """Seconds of check, csv and execute of one version, and its reports."""
    from keymps.default_plugins.sim import executor
    from keymps.motion.trajectory_io import write_trajectory_csv
    from keymps.robot import safety_geometry
    from keymps.robot.safety import validate

    trajectory, tool_path = run.stages.check.trajectory, run.stages.compose
    context: Any = contextlib.nullcontext()
    check, write_csv, sim = validate, write_trajectory_csv, executor
    if version == "baseline":
        context = baseline.installed(run)
        check, sim = baseline.safety.validate, baseline.executor
        write_csv = baseline.trajectory_io.write_trajectory_csv
    seconds: dict[str, float] = {}
    with context:
        # as in a run of a new task: the check builds the path's distance grids, the sim reuses
        # them (a warm run of the same task finds them from the run before)
        safety_geometry._GRIDS.clear()
        started = time.perf_counter()
        validated = check(run.robot, trajectory, tool_path, run.objects, run.task)
        seconds["check"] = time.perf_counter() - started
        started = time.perf_counter()
        write_csv(validated.trajectory, run.path("trajectory.csv"))
        seconds["csv"] = time.perf_counter() - started
        started = time.perf_counter()
        report = sim.SimExecutor(sim.SimOptions()).execute(validated, run)
        seconds["execute"] = time.perf_counter() - started
    return seconds, (validated.report.figures, report.figures)


def same_figures(a: dict[str, float], b: dict[str, float]) -> list[str]:
    """The keys whose values differ by more than 1e-9 relative."""
    return [
        key
        for key in sorted(set(a) | set(b))
        if key not in a or key not in b or not math.isclose(a[key], b[key], rel_tol=1e-9)
    ]


Times = dict[tuple[str, str, str], list[float]]
"""(task, version, stage) -> milliseconds of each timed repeat."""


def planned_runs(folder: Path) -> dict[str, Any]:
    """A warm run of each task (the offline planner, the sim executor), after a first one that
    pays the imports and caches."""
    from keymps import run_task

    def offline_run(task: str, out: Path) -> Any:
        options = RunOptions(rerun="off")
        overrides = RunOverrides(out=out, backend="offline", executor="sim")
        return run_task(ROOT / task, options=options, overrides=overrides)

    runs = {}
    for name, task in TASKS.items():
        offline_run(task, folder / f"cold-{name}")
        runs[name] = offline_run(task, folder / name)
    return runs


def timed_repeats(runs: dict[str, Any], baseline: Baseline, repeats: int) -> Times:
    """Both versions' stages on every run, `repeats` times after a warm-up, the order of the
    versions alternating; the warm-up's reports are compared instead of timed."""
    times: Times = {}
    for repeat in range(repeats + 1):
        for name, run in runs.items():
            order = ("baseline", "this") if repeat % 2 else ("this", "baseline")
            reports = {}
            for version in order:
                seconds, reports[version] = stages_once(run, version, baseline)
                for stage, value in seconds.items():
                    times.setdefault((name, version, stage), []).append(value * 1000)
            if repeat == 0:
                for key in list(times):
                    times[key].clear()
                print_comparison(name, reports)
    return times


def print_comparison(name: str, reports: dict[str, Any]) -> None:
    """Whether both versions' validation and sim figures of one run are the same."""
    for what, a, b in zip(("validation", "sim"), reports["baseline"], reports["this"], strict=True):
        differ = same_figures(a, b)
        verdict = f"differ: {', '.join(differ)}" if differ else "the same"
        print(f"{name} {what} figures: {verdict}")


def speedup_lines(runs: dict[str, Any], times: Times) -> list[tuple[str, str]]:
    """Prints each stage's median and minimum, baseline -> this; returns the median speed-ups."""
    lines = []
    for name in runs:
        for stage in STAGES:
            before, after = times[(name, "baseline", stage)], times[(name, "this", stage)]
            ratio = statistics.median(before) / statistics.median(after)
            print(
                f"{name:8s} {stage:8s} median {statistics.median(before):6.1f} -> "
                f"{statistics.median(after):6.1f} ms ({ratio:.2f}x), "
                f"min {min(before):6.1f} -> {min(after):6.1f} ms"
            )
            lines.append((f"{stage}_speedup_{name}", f"{ratio:.2f}"))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", default="a668308", help="git commit to compare with")
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument(
        "--quick", action="store_true", help="one repeat: checks the script runs (CI)"
    )
    arguments = parser.parse_args()
    if arguments.quick:
        arguments.repeats = 1
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        baseline = Baseline(arguments.baseline, folder)
        runs = planned_runs(folder)
        print(f"load {os.getloadavg()[0]:.2f} at start; baseline {arguments.baseline}")
        times = timed_repeats(runs, baseline, arguments.repeats)
        print(f"load {os.getloadavg()[0]:.2f} at the end")
        lines = speedup_lines(runs, times)
        for key, value in lines:
            print(f"{key}: {value}")


if __name__ == "__main__":
    main()
