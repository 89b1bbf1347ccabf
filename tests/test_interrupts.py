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
