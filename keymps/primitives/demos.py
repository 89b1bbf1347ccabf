"""Demonstrations: the CSV format (t, x, y, z), cleaning a recorded log, and the fit error."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from keymps.errors import KeympsError
from keymps.primitives.dmp import DMP

DEMO_COLUMNS = ("t", "x", "y", "z")
MIN_DEMO_SAMPLES = 10
MAX_DEMO_EXTENT_M = 2.0
"""A demonstration larger than this is not a kitchen motion: its positions are not metres."""
MAX_DEMO_DURATION_S = 600.0
"""A demonstration longer than this is not one motion primitive: its time is not seconds."""
STILL_WINDOW_S = 0.05
"""Trimming judges where the tool starts and stops moving on positions averaged over this
window: in a raw log, sensor noise alone takes single samples past the trim distance."""


class DemoError(KeympsError):
    """A demonstration file or recording cannot be used."""


@dataclass(frozen=True)
class Preprocessing:
    """How a recorded demonstration is cleaned before fitting (see docs/primitives.md)."""

    rate_hz: float | None = None
    """Resample to this uniform rate; None keeps uniform logs and resamples uneven ones to the
    median rate."""
    smooth_s: float = 0.0
    """Savitzky-Golay window (cubic) in seconds; 0 turns smoothing off."""
    trim_mm: float = 0.5
    """Drop still samples at both ends: those within this distance of the first/last position
    (both judged on positions averaged over STILL_WINDOW_S)."""

    def to_dict(self) -> dict[str, Any]:
        """The settings as a primitive file's `preprocessing` block.

        Returns:
            {"rate_hz", "smooth_s", "trim_mm"}.
        """
        return {"rate_hz": self.rate_hz, "smooth_s": self.smooth_s, "trim_mm": self.trim_mm}


def load_demo_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a demonstration CSV with the header t,x,y,z (seconds, metres).

    Args:
        path: The CSV file.

    Returns:
        t (T,) seconds and y (T, 3) metres, T >= 10, t strictly increasing.

    Raises:
        DemoError: For a missing or unreadable file, another header, a row that is not four
            finite numbers, too few samples or time that does not increase, naming the line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DemoError(f"{path}: demonstration file not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise DemoError(f"{path}: cannot read demonstration ({error})") from None
    rows = list(csv.reader(line for line in text.splitlines() if line.strip()))
    if not rows:
        raise DemoError(f"{path}: empty demonstration; expected a header t,x,y,z")
    header = tuple(cell.strip().lower() for cell in rows[0])
    if header != DEMO_COLUMNS:
        raise DemoError(
            f"{path}:1: expected columns t,x,y,z (seconds, metres), got {','.join(rows[0])}"
        )
    values = np.empty((len(rows) - 1, 4))
    for index, row in enumerate(rows[1:]):
        line = index + 2
        if len(row) != 4:
            raise DemoError(f"{path}:{line}: expected 4 values (t,x,y,z), got {len(row)}")
        try:
            values[index] = [float(cell) for cell in row]
        except ValueError:
            raise DemoError(f"{path}:{line}: not a number in {','.join(row)}") from None
        if not np.isfinite(values[index]).all():
            raise DemoError(f"{path}:{line}: NaN or infinite value in {','.join(row)}")
    if len(values) < MIN_DEMO_SAMPLES:
        raise DemoError(f"{path}: needs at least {MIN_DEMO_SAMPLES} samples, got {len(values)}")
    steps = np.diff(values[:, 0])
    if (steps <= 0).any():
        index = int(np.argmax(steps <= 0)) + 1
        raise DemoError(
            f"{path}:{index + 2}: time must increase strictly "
            f"(t = {values[index, 0]:g} after {values[index - 1, 0]:g})"
        )
    return values[:, 0].copy(), values[:, 1:].copy()


def write_demo_csv(path: Path, t: np.ndarray, y: np.ndarray) -> None:
    """Write a demonstration as CSV t,x,y,z, every float written to round-trip exactly.

    Args:
        path: The file to write.
        t: (T,) seconds.
        y: (T, 3) metres.
    """
    lines = [",".join(DEMO_COLUMNS)]
    rows = zip(np.asarray(t).tolist(), np.asarray(y).tolist(), strict=True)
    lines += [f"{ti!r},{p[0]!r},{p[1]!r},{p[2]!r}" for ti, p in rows]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def prepare_demo(
    t: np.ndarray, y: np.ndarray, settings: Preprocessing, where: str = "demonstration"
) -> tuple[np.ndarray, np.ndarray]:
    """Clean a recorded demonstration: check the units, resample, smooth, trim still ends.

    Args:
        t: (T,) time stamps, seconds.
        y: (T, 3) positions, metres.
        settings: What to do (rate, smoothing window, trim distance).
        where: Names the demonstration in messages.

    Returns:
        t (T',) seconds from 0 and y (T', 3) metres, uniformly sampled.

    Raises:
        DemoError: For a log in millimetres or milliseconds, a tool that never moves, a
            smoothing window longer than the demo, or fewer than 10 samples left.
    """
    t = np.asarray(t, float) - float(t[0])
    y = np.asarray(y, float)
    _check_units(t, y, where)
    steps = np.diff(t)
    rate = settings.rate_hz or 1.0 / float(np.median(steps))
    uneven = np.abs(steps - np.median(steps)).max() > 0.01 * np.median(steps)
    if settings.rate_hz is not None or uneven:
        count = max(int(round(t[-1] * rate)) + 1, MIN_DEMO_SAMPLES)
        grid = np.linspace(0.0, t[-1], count)
        y = np.stack([np.interp(grid, t, y[:, axis]) for axis in range(3)], axis=1)
        t = grid
    if settings.smooth_s > 0:
        from scipy.signal import savgol_filter

        window = int(round(settings.smooth_s * rate)) | 1
        if window >= 5:
            if window > len(t):
                raise DemoError(
                    f"{where}: smoothing window {settings.smooth_s} s is longer than the demo"
                )
            y = savgol_filter(y, window, 3, axis=0, mode="interp")
    if settings.trim_mm > 0:
        tolerance = settings.trim_mm / 1000.0
        window = max(1, min(int(round(STILL_WINDOW_S * rate)), len(t)))
        averaged = _moving_average(y, window)
        start, end = y[:window].mean(axis=0), y[-window:].mean(axis=0)
        moved_from_start = np.linalg.norm(averaged - start, axis=1) > tolerance
        moved_from_end = np.linalg.norm(averaged - end, axis=1) > tolerance
        if not moved_from_start.any():
            raise DemoError(
                f"{where}: the tool never moves more than {settings.trim_mm} mm; nothing to learn"
            )
        first = max(int(np.argmax(moved_from_start)) - 1, 0)
        last = min(len(t) - int(np.argmax(moved_from_end[::-1])), len(t) - 1)
        t, y = t[first : last + 1] - t[first], y[first : last + 1]
    if len(t) < MIN_DEMO_SAMPLES:
        raise DemoError(f"{where}: fewer than {MIN_DEMO_SAMPLES} samples after trimming")
    return t, y


def _check_units(t: np.ndarray, y: np.ndarray, where: str) -> None:
    """Refuse a log in millimetres or milliseconds: it would fit, and be useless."""
    extent = float(np.ptp(y, axis=0).max())
    if extent > MAX_DEMO_EXTENT_M:
        raise DemoError(
            f"{where}: the tool moves over {extent:g} m; positions must be metres "
            "(a log in millimetres? divide x, y, z by 1000)"
        )
    if t[-1] > MAX_DEMO_DURATION_S:
        raise DemoError(
            f"{where}: the demonstration lasts {t[-1]:g} s; time must be seconds "
            "(a log in milliseconds? divide t by 1000)"
        )


def _moving_average(y: np.ndarray, samples: int) -> np.ndarray:
    """Centred running mean of each column over `samples` samples (ends padded with the end)."""
    if samples <= 1:
        return y
    before = samples // 2
    padded = np.pad(y, ((before, samples - 1 - before), (0, 0)), mode="edge")
    sums = np.cumsum(np.vstack([np.zeros((1, y.shape[1])), padded]), axis=0)
    return (sums[samples:] - sums[:-samples]) / samples


def fit_rmse(dmp: DMP, t: np.ndarray, y: np.ndarray) -> float:
    """How well a DMP reproduces its demonstration.

    Args:
        dmp: The DMP fitted to the demonstration.
        t: (T,) the demonstration's time stamps, seconds.
        y: (T, 3) its positions, metres.

    Returns:
        The root-mean-square distance between the demo and the DMP's own rollout at the demo's
        time stamps, metres.
    """
    fine = dmp.rollout(dmp.demo_start, dmp.demo_goal, num=max(4 * len(t), 1000))
    at = np.stack([np.interp(t - t[0], fine.t, fine.y[:, axis]) for axis in range(3)], axis=1)
    return float(np.sqrt(((at - y) ** 2).sum(axis=1).mean()))
