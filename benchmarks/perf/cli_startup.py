"""How fast `keymps --help` answers, against Python's own start and the imports it avoids.

Run: python benchmarks/perf/cli_startup.py [--repeats 7]
The last lines are machine-readable `name: value` pairs. Target: help_s under 0.5 s.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

COMMANDS = {
    "python_bare": [sys.executable, "-c", "pass"],
    "keymps_help": [sys.executable, "-c", "from keymps.cli import main; main()", "--help"],
    "import_cv2": [sys.executable, "-c", "import cv2"],
    "import_pinocchio": [sys.executable, "-c", "import pinocchio"],
    "import_rerun": [sys.executable, "-c", "import rerun"],
    "import_litellm": [sys.executable, "-c", "import litellm"],
}


def median_seconds(command: list[str], repeats: int) -> float:
    env = {**os.environ, "LITELLM_LOCAL_MODEL_COST_MAP": "True"}
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, env=env)
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    measured = {name: median_seconds(cmd, args.repeats) for name, cmd in COMMANDS.items()}
    for name, seconds in measured.items():
        print(f"{name:<18} {seconds * 1000:8.1f} ms")
    heavy = sum(measured[k] for k in measured if k.startswith("import_"))
    print(f"help_s: {measured['keymps_help']:.3f}")
    print(f"help_vs_bare_python: {measured['keymps_help'] / measured['python_bare']:.2f}")
    print(f"heavy_imports_avoided_s: {heavy - 4 * measured['python_bare']:.3f}")


if __name__ == "__main__":
    main()
