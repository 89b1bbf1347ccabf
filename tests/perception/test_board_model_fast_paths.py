"""The board detector's model of the board: planes, distances, fits, search areas and region counts against the whole-image computations they replaced.

Each fast path is held against the implementation it replaced, on generated inputs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

RNG_SEED = 20261201


def test_side_bands_in_windows_match_the_whole_image_computation() -> None:
    from keymps.perception.search_area import SearchArea

    rng = np.random.default_rng(RNG_SEED + 12)
    for trial in range(20):
        width, height = int(rng.integers(40, 300)), int(rng.integers(40, 300))
        if trial % 4 == 0:
            polygon = None  # the whole image
        else:
            count = int(rng.integers(3, 8))
            angles = np.sort(rng.uniform(0, 2 * math.pi, count))
            radius = rng.uniform(0.3, 0.7, count) * min(width, height) / 2
            polygon = [
                (width / 2 + r * math.cos(a) + rng.uniform(-5, 5), height / 2 + r * math.sin(a))
                for r, a in zip(radius, angles, strict=True)
            ]  # a corner may lie outside the image
        area = SearchArea.of((width, height), polygon)
        band_width = float(rng.choice([0.5, 1.5, 2.0, 3.7, 12.0]))
        for got, side in zip(
            area.side_bands(band_width),
            zip(area.polygon, np.roll(area.polygon, -1, axis=0), strict=True),
            strict=True,
        ):
            assert np.array_equal(got, _whole_image_band(area.mask, *side, band_width))


def _whole_image_band(mask: np.ndarray, a: np.ndarray, b: np.ndarray, width_px: float) -> Any:
    """One side's band computed over every pixel (as side_bands did before its windows)."""
    height, width = mask.shape
    cols = np.arange(width, dtype=np.float32)[None, :] + 0.5
    rows = np.arange(height, dtype=np.float32)[:, None] + 0.5
    edge = b - a
    length = max(float(np.hypot(*edge)), 1e-9)
    t = np.clip(((cols - a[0]) * edge[0] + (rows - a[1]) * edge[1]) / length**2, 0, 1)
    dx, dy = cols - (a[0] + t * edge[0]), rows - (a[1] + t * edge[1])
    return mask & (dx * dx + dy * dy <= width_px * width_px)


def _random_board_model(rng: np.random.Generator) -> Any:
    from keymps.perception.board_model import BoardModel

    degree = int(rng.integers(0, 3))
    terms = (degree + 1) * (degree + 2) // 2
    coefficients = rng.normal(0, [[30, 10, 10]], (terms, 3)).astype(np.float32)
    coefficients[0] += np.float32([60, 5, 10])
    size = (int(rng.integers(20, 400)), int(rng.integers(20, 300)))
    return BoardModel(coefficients, degree, size, 0, 0.0)


def test_board_model_planes_are_the_term_by_term_image() -> None:
    from keymps.perception.board_model import _exponents

    rng = np.random.default_rng(RNG_SEED + 20)
    for _ in range(30):
        model = _random_board_model(rng)
        width, height = model.size_px
        x, y = model.normalized(
            np.arange(width, dtype=np.float32)[None, :],
            np.arange(height, dtype=np.float32)[:, None],
        )
        expected = np.zeros((height, width, 3), np.float32)  # as BoardModel.image() was
        for (i, j), weights in zip(_exponents(model.degree), model.coefficients, strict=True):
            term = x**i * y**j
            for channel in range(3):
                expected[..., channel] += weights[channel] * term
        assert np.array_equal(model.image(), expected)
        assert np.array_equal(np.moveaxis(model.planes(), 0, -1), expected)
        used = rng.normal(0, 50, (3, height, width)).astype(np.float32)  # an earlier surface
        assert model.planes(out=used) is used
        assert np.array_equal(np.moveaxis(used, 0, -1), expected)
        described = model.describe(model.planes())
        mean = expected.reshape(-1, 3).mean(axis=0)
        assert described["mean_lab"] == [round(float(v), 2) for v in mean]


def test_distance_to_board_in_buffers_is_the_formula() -> None:
    from keymps.perception.board_model import distance_to_board, lab_planes

    rng = np.random.default_rng(RNG_SEED + 21)
    for _ in range(30):
        shape = (int(rng.integers(5, 200)), int(rng.integers(5, 200)), 3)
        lab = (rng.normal(0, [30, 20, 20], shape) + [50, 0, 0]).astype(np.float32)
        model = (rng.normal(0, [20, 10, 10], shape) + [55, 3, 8]).astype(np.float32)
        model[..., 0][rng.random(shape[:2]) < 0.05] = -20.0  # where max(L + 16, 1) binds
        shadow = float(rng.choice([0.0, 0.5, rng.uniform(0, 0.99)]))
        # the formula as distance_to_board computed it, on H x W x 3 arrays
        lightness = lab[..., 0] - model[..., 0]
        ratio = np.clip((lab[..., 0] + 16.0) / np.maximum(model[..., 0] + 16.0, 1.0), 0.0, 1.0)
        da = lab[..., 1] - ratio * model[..., 1]
        db = lab[..., 2] - ratio * model[..., 2]
        weight = np.where(lightness < 0, 1.0 - shadow, 1.0).astype(np.float32)
        expected = np.sqrt((weight * lightness) ** 2 + da**2 + db**2)
        got = distance_to_board(lab_planes(lab), lab_planes(model), shadow)
        assert got.dtype == np.float32
        assert np.array_equal(got, expected)


def test_board_fit_by_index_is_the_fit_by_mask() -> None:
    from keymps.perception.board_model import BoardModel, _monomials, fit_board

    rng = np.random.default_rng(RNG_SEED + 22)
    for trial in range(24):
        height, width = int(rng.integers(30, 300)), int(rng.integers(30, 400))
        lab = (rng.normal(0, [3, 2, 2], (height, width, 3)) + [70, 4, 12]).astype(np.float32)
        lab[rng.random((height, width)) < 0.1] += np.float32([-30, 20, 5])  # an object's pixels
        where = rng.random((height, width)) < rng.uniform(0.02, 1.0)
        degree = trial % 3
        # the fit as it was: np.nonzero, index pairs, boolean masks, np.linalg.norm
        rows, cols = np.nonzero(where)
        if len(rows) > 12_000:
            keep = np.linspace(0, len(rows) - 1, 12_000).astype(int)
            rows, cols = rows[keep], cols[keep]
        values = lab[rows, cols].astype(np.float64)
        probe = BoardModel(np.zeros((1, 3)), degree, (width, height), 0, 0.0)
        design = _monomials(*probe.normalized(cols.astype(float), rows.astype(float)), degree)
        residual = np.linalg.norm(values - np.median(values, axis=0), axis=1)
        inliers = residual <= 3.0 * float(np.median(residual)) + 1.0
        coefficients = np.zeros((design.shape[1], 3))
        for _ in range(3):
            if inliers.sum() < design.shape[1] * 4:
                break
            used = design[inliers]
            coefficients = np.linalg.solve(
                used.T @ used + 1e-9 * np.eye(used.shape[1]), used.T @ values[inliers]
            )
            residual = np.linalg.norm(values - design @ coefficients, axis=1)
            inliers = residual <= 3.0 * float(np.median(residual[inliers])) + 1.0
        got = fit_board(lab, where, degree)
        assert np.array_equal(got.coefficients, coefficients.astype(np.float32))
        assert got.samples == int(inliers.sum())
        expected_residual = float(np.median(residual[inliers])) if inliers.any() else 0.0
        assert got.residual == expected_residual


def test_search_areas_are_shared_read_only_and_their_bands_are_the_direct_ones() -> None:
    from keymps.perception.search_area import SearchArea

    rng = np.random.default_rng(RNG_SEED + 23)
    for trial in range(12):
        width, height = int(rng.integers(40, 300)), int(rng.integers(40, 300))
        polygon = None
        if trial % 3:
            polygon = [
                (float(rng.uniform(0, width / 3)), float(rng.uniform(2 * height / 3, height))),
                (
                    float(rng.uniform(2 * width / 3, width)),
                    float(rng.uniform(2 * height / 3, height)),
                ),
                (float(rng.uniform(2 * width / 3, width)), float(rng.uniform(0, height / 3))),
                (float(rng.uniform(0, width / 3)), float(rng.uniform(0, height / 3))),
            ]
        area = SearchArea.of((width, height), polygon)
        assert SearchArea.of((width, height), polygon) is area
        assert not area.mask.flags.writeable
        for band_width in (int(rng.integers(1, 12)), 2):
            padded = np.pad(area.mask.astype(np.uint8), 1)
            distance = cv2_distance(padded)[1:-1, 1:-1]
            assert np.array_equal(
                area.border_band(band_width), area.mask & (distance <= band_width)
            )
            with pytest.raises(ValueError):
                area.border_band(band_width)[0, 0] = True
        first = area.side_bands(3.5)
        assert all(np.array_equal(a, b) for a, b in zip(first, area._side_bands(3.5), strict=True))


def cv2_distance(padded: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.distanceTransform(padded, cv2.DIST_L2, 3)


def test_region_counts_in_the_box_are_the_whole_image_counts() -> None:
    import cv2

    from keymps.default_plugins.board_detector import BoardDetector
    from keymps.perception.search_area import SearchArea

    rng = np.random.default_rng(RNG_SEED + 24)
    checked = 0
    for _ in range(12):
        width, height = int(rng.integers(60, 300)), int(rng.integers(60, 240))
        area = SearchArea.of((width, height), None)
        bands = [
            band & ~out for band, out in zip(area.side_bands(3.5), area.side_bands(2), strict=True)
        ]
        blobs = np.zeros((height, width), np.uint8)
        for _ in range(int(rng.integers(1, 5))):  # blobs, some over the image's border
            centre = (int(rng.integers(-10, width + 10)), int(rng.integers(-10, height + 10)))
            axes = (int(rng.integers(5, width // 2)), int(rng.integers(5, height // 2)))
            cv2.ellipse(blobs, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        mask = (blobs > 0) & (rng.random((height, width)) < 0.97)  # with holes
        distance = rng.uniform(0, 40, (height, width)).astype(np.float32)
        for region in BoardDetector()._regions(mask, distance, area, bands, 30):
            inside = region.mask  # whole image, as the counts were taken before
            assert region.coverage == float(inside.sum()) / area.pixels
            names = area.side_names()
            assert region.sides == tuple(
                n for n, b in zip(names, bands, strict=True) if (inside & b).any()
            )
            assert region.along == max(
                float((inside & b).sum()) / max(int(b.sum()), 1) for b in bands
            )
            assert region.contrast == float(np.median(distance[inside & mask]))
            checked += 1
    assert checked >= 12
