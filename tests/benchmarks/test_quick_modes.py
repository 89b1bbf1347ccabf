"""Every script under benchmarks/ runs end to end in its quick mode, so that none rots unseen.

A benchmark backs figures in the docs (docs/performance.md and others); a script that no longer
runs leaves those figures unreproducible. Each script takes `--quick` (a few cases, no targets
that need a quiet machine) and must exit 0. The quick modes measure nothing worth reading: the
targets are checked by running the scripts in full (docs/performance.md says how).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(
    path
    for path in (REPO / "benchmarks").rglob("*.py")
    if 'if __name__ == "__main__":' in path.read_text(encoding="utf-8")
)


def test_the_benchmarks_are_found() -> None:
    assert len(SCRIPTS) >= 8, SCRIPTS


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda path: str(path.relative_to(REPO)))
def test_the_benchmark_runs_in_its_quick_mode(script: Path, tmp_path: Path) -> None:
    help_text = subprocess.run(
        [sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120
    )
    assert "--quick" in help_text.stdout, f"{script.name} has no --quick mode"
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    done = subprocess.run(
        [sys.executable, str(script), "--quick"],
        capture_output=True,
        text=True,
        timeout=1200,  # generous: other processes may keep both cores busy
        cwd=REPO,
        env=env,
    )
    assert done.returncode == 0, (
        f"{script.name} --quick failed:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    )
    assert done.stdout.strip(), f"{script.name} --quick printed nothing"
