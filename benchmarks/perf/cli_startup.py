"""How fast `keymps --help` answers and `keymps run` finishes, against the imports each needs.

Run: python benchmarks/perf/cli_startup.py [--repeats 7] [--bytecode]
Every command is timed in a fresh process, the commands interleaved (so that a busy machine
slows a figure and its floor alike); medians. The last lines are machine-readable `name: value`
pairs. Targets: help_s under 0.5 s, run_vs_import_floor at most 2.5.

Python compiles every module it imports that has no cached bytecode; with
PYTHONDONTWRITEBYTECODE set and an editable install that has never written __pycache__, that is
all of keymps, on every run (about 0.1 s here). pip compiles an installed package's bytecode
at install time: `--bytecode` measures that case, with the bytecode cached in a temporary
PYTHONPYCACHEPREFIX (the checkout is not touched).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
KEYMPS = [sys.executable, "-c", "from keymps.cli import main; main()"]


def commands(out: Path) -> dict[str, list[str]]:
    task = str(REPO / "tasks" / "cake_icing.yaml")
    return {
        "python_bare": [sys.executable, "-c", "pass"],
        "keymps_help": [*KEYMPS, "--help"],
        "import_floor": [sys.executable, "-c", "import numpy, pinocchio, cv2"],
        "keymps_run": [*KEYMPS, "run", task, "--rerun", "off", "--out", str(out)],
        "import_cv2": [sys.executable, "-c", "import cv2"],
        "import_pinocchio": [sys.executable, "-c", "import pinocchio"],
        "import_rerun": [sys.executable, "-c", "import rerun"],
        "import_litellm": [sys.executable, "-c", "import litellm"],
    }


def interleaved(
    measured: dict[str, list[str]], repeats: int, env: dict[str, str]
) -> dict[str, float]:
    times: dict[str, list[float]] = {name: [] for name in measured}
    for _ in range(repeats):
        for name, command in measured.items():
            started = time.perf_counter()
            subprocess.run(command, check=True, capture_output=True, env=env, cwd=REPO)
            times[name].append(time.perf_counter() - started)
    return {name: statistics.median(seconds) for name, seconds in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--bytecode", action="store_true", help="cache compiled bytecode")
    parser.add_argument(
        "--quick", action="store_true", help="one repeat: checks the script runs (CI)"
    )
    args = parser.parse_args()
    if args.quick:
        args.repeats = 1
    with tempfile.TemporaryDirectory() as folder:
        env = {**os.environ, "LITELLM_LOCAL_MODEL_COST_MAP": "True"}
        if args.bytecode:
            env.pop("PYTHONDONTWRITEBYTECODE", None)
            env["PYTHONPYCACHEPREFIX"] = str(Path(folder) / "pycache")
        measured = commands(Path(folder) / "run")
        if not args.quick:  # warm the file cache (and the bytecode cache)
            interleaved(measured, 1, env)
        result = interleaved(measured, args.repeats, env)
    for name, seconds in result.items():
        print(f"{name:<18} {seconds * 1000:8.1f} ms")
    heavy = sum(result[k] for k in result if k.startswith("import_") and k != "import_floor")
    print(f"load_average: {os.getloadavg()[0]:.2f}")
    print(f"bytecode_cached: {int(args.bytecode)}")
    print(f"help_s: {result['keymps_help']:.3f}")
    print(f"help_vs_bare_python: {result['keymps_help'] / result['python_bare']:.2f}")
    print(f"heavy_imports_avoided_s: {heavy - 4 * result['python_bare']:.3f}")
    print(f"run_s: {result['keymps_run']:.3f}")
    print(f"run_vs_import_floor: {result['keymps_run'] / result['import_floor']:.2f}")


if __name__ == "__main__":
    main()
