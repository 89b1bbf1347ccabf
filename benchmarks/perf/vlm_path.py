"""What a VLM costs a `keymps run` beyond the model's own answer: runs against an instant server.

Run: python benchmarks/perf/vlm_path.py [--rounds 5] [--quick] [--baseline-python PATH]

A local OpenAI-compatible server (127.0.0.1, a process of its own) answers every request at once
with a valid plan (a ring of dots for icing, three cuts for cutting), so that whatever a run
waits for beyond the offline run is keymps' own overhead: litellm's import, the request, the
records. Each round runs, one after the other (so that a busy machine slows every figure alike),
in fresh processes of this interpreter:

- `offline`: `keymps run tasks/cake_icing.yaml --rerun off` (the offline planner);
- `vlm_in_process`: the same with `--model openai/x --api-base URL --no-cache` and no warm
  planner (KEYMPS_WARM_PLANNER=0): litellm imported by the run itself, as every run did before;
- `vlm_first`: the same with KEYMPS_WARM_PLANNER=1 and no planner running: it starts one;
- `vlm_second`, `vlm_third`: the same again, in a row, each finding the planner up;
- `eval`: `keymps eval SUITE --model ... --api-base URL --no-cache --concurrency 8`, with the
  planner up (its default: the calls go there) and with `--no-warm-planner` (`eval_in_process`:
  litellm imported by the evaluation).

The warm planner is stopped at the start of every round (`keymps planner stop`), and its socket
folder is a temporary XDG_RUNTIME_DIR (a planner of your own is not touched). With
`--baseline-python` (an interpreter with another keymps installed, e.g. main's), its offline
run, in-process VLM run and eval are measured in the same rounds: before/after from one run.

Targets (not in --quick): vlm_overhead_s (second and later runs minus the offline run) <= 1.0,
the first run no slower than the baseline's, eval_vlm_runs_per_s >= 5. The last lines are
machine-readable `name: value` pairs; peaks are the run process's own (ru_maxrss), the warm
planner's resident memory is printed apart.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from instant_vlm import InstantVlm, crop_size  # beside this script

ROOT = Path(__file__).resolve().parents[2]
TASK = ROOT / "tasks" / "cake_icing.yaml"
CLI = ["-c", "from keymps.cli import main; main()"]
MODEL = "openai/instant-vlm"
EXCLUDED: set[str] = set()
"""Processes whose CPU is not keymps' (the VLM server's)."""


def answer_for(body: dict[str, Any]) -> str:
    """A valid plan for the image the request describes: 15 dots on a ring (icing) or three
    vertical cuts across the crop (cutting)."""
    width, height = crop_size(body)
    schema = body.get("response_format", {}).get("json_schema", {}).get("schema", {})
    keywords = schema.get("properties", {}).get("keyword", {}).get("enum") or ["line"]
    keyword = "line" if "line" in keywords else keywords[0]
    if keyword == "line":
        radius = 0.3 * min(width, height)
        pairs = []
        for k in range(15):
            angle = 2 * math.pi * k / 15
            point = [width / 2 + radius * math.cos(angle), height / 2 + radius * math.sin(angle)]
            pairs.append([point, point])
    else:
        pairs = [[[width * f, 0.25 * height], [width * f, 0.75 * height]] for f in (0.4, 0.5, 0.6)]
    return json.dumps({"keyword": keyword, "pairs": pairs, "design": None, "rationale": "bench"})


def timed(arguments: list[str], env: dict[str, str], cwd: Path) -> tuple[float, float]:
    """(wall seconds, peak resident MB of the process itself) of one command; it must succeed."""
    started = time.perf_counter()
    process = subprocess.Popen(
        arguments, env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    output = process.stdout.read() if process.stdout else b""
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise SystemExit(f"{' '.join(arguments[3:])} failed:\n{output.decode(errors='replace')}")
    return seconds, usage.ru_maxrss / 1024


class Bench:
    """The commands of one benchmark: this checkout's keymps, or the baseline's."""

    def __init__(self, name: str, python: str, api_base: str, work: Path, env: dict[str, str]):
        self.name, self.python, self.api_base, self.work, self.env = (
            name,
            python,
            api_base,
            work,
            env,
        )
        # a baseline runs outside this checkout: `python -c` puts the working folder first on
        # sys.path, where this checkout's keymps would shadow the baseline's
        self.cwd = work if python != sys.executable else ROOT
        self.count = 0
        self.has_planner = self._has_planner()

    def _has_planner(self) -> bool:
        done = subprocess.run(
            [self.python, *CLI, "planner", "--help"],
            env=self.env,
            cwd=self.cwd,
            capture_output=True,
        )
        return done.returncode == 0

    def keymps(self, *arguments: str, warm: str | None = None) -> tuple[float, float]:
        env = dict(self.env)
        if warm is not None:
            env["KEYMPS_WARM_PLANNER"] = warm
        return timed([self.python, *CLI, *arguments], env, self.cwd)

    def out(self, name: str) -> str:
        self.count += 1
        return str(self.work / f"{self.name}-{name}-{self.count}")

    def run(self, vlm: bool, warm: str | None = None) -> tuple[float, float]:
        arguments = ["run", str(TASK), "--rerun", "off", "--out", self.out("run")]
        if vlm:
            arguments += ["--model", MODEL, "--api-base", self.api_base, "--no-cache"]
        return self.keymps(*arguments, warm=warm)

    def eval(
        self, suite: str, cases: list[str], repeats: int | None, warm: str | None = None
    ) -> tuple[float, float]:
        """Runs per second of one whole `keymps eval` command, and its CPU seconds per run (its
        processes' and the warm planner's, whose children ask the VLM)."""
        arguments = ["eval", suite, "--model", MODEL, "--api-base", self.api_base, "--no-cache"]
        arguments += ["--concurrency", "8", "--quiet", "--out", self.out("eval")]
        for case in cases:
            arguments += ["--case", case]
        if repeats:
            arguments += ["--repeats", str(repeats)]
        planner = self.planner_pid()
        before = _planner_cpu_s(planner)
        with _TreeCpu() as tree:
            seconds, _ = self.keymps(*arguments, warm=warm)
        cpu = tree.seconds + _planner_cpu_s(planner) - before
        records = Path(arguments[arguments.index("--out") + 1]) / "results.jsonl"
        lines = [json.loads(line) for line in records.read_text().splitlines()]
        failed = [r for r in lines if not r.get("ok")]
        if failed:
            raise SystemExit(f"{len(failed)} eval runs failed, first: {failed[0]['error']}")
        return len(lines) / seconds, cpu / len(lines)

    def stop_planner(self) -> None:
        if self.has_planner:
            subprocess.run(
                [self.python, *CLI, "planner", "stop"], env=self.env, cwd=self.cwd, check=True,
                capture_output=True,
            )  # fmt: skip

    def planner_pid(self) -> int | None:
        if not self.has_planner:
            return None
        done = subprocess.run(
            [self.python, *CLI, "planner", "status", "--json"], env=self.env, cwd=self.cwd,
            capture_output=True, text=True,
        )  # fmt: skip
        return int(json.loads(done.stdout)["pid"]) if done.returncode == 0 else None

    def planner_rss_mb(self) -> float | None:
        pid = self.planner_pid()
        if pid is None:
            return None
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        return None


def _cpu_s(pid: int | str, reaped: bool = False) -> float:
    """CPU seconds of a process (and of the children it reaped), 0 once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    ticks = sum(int(v) for v in fields[11 : 15 if reaped else 13])
    return ticks / os.sysconf("SC_CLK_TCK")


def _planner_cpu_s(pid: int | None) -> float:
    return _cpu_s(pid, reaped=True) if pid is not None else 0.0


class _TreeCpu:
    """CPU seconds of this process's descendants (the VLM server's process left out) while the
    block runs, sampled every 50 ms: a process that ends keeps its last sample."""

    def __init__(self) -> None:
        self.last: dict[str, float] = {}
        self.first: dict[str, float] = {}
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._watch, daemon=True)

    def _descendants(self, pid: str) -> list[str]:
        found = []
        for task in Path(f"/proc/{pid}/task").glob("*"):
            try:
                children = (task / "children").read_text().split()
            except OSError:
                continue
            for child in children:
                if child not in EXCLUDED:
                    found += [child, *self._descendants(child)]
        return found

    def sample(self) -> None:
        for pid in self._descendants(str(os.getpid())):
            used = _cpu_s(pid)
            if used:
                self.first.setdefault(pid, 0.0 if self.thread.is_alive() else used)
                self.last[pid] = used

    def _watch(self) -> None:
        while not self.done.wait(0.05):
            self.sample()

    def __enter__(self) -> _TreeCpu:
        self.sample()  # the processes there already count from now
        self.thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self.done.set()
        self.thread.join()

    @property
    def seconds(self) -> float:
        return sum(self.last[pid] - self.first[pid] for pid in self.last)


def one_round(
    bench: Bench, baseline: Bench | None, eval_args: tuple[str, list[str], int | None]
) -> dict[str, float]:
    """Every figure of one round, in a fixed order."""
    figures: dict[str, float] = {}
    steps: list[tuple[str, Callable[[], tuple[float, float]]]] = [
        ("offline", lambda: bench.run(False)),
        ("vlm_in_process", lambda: bench.run(True, warm="0")),
    ]
    if bench.has_planner:
        steps += [
            ("vlm_first", lambda: bench.run(True, warm="1")),
            ("vlm_second", lambda: bench.run(True)),
            ("vlm_third", lambda: bench.run(True)),
        ]
    if baseline is not None:
        steps += [
            ("baseline_offline", lambda: baseline.run(False)),
            ("baseline_vlm", lambda: baseline.run(True)),
        ]
    bench.stop_planner()
    for name, step in steps:
        figures[f"{name}_s"], figures[f"{name}_mb"] = step()
    planner_mb = bench.planner_rss_mb()
    if planner_mb is not None:
        figures["planner_rss_mb"] = planner_mb
    if bench.has_planner:  # with the planner the runs started
        figures["eval_runs_per_s"], figures["eval_cpu_s"] = bench.eval(*eval_args)
    figures["eval_in_process_runs_per_s"], figures["eval_in_process_cpu_s"] = bench.eval(
        *eval_args, warm="0"
    )
    if baseline is not None:
        runs, cpu = baseline.eval(*eval_args)
        figures["baseline_eval_runs_per_s"], figures["baseline_eval_cpu_s"] = runs, cpu
    bench.stop_planner()
    return figures


def summarize(rounds: list[dict[str, float]], quick: bool) -> None:
    def median(name: str) -> float:
        return statistics.median(r[name] for r in rounds)

    def paired(a: str, b: str) -> float:
        """The median of each round's a - b (a busy round slows both)."""
        return statistics.median(r[a] - r[b] for r in rounds)

    names = sorted({k for r in rounds for k in r})
    for name in names:
        values = ", ".join(f"{r[name]:.2f}" for r in rounds if name in r)
        print(f"{name:<28} {values}")
    later = "vlm_second_s" if "vlm_second_s" in rounds[0] else "vlm_in_process_s"
    seconds_later = [r[k] for r in rounds for k in (later, "vlm_third_s") if k in r]
    overhead_later = [
        r[k] - r["offline_s"] for r in rounds for k in (later, "vlm_third_s") if k in r
    ]
    print(f"load_average: {os.getloadavg()[0]:.2f}")
    print(f"rounds: {len(rounds)}")
    print(f"offline_run_s: {median('offline_s'):.3f}")
    print(f"vlm_run_s: {statistics.median(seconds_later):.3f}")
    print(f"vlm_overhead_s: {statistics.median(overhead_later):.3f}")
    print(f"vlm_first_run_s: {median('vlm_in_process_s'):.3f}")
    print(f"vlm_first_overhead_s: {paired('vlm_in_process_s', 'offline_s'):.3f}")
    if "vlm_first_s" in rounds[0]:
        print(f"vlm_first_run_starting_planner_s: {median('vlm_first_s'):.3f}")
        print(f"vlm_first_starting_overhead_s: {paired('vlm_first_s', 'offline_s'):.3f}")
    print(f"vlm_peak_mb: {median(later.removesuffix('_s') + '_mb'):.0f}")
    print(f"vlm_in_process_peak_mb: {median('vlm_in_process_mb'):.0f}")
    print(f"offline_peak_mb: {median('offline_mb'):.0f}")
    if "planner_rss_mb" in rounds[0]:
        print(f"warm_planner_rss_mb: {median('planner_rss_mb'):.0f}")
    eval_name = (
        "eval_runs_per_s" if "eval_runs_per_s" in rounds[0] else "eval_in_process_runs_per_s"
    )
    print(f"eval_vlm_runs_per_s: {median(eval_name):.2f}")
    print(f"eval_vlm_in_process_runs_per_s: {median('eval_in_process_runs_per_s'):.2f}")
    cpu_name = "eval_cpu_s" if eval_name == "eval_runs_per_s" else "eval_in_process_cpu_s"
    print(f"eval_vlm_cpu_s_per_run: {median(cpu_name):.3f}")
    print(f"eval_vlm_in_process_cpu_s_per_run: {median('eval_in_process_cpu_s'):.3f}")
    met = statistics.median(overhead_later) <= 1.0 and median(eval_name) >= 5
    if "baseline_vlm_s" in rounds[0]:
        print(f"baseline_offline_run_s: {median('baseline_offline_s'):.3f}")
        print(f"baseline_vlm_run_s: {median('baseline_vlm_s'):.3f}")
        print(f"baseline_vlm_overhead_s: {paired('baseline_vlm_s', 'baseline_offline_s'):.3f}")
        print(f"baseline_vlm_peak_mb: {median('baseline_vlm_mb'):.0f}")
        print(f"baseline_eval_vlm_runs_per_s: {median('baseline_eval_runs_per_s'):.2f}")
        print(f"baseline_eval_vlm_cpu_s_per_run: {median('baseline_eval_cpu_s'):.3f}")
        first_vs = paired("vlm_in_process_s", "baseline_vlm_s")
        print(f"first_run_minus_baseline_s: {first_vs:.3f}")
        met = met and first_vs <= 0.0
        if "vlm_first_s" in rounds[0]:
            starting_vs = paired("vlm_first_s", "baseline_vlm_s")
            print(f"first_run_starting_planner_minus_baseline_s: {starting_vs:.3f}")
    if not quick:
        print(f"targets_met: {int(met)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="one round, a few eval runs (CI)")
    parser.add_argument("--baseline-python", help="an interpreter with another keymps installed")
    parser.add_argument("--suite", default="cutting_sim", help="the eval's suite")
    args = parser.parse_args()
    rounds = 1 if args.quick else args.rounds
    eval_args = ("cutting_sim", ["1", "4"], 1) if args.quick else (args.suite, [], None)
    with (
        InstantVlm(answer_for) as server,
        tempfile.TemporaryDirectory(prefix="keymps-vlm-path-") as folder,
    ):
        EXCLUDED.add(server.pid)
        work = Path(folder)
        runtime = work / "runtime"
        runtime.mkdir(mode=0o700)
        env = {
            **os.environ,
            "XDG_RUNTIME_DIR": str(runtime),  # a warm planner of this benchmark's own
            "KEYMPS_CACHE_DIR": str(work / "cache"),
            "LITELLM_LOCAL_MODEL_COST_MAP": "True",
        }
        env.pop("KEYMPS_WARM_PLANNER", None)
        bench = Bench("this", sys.executable, server.api_base, work, env)
        baseline = None
        if args.baseline_python:
            baseline = Bench("baseline", args.baseline_python, server.api_base, work, env)
        try:
            bench.run(False)  # the file cache warm for everyone
            results = []
            for index in range(rounds):
                results.append(one_round(bench, baseline, eval_args))
                print(f"round {index + 1} done (load {os.getloadavg()[0]:.2f})", flush=True)
        finally:
            bench.stop_planner()
    summarize(results, args.quick)


if __name__ == "__main__":
    main()
