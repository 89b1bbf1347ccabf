"""The optimal assignment behind metric_d_optimal: scipy's compiled solver, without the imports
of scipy.optimize.

`scipy.optimize.linear_sum_assignment` is a function of the compiled module
`scipy.optimize._lsap`, which needs nothing but numpy. Importing it the usual way runs
scipy.optimize's `__init__` first (about 0.3 s here, once per `keymps eval` worker); loading
the compiled file on its own takes under a millisecond. Should a scipy release move or change
that file, the public import is used instead: slower to start, the same answers.
"""

from __future__ import annotations

import functools
import importlib.machinery
import importlib.util
from collections.abc import Callable
from pathlib import Path

import numpy as np

Solver = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
COMPILED_MODULE = "scipy.optimize._lsap"


def min_cost_assignment(cost: np.ndarray) -> np.ndarray:
    """The column of each row in an assignment of minimal total cost, each column used at most
    once (a cost matrix with at least as many columns as rows)."""
    rows, columns = cost.shape
    if rows > columns:
        raise ValueError(f"{rows} rows cannot each get one of {columns} columns")
    assigned_rows, assigned_columns = solver()(cost)
    column_of_row = np.empty(rows, dtype=np.intp)
    column_of_row[assigned_rows] = assigned_columns
    return column_of_row


@functools.cache
def solver() -> Solver:
    """scipy's linear_sum_assignment, from its compiled module alone when that loads."""
    try:
        return _compiled_solver()
    except (ImportError, OSError, AttributeError):
        from scipy.optimize import linear_sum_assignment

        return linear_sum_assignment


def _compiled_solver() -> Solver:
    scipy_spec = importlib.util.find_spec("scipy")  # (finds scipy without importing it)
    if scipy_spec is None or not scipy_spec.submodule_search_locations:
        raise ImportError("scipy is not installed")
    folder = Path(next(iter(scipy_spec.submodule_search_locations))) / "optimize"
    finder = importlib.machinery.FileFinder(
        str(folder),
        (importlib.machinery.ExtensionFileLoader, importlib.machinery.EXTENSION_SUFFIXES),
    )
    spec = finder.find_spec(COMPILED_MODULE)
    if spec is None or spec.loader is None:
        raise ImportError(f"no compiled {COMPILED_MODULE} in {folder}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    solve: Solver = module.linear_sum_assignment
    return solve
