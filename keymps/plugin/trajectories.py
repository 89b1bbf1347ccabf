"""Executors accept only trajectories the safety check issued, unchanged since.

keymps.robot.safety.validate is the single issuer; `require_validated` is what every executor
calls before it moves anything.
"""

from __future__ import annotations

import hashlib
import weakref
from dataclasses import replace
from typing import Any

import numpy as np

from keymps.errors import SafetyError
from keymps.types import Trajectory, ValidatedTrajectory, ValidationReport

_issued: dict[int, tuple[weakref.ref[ValidatedTrajectory], str]] = {}


def _digest(trajectory: Trajectory) -> str:
    digest = hashlib.sha256()
    for array in (trajectory.t, trajectory.q, trajectory.qd, trajectory.qdd, trajectory.tool_xyz):
        digest.update(_bytes_of(np.ascontiguousarray(array, dtype=float)))
    digest.update(_bytes_of(np.ascontiguousarray(trajectory.piece_index, dtype=np.int64)))
    kinds = np.ascontiguousarray(np.asarray(trajectory.kind, dtype=str))
    digest.update(f"{kinds.dtype.str}{kinds.shape}".encode())  # fixed width: no join needed
    digest.update(kinds.tobytes())
    digest.update(repr((trajectory.joint_names, float(trajectory.rate_hz))).encode())
    return digest.hexdigest()


def _bytes_of(array: np.ndarray) -> memoryview:
    """The bytes of a C-contiguous array, without copying them (what tobytes() gives)."""
    return array.reshape(-1).view(np.uint8).data


def issue(trajectory: Trajectory, report: ValidationReport) -> ValidatedTrajectory:
    copies: dict[str, Any] = {}
    for name in ("t", "q", "qd", "qdd", "tool_xyz", "piece_index", "kind"):
        copies[name] = np.array(getattr(trajectory, name), copy=True)
        copies[name].flags.writeable = False  # a validated trajectory cannot be edited in place
    frozen = replace(trajectory, **copies)
    validated = ValidatedTrajectory(frozen, report)
    key = id(validated)
    _issued[key] = (weakref.ref(validated, lambda _: _issued.pop(key, None)), _digest(frozen))
    return validated


def require_validated(candidate: object, executor: str) -> Trajectory:
    """The trajectory inside a ValidatedTrajectory the safety check issued, unchanged since.

    Every executor calls this before it moves anything.

    Args:
        candidate: What the executor was given.
        executor: The executor's name, for the message.

    Returns:
        The checked trajectory (its arrays read-only).

    Raises:
        keymps.errors.SafetyError: When `candidate` was not issued by
            keymps.robot.safety.validate, failed it, or was modified afterwards.
    """
    entry = _issued.get(id(candidate))
    if (
        not isinstance(candidate, ValidatedTrajectory)
        or entry is None
        or entry[0]() is not candidate
    ):
        raise SafetyError(
            [
                f"executor {executor!r} refuses a trajectory that did not come from "
                "keymps.robot.safety.validate()"
            ]
        )
    if _digest(candidate.trajectory) != entry[1] or not candidate.report.ok:
        raise SafetyError(
            [f"executor {executor!r} refuses a validated trajectory that was modified afterwards"]
        )
    return candidate.trajectory


def trajectory_digest(trajectory: Trajectory) -> str:
    """The sha256 of a trajectory's samples, joint names and rate.

    It is what `require_validated` compares, and what exported files name to say which
    trajectory they hold.

    Args:
        trajectory: The timed trajectory (a `ValidatedTrajectory`'s `.trajectory`).

    Returns:
        64 hexadecimal characters.
    """
    return _digest(trajectory)
