"""The optimal assignment (keymps/eval/assignment.py): scipy's answers, from scipy's compiled
solver loaded without scipy.optimize, or from the public import when that cannot be done."""

from __future__ import annotations

import importlib.machinery
import importlib.util
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from keymps.eval import assignment
from keymps.eval.assignment import min_cost_assignment


@pytest.fixture
def fresh_solver() -> Iterator[None]:
    """solver() looked up again in the test, and again after it (it is cached per process)."""
    assignment.solver.cache_clear()
    yield
    assignment.solver.cache_clear()


def test_the_assignment_is_scipys_on_random_matrices() -> None:
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(20261203)
    for _ in range(200):  # square and wide
        rows_n = int(rng.integers(1, 40))
        cost = rng.random((rows_n, rows_n + int(rng.integers(0, 3)) * int(rng.integers(0, 50))))
        _, columns = linear_sum_assignment(cost)
        mine = min_cost_assignment(cost)
        assert len(set(mine.tolist())) == rows_n
        assert cost[np.arange(rows_n), mine].sum() == cost[np.arange(rows_n), columns].sum()


def test_more_rows_than_columns_is_an_error() -> None:
    with pytest.raises(ValueError, match="5 rows cannot each get one of 4 columns"):
        min_cost_assignment(np.ones((5, 4)))


LOAD_AND_LIST = """
import json, sys
import numpy as np
from keymps.eval import assignment
from keymps.eval.metric import metric_d_optimal
truth = [np.column_stack([np.linspace(0, 0.1, 50), np.zeros(50), np.zeros(50)])]
made = [truth[0] + 0.002]
d = metric_d_optimal(truth, made, n=50)
scipy_modules = sorted(m for m in sys.modules if m.split(".")[0] == "scipy")
loaded = assignment.solver()
from scipy.optimize import linear_sum_assignment  # afterwards, the public import still works
cost = np.random.default_rng(1).random((30, 40))
same = [a.tolist() for a in loaded(cost)] == [a.tolist() for a in linear_sum_assignment(cost)]
print(json.dumps({"d": d, "scipy_modules": scipy_modules, "same": same}))
"""


def test_the_compiled_solver_loads_without_scipy_optimize() -> None:
    """With the locked scipy the fast path is taken: a scipy that moved its compiled module
    would make this fail rather than quietly cost every eval worker 0.3 s."""
    done = subprocess.run(
        [sys.executable, "-c", LOAD_AND_LIST], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["scipy_modules"] == [assignment.COMPILED_MODULE]
    assert result["same"]
    assert result["d"] == pytest.approx(0.002 * np.sqrt(3), abs=1e-9)


def test_a_moved_compiled_module_falls_back_to_the_public_import(
    monkeypatch: pytest.MonkeyPatch, fresh_solver: None
) -> None:
    from scipy.optimize import linear_sum_assignment

    monkeypatch.setattr(assignment, "COMPILED_MODULE", "scipy.optimize._moved_away")
    assert assignment.solver() is linear_sum_assignment
    cost = np.random.default_rng(2).random((6, 9))
    assert min_cost_assignment(cost).tolist() == linear_sum_assignment(cost)[1].tolist()


def test_a_broken_compiled_file_falls_back_to_the_public_import(
    monkeypatch: pytest.MonkeyPatch, fresh_solver: None, tmp_path: Path
) -> None:
    """A compiled file that does not load (here: not a shared library at all)."""
    from scipy.optimize import linear_sum_assignment

    optimize = tmp_path / "scipy" / "optimize"
    optimize.mkdir(parents=True)
    (optimize / f"_lsap{importlib.machinery.EXTENSION_SUFFIXES[0]}").write_bytes(b"not ELF")
    real_find_spec = importlib.util.find_spec

    def find_spec(name: str, package: str | None = None) -> importlib.machinery.ModuleSpec | None:
        if name == "scipy":  # a scipy whose compiled file is the broken one
            spec = importlib.machinery.ModuleSpec("scipy", None, is_package=True)
            spec.submodule_search_locations = [str(tmp_path / "scipy")]
            return spec
        return real_find_spec(name, package)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    assert assignment.solver() is linear_sum_assignment
