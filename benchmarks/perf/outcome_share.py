"""The outcome stage's share of a warm run's compute (issue 36: under 20 %).

Run: python benchmarks/perf/outcome_share.py [--repeats 7] [--quick]

Each shipped task (and a sawing cut of the banana bread, the longest cutting motion) runs once
to warm the models and caches, then --repeats times in this process, the tasks interleaved so
that a busy machine slows them alike. A run's compute is the sum of its stage times (image to
execute, the sim executor's replay included); the share is the outcome stage's part of it. The
median over the repeats is printed per task with the stage's own median in milliseconds, and
the load average. Target: every share < 0.20. The last lines are machine-readable
`outcome_share_<task>: <value>`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TARGET = 0.20


def cases() -> dict[str, tuple[Path, dict[str, object]]]:
    bread = ROOT / "tasks" / "scenes" / "banana_bread.png"
    height = json.loads(bread.with_suffix(".json").read_text())["objects"][0]["height_m"]
    return {
        "icing": (ROOT / "tasks" / "cake_icing.yaml", {}),
        "cutting": (ROOT / "tasks" / "object_cutting.yaml", {}),
        "sawing": (
            ROOT / "tasks" / "object_cutting.yaml",
            {"image": bread, "height": height, "instruction": "Cut the bread into 6 slices"},
        ),
    }


def one_run(task_file: Path, extra: dict[str, object], out: Path) -> dict[str, float]:
    """The stage timings (seconds) of one offline run with the sim executor."""
    from keymps import RunOptions, RunOverrides, load_task, run_task

    task = load_task(task_file)
    if "image" in extra:
        scene = task.scene.model_copy(
            update={"image": extra["image"], "object_height": extra["height"]}
        )
        task = task.model_copy(update={"scene": scene})
    run = run_task(
        task,
        options=RunOptions(rerun="off", quiet=True),
        overrides=RunOverrides(
            out=out, backend="offline", executor="sim", instruction=extra.get("instruction")
        ),
    )
    return dict(run.timings_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--quick", action="store_true", help="one repeat of two tasks (a test)")
    args = parser.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    chosen = cases()
    if args.quick:
        chosen = {name: chosen[name] for name in ("icing", "cutting")}
        args.repeats = 1
    shares: dict[str, list[float]] = {name: [] for name in chosen}
    stage_ms: dict[str, list[float]] = {name: [] for name in chosen}
    with tempfile.TemporaryDirectory() as scratch:
        for name, (task, extra) in chosen.items():  # warm: models, caches, imports
            one_run(task, extra, Path(scratch) / f"warm-{name}")
        for repeat in range(args.repeats):
            for name, (task, extra) in chosen.items():
                timings = one_run(task, extra, Path(scratch) / f"{name}-{repeat}")
                shares[name].append(timings["outcome"] / sum(timings.values()))
                stage_ms[name].append(1000 * timings["outcome"])
    print(f"load average: {os.getloadavg()[0]:.2f}")
    print("| task | outcome stage (ms) | share of the run's compute | target |")
    print("| --- | --- | --- | --- |")
    for name in chosen:
        share = statistics.median(shares[name])
        print(f"| {name} | {statistics.median(stage_ms[name]):.0f} | {share:.3f} | < {TARGET} |")
    for name in chosen:
        print(f"outcome_share_{name}: {statistics.median(shares[name]):.4f}")


if __name__ == "__main__":
    main()
