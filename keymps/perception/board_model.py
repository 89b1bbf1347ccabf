"""The board's colour where no object is: a smooth surface in CIE Lab, fitted to the board itself.

The board is estimated from where it must be, the border of the searched area, not from the
histogram's mode (which a uniform object covering a third of the image wins). Each Lab channel
is a low-order polynomial of the pixel position, so a lighting gradient or vignetting is part of
the model and not an object. The fit is robust: samples far from it (crumbs, an object's edge
reaching into the border band) are dropped and the fit repeated. `refit` then fits again on
every pixel judged board, which pins the surface down in the middle of the image too.

The distance of a pixel to the model forgives darkening (a soft shadow keeps the board's hue and
scales its chroma) by `shadow` of its lightness difference; any other colour change counts in
full. Units are Lab (Delta E 1976): about 2.3 is the smallest difference a person sees.
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass

import numpy as np

from keymps.sorted_values import median

MAX_SAMPLES = 12_000
"""Board pixels used for one fit (drawn evenly); more change the surface by nothing visible."""

_lab_tables: threading.Thread | None = None
_lab_tables_lock = threading.Lock()


def prepare_lab_tables() -> None:
    """Have OpenCV build its Lab conversion tables on another thread (once per process).

    OpenCV builds them on a process's first conversion to or from Lab: about 100 ms of software
    floating point, with the GIL released, so on a second core it costs the run nothing. The
    board detector starts it when it is made, well before the run detects.

    Not a daemon: a process ending while the build is inside OpenCV (`keymps validate` makes a
    detector and is done in milliseconds) aborted in OpenCV's exit-time destructors
    ("terminate called without an active exception"); the interpreter now waits for it."""
    global _lab_tables
    with _lab_tables_lock:
        if _lab_tables is None:
            _lab_tables = threading.Thread(target=_build_lab_tables, name="keymps-lab-tables")
            _lab_tables.start()


def lab_tables_ready() -> None:
    """Wait for prepare_lab_tables' thread, if any. OpenCV's table build is not thread-safe:
    every Lab conversion calls this first (after a fork the thread is gone and this returns)."""
    if _lab_tables is not None:
        _lab_tables.join()


def _build_lab_tables() -> None:
    with contextlib.suppress(Exception):  # the conversion itself will report any problem
        import cv2

        cv2.cvtColor(np.zeros((1, 1, 3), np.float32), cv2.COLOR_BGR2Lab)


def to_lab(image: np.ndarray) -> np.ndarray:
    """BGR uint8 (H x W x 3) -> float32 CIE Lab: L in [0, 100], a and b about [-128, 127]."""
    import cv2

    lab_tables_ready()
    scaled = np.divide(image, np.float32(255.0), dtype=np.float32)  # one pass: astype, then / 255
    return np.asarray(cv2.cvtColor(scaled, cv2.COLOR_BGR2Lab))


def lab_planes(lab: np.ndarray) -> np.ndarray:
    """H x W x 3 -> 3 x H x W (contiguous channel planes: what the per-pixel passes read)."""
    return np.ascontiguousarray(np.moveaxis(lab, -1, 0))


def _exponents(degree: int) -> list[tuple[int, int]]:
    return [(i, d - i) for d in range(degree + 1) for i in range(d + 1)]


def _monomials(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    return np.stack([x**i * y**j for i, j in _exponents(degree)], axis=-1)


@dataclass(frozen=True)
class BoardModel:
    """Lab = polynomial(x, y) per channel, x and y scaled to [-1, 1] over the image."""

    coefficients: np.ndarray
    """(terms, 3): one column per Lab channel."""
    degree: int
    size_px: tuple[int, int]
    samples: int
    """Board pixels the last fit used."""
    residual: float
    """Median distance of those pixels to the model (the board's texture and noise), Lab."""

    def normalized(self, cols: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel columns and rows mapped to [-1, 1] across the image (the polynomial's domain)."""
        width, height = self.size_px
        return (
            (2.0 * cols + 1.0) / width - 1.0,
            (2.0 * rows + 1.0) / height - 1.0,
        )

    def at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Model colour (N, 3) at these pixel indices."""
        x, y = self.normalized(cols.astype(np.float32), rows.astype(np.float32))
        return _monomials(x, y, self.degree) @ self.coefficients

    def planes(self, out: np.ndarray | None = None) -> np.ndarray:
        """The model over the whole image, one plane per channel (3 x H x W, float32), into
        `out` if given (an earlier model's planes no longer needed)."""
        width, height = self.size_px
        x, y = self.normalized(
            np.arange(width, dtype=np.float32)[None, :],
            np.arange(height, dtype=np.float32)[:, None],
        )
        result = np.zeros((3, height, width), np.float32) if out is None else out
        result.fill(0.0)
        term, scaled = np.empty((2, height, width), np.float32)
        for (i, j), weights in zip(_exponents(self.degree), self.coefficients, strict=True):
            if i == j == 0:  # the constant term: weight times 1
                for channel in range(3):
                    result[channel] += weights[channel]
                continue
            np.multiply(x**i, y**j, out=term)  # (1, W) times (H, 1): one H x W product per term
            for channel in range(3):
                # into buffers, not fresh arrays: the same float32 sums, term by term
                result[channel] += np.multiply(term, weights[channel], out=scaled)
        return result

    def image(self) -> np.ndarray:
        """The model over the whole image (H x W x 3, float32)."""
        return np.ascontiguousarray(np.moveaxis(self.planes(), 0, -1))

    def describe(self, planes: np.ndarray) -> dict[str, object]:
        """JSON-ready summary: the mean colour, how much it varies, the fit's residual.
        `planes` is self.planes() (computed once by the caller)."""
        lightness = planes[0]
        return {
            "colour_space": "CIE Lab (D65)",
            "surface_degree": self.degree,
            "mean_lab": [round(_running_mean(plane), 2) for plane in planes],
            "lightness_range": [round(float(lightness.min()), 2), round(float(lightness.max()), 2)],
            "samples": self.samples,
            "residual": round(self.residual, 3),
        }


def _running_mean(plane: np.ndarray) -> float:
    """The float32 running sum's mean, as image.reshape(-1, 3).mean(axis=0) adds a channel
    (row by row, not pairwise), so the reported colour is what it always was; a third faster."""
    total = np.add.accumulate(plane.ravel())[-1]
    return float(total / np.float32(plane.size))


def fit_board(
    lab: np.ndarray, where: np.ndarray, degree: int, *, iterations: int = 3
) -> BoardModel:
    """Robust least-squares fit of the board surface to the pixels `where` (bool H x W)."""
    height, width = where.shape
    flat = np.flatnonzero(where)
    if len(flat) > MAX_SAMPLES:
        flat = flat[np.linspace(0, len(flat) - 1, MAX_SAMPLES).astype(int)]
    rows, cols = np.divmod(flat, width)
    # rows by index (take) rather than by mask or index pairs: the same rows, copied faster
    values = lab.reshape(-1, lab.shape[-1]).take(flat, axis=0).astype(np.float64)
    probe = BoardModel(np.zeros((1, 3)), degree, (width, height), 0, 0.0)
    x, y = probe.normalized(cols.astype(np.float64), rows.astype(np.float64))
    design = _monomials(x, y, degree)
    # start from the median colour: where the border is mostly board, that is the board's,
    # even with something else along part of it (the table, an object's edge)
    residual = _row_norms(values - median(values, axis=0))
    inliers = residual <= 3.0 * float(median(residual)) + 1.0
    coefficients = np.zeros((design.shape[1], 3))
    for _ in range(iterations):
        if inliers.sum() < design.shape[1] * 4:
            break
        kept = np.flatnonzero(inliers)
        used = design.take(kept, axis=0)
        # normal equations: a (terms x terms) solve instead of an SVD of every sample
        coefficients = np.linalg.solve(
            used.T @ used + 1e-9 * np.eye(used.shape[1]), used.T @ values.take(kept, axis=0)
        )
        residual = _row_norms(values - design @ coefficients)
        typical = float(median(residual[inliers]))
        inliers = residual <= 3.0 * typical + 1.0
    return BoardModel(
        coefficients.astype(np.float32),
        degree,
        (width, height),
        int(inliers.sum()),
        float(median(residual[inliers])) if inliers.any() else 0.0,
    )


def board_in_shadow(lab: np.ndarray, model: np.ndarray, tolerance: float) -> np.ndarray:
    """Bool H x W: pixels darker than the board whose colour is the board's own, darkened.

    Less light scales (L + 16, a, b) alike (the cube root of the luminance, for the board's
    colour as for any): a pixel whose chroma is the model's scaled by its lightness ratio, to
    within `tolerance` (Lab), is board in shadow, however dark, and never an object. An object
    of exactly the board's colour, only darker, is then taken for shadow too: such a scene is
    refused ("no object found"), never planned on its shadow. Planes as distance_to_board's."""
    ratio = np.add(lab[0], 16.0)
    ratio /= np.maximum(np.add(model[0], 16.0), 1.0)
    np.clip(ratio, 0.0, 1.0, out=ratio)
    da = np.subtract(lab[1], ratio * model[1])
    db = np.subtract(lab[2], ratio * model[2])
    chroma = np.sqrt(da * da + db * db)
    return (chroma <= tolerance) & (lab[0] < model[0])


def _row_norms(vectors: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of (N, 3): np.linalg.norm(axis=1)'s sum of squares, bit for
    bit, without its reduction over rows of three."""
    squares = vectors * vectors
    return np.sqrt(squares[:, 0] + squares[:, 1] + squares[:, 2])


def distance_to_board(lab: np.ndarray, model: np.ndarray, shadow: float) -> np.ndarray:
    """Per-pixel Lab distance to the board model; darkening counts (1 - shadow) of its size.
    Both are channel planes (3 x H x W, or three H x W arrays): lab_planes(), model.planes()."""
    lightness = np.subtract(lab[0], model[0])
    # a shadow scales (L + 16, a, b) alike: compare chroma with the board's, scaled as much
    ratio = np.add(model[0], 16.0)
    np.maximum(ratio, 1.0, out=ratio)
    scratch = np.add(lab[0], 16.0)
    np.divide(scratch, ratio, out=ratio)
    np.clip(ratio, 0.0, 1.0, out=ratio)
    # in place, in buffers: the same float32 operations as the formula, in the same order
    da = np.multiply(ratio, model[1], out=scratch)
    np.subtract(lab[1], da, out=da)
    db = np.multiply(ratio, model[2], out=ratio)
    np.subtract(lab[2], db, out=db)
    np.multiply(lightness, np.float32(1.0 - shadow), out=lightness, where=lightness < 0)
    total = np.square(lightness, out=lightness)
    total += np.square(da, out=da)
    total += np.square(db, out=db)
    return np.sqrt(total, out=total)
