"""keymps._memory: the keymps command keeps freed memory for the next arrays (glibc)."""

from __future__ import annotations

import subprocess
import sys

import pytest

FAULTS_OF_REPEATED_ARRAYS = """
import resource, sys
import numpy as np
from keymps._memory import keep_freed_memory
changed = keep_freed_memory() if sys.argv[1] == "keep" else False
def detect_like():  # a dozen full-image planes alive at once, then all freed
    planes = [np.ones((360, 600), np.float32) for _ in range(12)]
    return sum(float(p[0, 0]) for p in planes)
for _ in range(3):
    detect_like()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    detect_like()
print(changed, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(how: str, **env: str) -> tuple[str, int]:
    done = subprocess.run(
        [sys.executable, "-c", FAULTS_OF_REPEATED_ARRAYS, how],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
        env={**_environment(), **env},
    )
    changed, faults = done.stdout.split()
    return changed, int(faults)


def _environment() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_arrays_are_reused_instead_of_faulted_in_again() -> None:
    changed, kept = _faults("keep")
    _, default = _faults("default")
    assert changed == "True"
    assert default > 20 * 1000  # 10 MB a time: 2,500 pages faulted in again and again
    assert kept < 200


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_an_exported_malloc_setting_wins() -> None:
    changed, _ = _faults("keep", MALLOC_TRIM_THRESHOLD_="131072")
    assert changed == "False"
