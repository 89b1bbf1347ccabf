"""Shared by the tests: the count of fuzzed and fault-injected cases, printed after every run.

The fuzz suites (tests/*/test_*_fuzz.py and test_litellm_faults.py) add each
distinct case they try to the session's `fuzz_counter`; pytest's terminal summary then prints
one line per suite, so CI logs show how many cases ran (docs/safety.md). The tests run in
pytest-xdist workers: each worker hands its counts to the controlling process when it ends.
"""

from __future__ import annotations

import hashlib
import signal
from collections import defaultdict
from typing import Any

import pytest


class FuzzCounter:
    """Distinct cases per suite (by content digest), and how many ended in success or error."""

    def __init__(self) -> None:
        self.distinct: dict[str, set[str]] = defaultdict(set)
        self.outcomes: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))

    def add(self, suite: str, case: Any, outcome: str = "tried") -> None:
        data = case if isinstance(case, bytes) else repr(case).encode("utf-8", "replace")
        self.distinct[suite].add(hashlib.sha1(data).hexdigest())
        self.outcomes[suite][outcome] += 1

    def total(self, prefix: str = "") -> int:
        return sum(len(v) for k, v in self.distinct.items() if k.startswith(prefix))

    def as_data(self) -> dict[str, Any]:
        """The counts as plain data, for a worker to send to the controlling process."""
        return {
            suite: {"distinct": sorted(digests), "outcomes": dict(self.outcomes[suite])}
            for suite, digests in self.distinct.items()
        }

    def merge(self, data: dict[str, Any]) -> None:
        """Add a worker's counts (`as_data`)."""
        for suite, counts in data.items():
            self.distinct[suite].update(counts["distinct"])
            for outcome, n in counts["outcomes"].items():
                self.outcomes[suite][outcome] += n

    def lines(self) -> list[str]:
        lines = []
        for suite in sorted(self.distinct):
            outcomes = ", ".join(f"{k} {v}" for k, v in sorted(self.outcomes[suite].items()))
            lines.append(f"{suite}: {len(self.distinct[suite])} distinct cases ({outcomes})")
        return lines


COUNTER = FuzzCounter()


@pytest.fixture(scope="session")
def fuzz_counter() -> FuzzCounter:
    return COUNTER


def pytest_configure(config: pytest.Config) -> None:
    """The Ctrl-C and hang-up tests need those signals delivered: a suite started in the
    background of a shell without job control (or under nohup) inherits them ignored, and every
    process a test starts would inherit that too."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN:
        signal.signal(signal.SIGHUP, signal.SIG_DFL)


def pytest_sessionfinish(session: pytest.Session) -> None:
    worker_output = getattr(session.config, "workeroutput", None)
    if worker_output is not None:  # a pytest-xdist worker
        worker_output["fuzz_counter"] = COUNTER.as_data()


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: Any) -> None:
    """pytest-xdist's controller: a worker ended; its counts join the summary."""
    COUNTER.merge(getattr(node, "workeroutput", {}).get("fuzz_counter", {}))


def pytest_terminal_summary(terminalreporter: Any) -> None:
    if not COUNTER.distinct:
        return
    terminalreporter.write_sep("-", "fuzz and fault-injection cases tried")
    for line in COUNTER.lines():
        terminalreporter.write_line(line)
    answers = COUNTER.total("answers")
    terminalreporter.write_line(
        f"total: {COUNTER.total()} distinct cases, of which {answers} planner answers"
    )


@pytest.fixture(autouse=True, scope="session")
def _private_vlm_cache(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """No test writes VLM answers into the user's own cache folder, or reads their config."""
    mp = pytest.MonkeyPatch()
    mp.setenv("KEYMPS_CACHE_DIR", str(tmp_path_factory.mktemp("vlm-cache")))
    mp.setenv("KEYMPS_CONFIG", str(tmp_path_factory.mktemp("user-config") / "config.yaml"))
    yield
    mp.undo()


@pytest.fixture(autouse=True, scope="session")
def _private_warm_planner_folder(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """No test reaches the user's own warm planner: `keymps run` uses one that is up
    (keymps.planning.warm), so the tests' runs look for it in a folder of their own."""
    mp = pytest.MonkeyPatch()
    folder = tmp_path_factory.mktemp("runtime")
    folder.chmod(0o700)
    mp.setenv("XDG_RUNTIME_DIR", str(folder))
    mp.delenv("KEYMPS_WARM_PLANNER", raising=False)
    yield
    mp.undo()
