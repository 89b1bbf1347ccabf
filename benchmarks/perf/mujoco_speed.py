"""How long the `mujoco` executor takes for a 40 s cutting trajectory, against the motion itself.

Run: python benchmarks/perf/mujoco_speed.py [--task tasks/object_cutting.yaml]
Plans the task once (offline planner), then executes the same validated trajectory with: the
physics alone (no video, no outcome: the floor), the default video, and the video with
shadows in the perspective view. Prints wall and CPU seconds and their ratio to the motion's duration, with the load
average (the machine is shared: wall time under load is not the code's speed).
Target: wall_ratio_default at most 3 (on 2 cores).
The last lines are machine-readable `name: value` pairs.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from keymps.run import RunOptions, RunOverrides


def execute(validated: Any, run: Any, **options: Any) -> tuple[float, float]:
    from keymps.plugin.manager import create_component

    executor = create_component("executor", "mujoco", options)
    wall, cpu = time.perf_counter(), time.process_time()
    report = executor.execute(validated, run)
    if not report.ok:
        raise SystemExit(f"execution failed: {report.message}")
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--task", default="tasks/object_cutting.yaml")
    parser.add_argument(
        "--quick", action="store_true", help="the physics alone: checks the script runs (CI)"
    )
    args = parser.parse_args()
    import keymps_mujoco  # noqa: F401  (MUJOCO_GL before mujoco is imported)

    import keymps

    with tempfile.TemporaryDirectory() as folder:
        run = keymps.run_task(
            args.task,
            options=RunOptions(rerun="off", quiet=True),
            overrides=RunOverrides(executor="file", out=Path(folder) / "plan"),
        )
        validated = run.stages.check
        duration = validated.trajectory.duration_s
        print(f"load average before: {os.getloadavg()}")
        print(f"motion: {duration:.1f} s, {validated.trajectory.samples} samples")
        cases = {
            "physics": {"video": False, "outcome": False},
            "default": {},
            "shadows": {"shadows": True},
        }
        if args.quick:
            cases = {"physics": cases["physics"]}
        measured = {}
        for name, options in cases.items():
            run.folder = Path(folder) / name
            run.folder.mkdir()
            measured[name] = execute(validated, run, **options)
            wall, cpu = measured[name]
            print(f"{name:<12} wall {wall:7.1f} s  cpu {cpu:7.1f} s")
        print(f"load average after: {os.getloadavg()}")
    print(f"motion_s: {duration:.2f}")
    for name, (wall, cpu) in measured.items():
        print(f"wall_ratio_{name}: {wall / duration:.2f}")
        print(f"cpu_ratio_{name}: {cpu / duration:.2f}")
    if "default" in measured:
        floor = measured["physics"][1]
        print(f"video_cpu_over_physics_default: {measured['default'][1] / floor:.1f}")


if __name__ == "__main__":
    main()
