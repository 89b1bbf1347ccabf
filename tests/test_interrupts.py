"""Ctrl-C held back over a native module's initialisation (keymps.interrupts)."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import pytest

from keymps.interrupts import import_whole, interrupts_deferred


def test_a_ctrl_c_during_an_import_takes_effect_once_the_module_is_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "slow_native.py").write_text(
        "import os, signal\nos.kill(os.getpid(), signal.SIGINT)\nafter_the_interrupt = True\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "slow_native", raising=False)
    with pytest.raises(KeyboardInterrupt):
        import_whole("slow_native")
    assert sys.modules["slow_native"].after_the_interrupt  # initialised to its end
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert import_whole("slow_native") is sys.modules["slow_native"]  # loaded: no handler swap


def test_without_a_ctrl_c_nothing_is_raised_and_the_handler_is_restored() -> None:
    with interrupts_deferred():
        pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_ctrl_c_in_a_deferred_block_is_raised_at_its_end() -> None:
    reached = []
    with pytest.raises(KeyboardInterrupt), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        reached.append(True)
    assert reached == [True]


def test_a_stopped_command_exits_even_when_a_thread_waits_forever(tmp_path: Path) -> None:
    """A signal can cut an import short between taking and releasing Python's import lock; a
    background thread importing then waits forever, and so did the interpreter's exit, which
    waits for it (1 SIGTERM in 30 at a random moment hung `keymps run` past 60 s). Here a
    plugin leaves the lock taken and starts such a thread, then the process gets SIGTERM."""
    import subprocess

    (tmp_path / "hung_plugin.py").write_text(
        "import _imp, os, signal, threading, time\n"
        "_imp.acquire_lock()  # what an import cut short by a signal can leave behind\n"
        "threading.Thread(target=lambda: __import__('this_module_waits')).start()\n"
        "time.sleep(0.2)\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(5)\n"
    )
    info = tmp_path / "hung_plugin-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: hung-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[keymps]\nhung = hung_plugin\n")
    done = subprocess.run(
        [sys.executable, "-c", "from keymps.cli.app import main; main()", "plugins"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
        timeout=60,
    )
    assert done.returncode == 143, done.stderr
    assert done.stderr.splitlines()[-1] == "error: interrupted (SIGTERM)"
