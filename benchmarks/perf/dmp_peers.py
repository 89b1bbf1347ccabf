"""keymps DMPs against pydmps 0.2 and movement_primitives 0.9.1: speed, accuracy, re-targeting.

    pip install pydmps==0.2 movement-primitives==0.9.1 pytransform3d
    python benchmarks/perf/dmp_peers.py [--repeat 21]

One 3D demonstration of 1000 samples (the bundled sawing demo, resampled), 50 basis functions
per axis for every library. Reports the median over repeated runs of: fit time, rollout time
(1000 output steps) and fit RMSE (rollout vs demo at the demo's time stamps). Then the sawing
demo is re-targeted to a cut turned 90 degrees about z and the stroke amplitude that survives
along the new blade direction is measured (half the peak-to-peak of the along-blade motion
after removing a degree-5 polynomial trend in time).

keymps is timed cold (its caches emptied before every call: what one fit or one new segment
length costs) and warm (the basis matrix and the canonical rollout cached, as when K segments
re-use one primitive). The headline ratios use the cold figures. The last lines are
machine-readable `name: value` pairs. BLAS runs single-threaded for every library.
"""

from __future__ import annotations

import os

# Single-threaded BLAS for every contender: fair, and far less noisy on a shared machine.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = 1000
BASIS = 50


def _require_peers() -> tuple[Any, Any]:
    try:
        import pydmps.dmp_discrete
        from movement_primitives.dmp import DMP as MovementPrimitivesDMP
    except ImportError as error:
        sys.exit(
            f"this benchmark needs the peer libraries ({error.name} is missing):\n"
            "    pip install pydmps==0.2 movement-primitives==0.9.1 pytransform3d\n"
            "(benchmark-only dependencies; keymps itself does not need them)"
        )
    return pydmps.dmp_discrete, MovementPrimitivesDMP


def demonstration() -> tuple[np.ndarray, np.ndarray]:
    from keymps.primitives.demos import load_demo_csv

    t, y = load_demo_csv(ROOT / "primitives" / "sawing.csv")
    grid = np.linspace(t[0], t[-1], SAMPLES)
    return grid, np.stack([np.interp(grid, t, y[:, k]) for k in range(3)], axis=1)


def interleaved_medians(
    operations: dict[str, tuple[Callable[[], Any], Callable[[], Any] | None]], repeat: int
) -> dict[str, float]:
    """Median seconds of each operation, run in turn within each round so that a busy machine
    slows every contender alike. Each entry is (operation, setup run untimed before it)."""
    times: dict[str, list[float]] = {name: [] for name in operations}
    for _ in range(repeat):
        for name, (operation, setup) in operations.items():
            if setup is not None:
                setup()
            start = time.perf_counter()
            operation()
            times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in times.items()}


def rmse_mm(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(((a - b) ** 2).sum(axis=1).mean()) * 1000)


def _detrended(t: np.ndarray, signal: np.ndarray) -> np.ndarray:
    """The signal minus its least-squares degree-5 polynomial in time."""
    x = (t - t[0]) / (t[-1] - t[0])
    trend = np.vander(x, 6)
    return signal - trend @ np.linalg.lstsq(trend, signal, rcond=None)[0]


def stroke_mm(
    t: np.ndarray, y: np.ndarray, start: np.ndarray, goal: np.ndarray, pattern: np.ndarray
) -> tuple[float, float]:
    """How much of the demo's stroke pattern (its detrended along-blade motion) is present along
    and across the blade of the cut start -> goal, in mm of stroke amplitude (matched filter)."""
    heading = (goal - start)[:2] / np.linalg.norm((goal - start)[:2])
    across = np.array([-heading[1], heading[0]])
    amplitude = float(np.ptp(pattern) / 2 * 1000)
    result = []
    for direction in (heading, across):
        residual = _detrended(t, (y[:, :2] - start[:2]) @ direction)
        result.append(amplitude * float(residual @ pattern / (pattern @ pattern)))
    return result[0], result[1]


class Keymps:
    name = "keymps"

    def __init__(self, t: np.ndarray, y: np.ndarray):
        from keymps.primitives import dmp as module

        self.module, self.t, self.y = module, t, y
        self.dmp = module.DMP.fit(t, y, n_basis=BASIS)

    def clear(self) -> None:
        self.module.clear_caches()
        self.dmp._cache.clear()

    def fit(self) -> None:
        self.dmp = self.module.DMP.fit(self.t, self.y, n_basis=BASIS)

    def rollout(
        self, start: np.ndarray | None = None, goal: np.ndarray | None = None
    ) -> np.ndarray:
        start = self.y[0] if start is None else start
        goal = self.y[-1] if goal is None else goal
        return self.dmp.rollout(start, goal, num=SAMPLES).y


class PyDmps:
    name = "pydmps 0.2"

    def __init__(self, module: Any, t: np.ndarray, y: np.ndarray):
        self.module, self.y = module, y
        self.fit()

    def fit(self) -> None:
        self.dmp = self.module.DMPs_discrete(n_dmps=3, n_bfs=BASIS, dt=1.0 / SAMPLES)
        self.dmp.imitate_path(y_des=self.y.T)

    def rollout(
        self, start: np.ndarray | None = None, goal: np.ndarray | None = None
    ) -> np.ndarray:
        if start is not None:
            self.dmp.y0, self.dmp.goal = start.copy(), goal.copy()
        y, _, _ = self.dmp.rollout(timesteps=SAMPLES)
        if start is not None:
            self.dmp.y0, self.dmp.goal = self.y[0].copy(), self.y[-1].copy()
        return y


class MovementPrimitives:
    name = "movement_primitives 0.9.1"

    def __init__(self, cls: Any, t: np.ndarray, y: np.ndarray):
        self.cls, self.t, self.y = cls, t, y
        self.fit()

    def fit(self) -> None:
        duration = float(self.t[-1] - self.t[0])
        step = duration / (SAMPLES - 1)
        self.dmp = self.cls(
            n_dims=3, execution_time=duration, dt=step, n_weights_per_dim=BASIS, int_dt=step
        )
        self.dmp.imitate(self.t - self.t[0], self.y)

    def rollout(
        self, start: np.ndarray | None = None, goal: np.ndarray | None = None
    ) -> np.ndarray:
        if start is not None:
            self.dmp.configure(start_y=start, goal_y=goal)
        _, y = self.dmp.open_loop()
        if start is not None:
            self.dmp.configure(start_y=self.y[0], goal_y=self.y[-1])
        return y[:SAMPLES]


Results = dict[str, dict[str, float]]
"""Library name -> fit_s, rollout_s, rmse_mm (and keymps' fit_warm_s, rollout_warm_s)."""


def measured(ours: Keymps, peers: list[Any], y: np.ndarray, repeat: int) -> Results:
    """Median fit and rollout seconds of every library, interleaved (keymps cold and warm), and
    each one's fit RMSE against the demonstration."""
    ours.rollout()  # imports and first-call costs out of the way
    for peer in peers:
        peer.rollout()
    medians = {}
    for step in ("fit", "rollout"):
        operations = {
            "keymps": (getattr(ours, step), ours.clear),
            "keymps_warm": (getattr(ours, step), None),
            **{peer.name: (getattr(peer, step), None) for peer in peers},
        }
        medians[step] = interleaved_medians(operations, repeat)
    fits, rollouts = medians["fit"], medians["rollout"]
    ours.fit()
    results: Results = {
        "keymps": {
            "fit_s": fits["keymps"],
            "fit_warm_s": fits["keymps_warm"],
            "rollout_s": rollouts["keymps"],
            "rollout_warm_s": rollouts["keymps_warm"],
            "rmse_mm": rmse_mm(ours.rollout(), y),
        }
    }
    for peer in peers:
        peer.fit()
        results[peer.name] = {
            "fit_s": fits[peer.name],
            "rollout_s": rollouts[peer.name],
            "rmse_mm": rmse_mm(peer.rollout(), y),
        }
    return results


def retargeted_strokes(
    t: np.ndarray, y: np.ndarray, libraries: list[Any]
) -> tuple[tuple[float, float], dict[str, tuple[float, float]]]:
    """The stroke (along, across the blade, mm) of the demonstration, and of each library's
    rollout re-targeted to the same cut turned 90 degrees about z."""
    start = y[0]
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    goal = start + turn @ (y[-1] - y[0])
    pattern = _detrended(t, y[:, 0] - y[0, 0])
    demo = stroke_mm(t, y, y[0], y[-1], pattern)
    strokes = {
        library.name: stroke_mm(t, library.rollout(start, goal), start, goal, pattern)
        for library in libraries
    }
    return demo, strokes


def print_speeds(t: np.ndarray, results: Results, peers: list[Any], repeat: int) -> None:
    print(f"demonstration: bundled sawing demo, {SAMPLES} samples over {t[-1] - t[0]:.1f} s, "
          f"{BASIS} basis functions per axis, median of {repeat} interleaved runs")  # fmt: skip
    print()
    header = f"{'library':28s} {'fit ms':>9s} {'rollout ms':>11s} {'RMSE mm':>9s}"
    print(header)
    print("-" * len(header))
    k = results["keymps"]
    print(f"{'keymps (cold)':28s} {k['fit_s'] * 1e3:9.3f} {k['rollout_s'] * 1e3:11.3f} "
          f"{k['rmse_mm']:9.4f}")  # fmt: skip
    print(f"{'keymps (warm: cached)':28s} {k['fit_warm_s'] * 1e3:9.3f} "
          f"{k['rollout_warm_s'] * 1e3:11.3f} {k['rmse_mm']:9.4f}")  # fmt: skip
    for peer in peers:
        r = results[peer.name]
        print(f"{peer.name:28s} {r['fit_s'] * 1e3:9.3f} {r['rollout_s'] * 1e3:11.3f} "
              f"{r['rmse_mm']:9.4f}")  # fmt: skip
    print()
    mp = results["movement_primitives 0.9.1"]
    best_rollout = min(results[p.name]["rollout_s"] for p in peers)
    fastest = min(peers, key=lambda p: results[p.name]["rollout_s"]).name
    print(f"fit:     keymps {mp['fit_s'] / k['fit_s']:.1f}x faster than movement_primitives "
          f"cold, {mp['fit_s'] / k['fit_warm_s']:.1f}x warm")  # fmt: skip
    print(f"rollout: keymps {best_rollout / k['rollout_s']:.1f}x faster than the fastest peer "
          f"({fastest}) cold, {best_rollout / k['rollout_warm_s']:.1f}x warm")  # fmt: skip
    print()


def print_strokes(demo: tuple[float, float], strokes: dict[str, tuple[float, float]]) -> None:
    print("re-targeted to the cut turned 90 degrees about z: stroke amplitude (mm)")
    print(f"{'':28s} {'along blade':>12s} {'across blade':>13s}")
    print(f"{'demonstration':28s} {demo[0]:12.2f} {demo[1]:13.2f}")
    for name, (along, across) in strokes.items():
        print(f"{name:28s} {along:12.2f} {across:13.2f}")
    print()


def figures(
    results: Results, demo_along: float, strokes: dict[str, tuple[float, float]]
) -> dict[str, float]:
    """The machine-readable figures: keymps against movement_primitives and the best peer."""
    k, mp = results["keymps"], results["movement_primitives 0.9.1"]
    peers = [name for name in results if name != "keymps"]
    best_rollout = min(results[name]["rollout_s"] for name in peers)
    return {
        "fit_speedup_vs_movement_primitives": mp["fit_s"] / k["fit_s"],
        "fit_speedup_vs_movement_primitives_warm": mp["fit_s"] / k["fit_warm_s"],
        "rollout_speedup_vs_best_peer": best_rollout / k["rollout_s"],
        "rollout_speedup_vs_best_peer_warm": best_rollout / k["rollout_warm_s"],
        "rmse_mm_keymps": k["rmse_mm"],
        "rmse_mm_best_peer": min(results[name]["rmse_mm"] for name in peers),
        "stroke_demo_mm": demo_along,
        "stroke_kept_mm_keymps": abs(strokes["keymps"][0]),
        "stroke_kept_mm_best_peer": max(abs(strokes[name][0]) for name in peers),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=21, help="runs per measurement (median)")
    parser.add_argument(
        "--quick", action="store_true", help="3 repeats: checks the script runs (CI)"
    )
    args = parser.parse_args()
    repeat = 3 if args.quick else max(3, args.repeat)
    warnings.filterwarnings("ignore")
    pydmps_module, mp_class = _require_peers()
    t, y = demonstration()
    ours = Keymps(t, y)
    peers = [PyDmps(pydmps_module, t, y), MovementPrimitives(mp_class, t, y)]
    results = measured(ours, peers, y, repeat)
    demo, strokes = retargeted_strokes(t, y, [ours, *peers])
    print_speeds(t, results, peers, repeat)
    print_strokes(demo, strokes)
    for name, value in figures(results, demo[0], strokes).items():
        print(f"{name}: {value:.4g}")


if __name__ == "__main__":
    main()
