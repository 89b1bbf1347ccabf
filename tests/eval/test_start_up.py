"""`keymps eval` with a VLM begins its slow starts before it reads the suite: litellm's import
(a thread of the process whose broker makes the calls) and the workers' fork server (a process
importing keymps.eval.preload). Each case runs in a fresh interpreter, where nothing was
started before."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

SCRIPT = """
import json, sys, threading
from multiprocessing import forkserver
from keymps.eval.pool import get_going
backend, concurrency, processes = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
get_going(backend, "openai/test-vlm", "http://127.0.0.1:9/v1", concurrency, processes)
get_going(backend, "openai/test-vlm", "http://127.0.0.1:9/v1", concurrency, processes)
server = forkserver._forkserver
print(json.dumps({
    "threads": sorted(t.name for t in threading.enumerate() if t.name.startswith("keymps")),
    "fork_server": server._forkserver_pid is not None,
    "preload": list(server._preload_modules),
}))
"""


@pytest.mark.parametrize(
    ("backend", "concurrency", "processes", "thread", "fork_server"),
    [
        ("offline", 8, None, False, False),
        ("replay", 8, None, False, False),
        ("litellm", 8, None, True, True),
        ("litellm", 8, 2, True, True),
        ("litellm", 8, 1, True, False),  # every run in this process: no workers to start
        ("litellm", 1, None, True, False),  # one call at a time: one process
    ],
)
def test_a_vlm_evaluation_gets_going_at_once(
    backend: str, concurrency: int, processes: int | None, thread: bool, fork_server: bool
) -> None:
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, backend, str(concurrency), json.dumps(processes)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    state = json.loads(done.stdout)
    assert state["threads"] == (["keymps-backend-prepare"] if thread else [])  # once, not twice
    assert state["fork_server"] is fork_server
    if fork_server:
        assert state["preload"] == ["keymps.eval.preload", "keymps.default_plugins.litellm.backend"]
