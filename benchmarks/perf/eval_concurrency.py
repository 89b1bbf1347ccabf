"""How `keymps eval` scales with --concurrency against a VLM that answers after a fixed delay.

A local OpenAI-compatible server (127.0.0.1, a process of its own, keeping connections open as
VLM servers do) answers every planning request after --latency seconds with six equal wedges of
the cake it is shown (a valid design). The script runs the cake_six suite's keymps method
(plan-only jobs: image, detect, plan, ground, equal-parts check) through the real runner and
litellm, with a fresh answer cache per run so that every request reaches the server: first with
--concurrency 1, then with 8 (the same jobs), and finally a long run at 8 to see that memory
stays flat. A second pair of runs against a slower server (--slow-latency, default 1 s) shows how
the speedup grows when the VLM, not keymps' own work per run (about 40 ms of CPU), dominates.
CPU and memory are those of this process and the processes it starts for the evaluation (the
fork server and its workers), not the server's.

    python benchmarks/perf/eval_concurrency.py [--requests 80] [--latency 0.2] [--long 1000]

Ends with `name: value` lines (speedup_c8_vs_c1, cpu_s_per_request, peak_rss_growth_mb, ...).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from instant_vlm import InstantVlm, crop_size  # beside this script

# as `keymps eval` does before NumPy loads: runs, not BLAS threads, are the parallelism
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _answer(body: dict[str, Any]) -> str:
    """Six equal wedges of the round cake the request shows: three diameters at 60 degrees."""
    width, height = crop_size(body)
    cx, cy, r = width / 2, height / 2, min(width, height) / 2 - 1
    pairs = []
    for k in range(3):
        a = math.radians(90 + 60 * k)
        pairs.append(
            [
                [cx - r * math.cos(a), cy - r * math.sin(a)],
                [cx + r * math.cos(a), cy + r * math.sin(a)],
            ]
        )
    return json.dumps({"keyword": "straight", "pairs": pairs, "rationale": "six wedges"})


def _rss_kb(pid: str) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:  # the process ended meanwhile
        pass
    return 0


EXCLUDED: set[str] = set()
"""Processes left out of the figures (the VLM server)."""


def _descendants(pid: str) -> list[str]:
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children = (task / "children").read_text().split()
        except OSError:
            continue
        for child in children:
            if child not in EXCLUDED:
                found += [child, *_descendants(child)]
    return found


def _cpu_s(pid: str) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class CpuMeter:
    """CPU seconds used by this process and its descendants since the meter was made; workers
    that end between samples keep their last sampled value."""

    def __init__(self) -> None:
        self.first: dict[str, float] = {}
        self.last: dict[str, float] = {}
        self.sample()

    def sample(self) -> None:
        for pid in [str(os.getpid()), *_descendants(str(os.getpid()))]:
            used = _cpu_s(pid)
            self.first.setdefault(pid, used if not self.last else 0.0)
            self.last[pid] = used

    def seconds(self) -> float:
        self.sample()
        return sum(self.last[pid] - self.first[pid] for pid in self.last)


def rss_mb() -> float:
    """Resident memory of this process and every process it started (the eval workers and
    their fork server), in MB; pages the workers share with the fork server count twice."""
    return sum(_rss_kb(pid) for pid in ["self", *_descendants(str(os.getpid()))]) / 1024


def run(
    requests: int,
    concurrency: int,
    api_base: str,
    out: Path,
    sample: list[float] | None = None,
    cpu: CpuMeter | None = None,
) -> tuple[float, list[dict[str, Any]]]:
    from keymps.eval.runner import EvalOptions, run_suite
    from keymps.eval.suites import load_suite

    suite = load_suite("cake_six")
    options = EvalOptions(
        out=out,
        methods=("keymps",),
        repeats=requests // len(suite.cases),
        concurrency=concurrency,
        processes=None,  # as `keymps eval` chooses: one worker process per core
        backend="litellm",
        model="openai/perf-vlm",
        api_base=api_base,
    )

    def on_result(job: Any, record: dict[str, Any]) -> None:
        if sample is not None:
            sample.append(rss_mb())
        if cpu is not None:
            cpu.sample()

    # a fresh answer cache: every run must reach the server (the same seeds recur across runs)
    os.environ["KEYMPS_CACHE_DIR"] = str(out / "cache")
    started = time.perf_counter()
    records = run_suite(suite, options, on_result=on_result)
    return time.perf_counter() - started, records


def at_both_concurrencies(requests: int, api_base: str, work: Path, label: str) -> dict[int, float]:
    """Seconds of the same runs at --concurrency 1 and 8; each run must succeed and reach the
    server (an answer from the cache would make the timing wrong)."""
    seconds: dict[int, float] = {}
    for concurrency in (1, 8):
        out = work / f"{label.replace(' ', '-')}c{concurrency}"
        seconds[concurrency], records = run(requests, concurrency, api_base, out)
        failed = [r for r in records if not r.get("ok")]
        if failed:
            raise SystemExit(f"{len(failed)} runs failed, first: {failed[0]['error']}")
        if any(r.get("cached") for r in records):
            raise SystemExit("some answers came from the cache: the timing would be wrong")
        print(f"{label}c{concurrency}: {len(records)} requests in {seconds[concurrency]:.1f} s")
    return seconds


@dataclass(frozen=True)
class MemoryRun:
    """The long run at --concurrency 8: CPU per request, and resident memory after 100 runs
    and its growth over the rest."""

    requests: int
    cpu_s_per_request: float
    rss_after_100_mb: float
    peak_rss_growth_mb: float


def memory_run(requests: int, api_base: str, out: Path) -> MemoryRun:
    cpu = CpuMeter()
    samples: list[float] = []
    seconds, records = run(requests, 8, api_base, out, samples, cpu)
    settled = samples[min(len(samples) - 1, 100)]
    print(f"long run: {len(records)} requests in {seconds:.1f} s")
    return MemoryRun(
        requests=len(records),
        cpu_s_per_request=cpu.seconds() / max(1, len(records)),
        rss_after_100_mb=settled,
        peak_rss_growth_mb=max(samples[100:] or samples) - settled,
    )


def parse_arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=80)
    parser.add_argument("--latency", type=float, default=0.2)
    parser.add_argument("--long", type=int, default=1000, help="requests of the memory run")
    parser.add_argument("--slow-latency", type=float, default=1.0, help="a second, slower server")
    parser.add_argument("--slow-requests", type=int, default=40)
    parser.add_argument(
        "--quick", action="store_true", help="a few short runs: checks the script runs (CI)"
    )
    args = parser.parse_args()
    if args.quick:
        args.requests, args.long, args.slow_requests = 8, 40, 4
        args.latency, args.slow_latency = 0.05, 0.2
    return args


def main() -> None:
    args = parse_arguments()
    with (
        InstantVlm(_answer, args.latency) as server,
        tempfile.TemporaryDirectory(prefix="keymps-eval-perf-") as folder,
    ):
        EXCLUDED.add(server.pid)
        work = Path(folder)
        # imports, litellm's first request, first renders, and the fork server of the worker
        # processes (started once per process, like the imports)
        run(4 if args.quick else 16, 8, server.api_base, work / "warmup")
        seconds = at_both_concurrencies(args.requests, server.api_base, work, "")
        server.set_latency(args.slow_latency)
        slow = at_both_concurrencies(args.slow_requests, server.api_base, work, "slow ")
        server.set_latency(args.latency)
        memory = memory_run(args.long, server.api_base, work / "long")
    print(f"requests: {args.requests}")
    print(f"server_latency_s: {args.latency}")
    print(f"seconds_c1: {seconds[1]:.2f}")
    print(f"seconds_c8: {seconds[8]:.2f}")
    print(f"latency_share_c1: {args.requests * args.latency / seconds[1]:.2f}")
    print(f"cpu_s_per_request: {memory.cpu_s_per_request:.3f}")
    print(f"speedup_c8_vs_c1: {seconds[1] / seconds[8]:.2f}")
    print(f"speedup_c8_vs_c1_at_{args.slow_latency:g}s: {slow[1] / slow[8]:.2f}")
    print(f"long_requests: {memory.requests}")
    print(f"rss_after_100_mb: {memory.rss_after_100_mb:.1f}")
    print(f"peak_rss_growth_mb: {memory.peak_rss_growth_mb:.1f}")


if __name__ == "__main__":
    main()
