"""keymps._memory: the keymps command keeps freed memory for the next arrays (glibc), and its
garbage collector skips start-up."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

TASKS = Path(__file__).resolve().parents[1] / "tasks"

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


def test_the_collector_is_off_for_start_up_and_on_with_start_up_frozen_after() -> None:
    import gc

    from keymps._memory import collector_paused_for_start_up

    assert gc.isenabled()
    with collector_paused_for_start_up() as start_up_done:
        assert not gc.isenabled()
        made_in_start_up = [[] for _ in range(1000)]
        start_up_done()
        assert gc.isenabled()
        assert gc.get_freeze_count() >= len(made_in_start_up)  # never scanned again
        start_up_done()  # a second call changes nothing
        assert gc.isenabled()
    assert gc.isenabled() and gc.get_freeze_count() == 0  # the process's own collector again


def test_start_up_that_fails_leaves_the_collector_as_it_found_it() -> None:
    import gc

    from keymps._memory import collector_paused_for_start_up

    gc.disable()
    try:
        with pytest.raises(RuntimeError), collector_paused_for_start_up():
            raise RuntimeError("the task file is missing")
        assert not gc.isenabled() and gc.get_freeze_count() == 0
    finally:
        gc.enable()
    with pytest.raises(RuntimeError), collector_paused_for_start_up():
        raise RuntimeError("the task file is missing")
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_objects_someone_else_froze_stay_frozen() -> None:
    import gc

    from keymps._memory import collector_paused_for_start_up

    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with collector_paused_for_start_up() as start_up_done:
            start_up_done()
        assert gc.get_freeze_count() >= frozen  # not unfrozen behind its owner's back
    finally:
        gc.unfreeze()


def test_keymps_run_collects_garbage_once_started(tmp_path: Path) -> None:
    import gc

    from click.testing import CliRunner

    from keymps.cli.app import cli

    seen: list[bool] = []
    # A low first threshold: in a process that has run a thousand tests the run's net new
    # containers may not reach the default 700, and no collection would show the collector on.
    thresholds = gc.get_threshold()
    gc.set_threshold(50, *thresholds[1:])
    gc.callbacks.append(lambda phase, info: seen.append(phase == "start"))
    try:
        done = CliRunner().invoke(
            cli,
            [
                "run",
                str(TASKS / "cake_icing.yaml"),
                "--rerun",
                "off",
                "--out",
                str(tmp_path / "run"),
            ],
        )
    finally:
        gc.callbacks.pop()
        gc.set_threshold(*thresholds)
    assert done.exit_code == 0, done.output
    assert any(seen)  # the stages ran with the collector on (start-up's objects frozen)
    assert gc.isenabled() and gc.get_freeze_count() == 0
