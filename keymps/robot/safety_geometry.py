"""Distances the safety check measures: points to a polyline (the planned path) and points
outside a polygon (the object's footprint). The simulator measures with the same functions."""

from __future__ import annotations

import numpy as np


def _segment_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances of points (n, 3) to segments a[i]-b[i] given per point: (n, k, 3) each."""
    ab = b - a
    length2 = np.maximum((ab**2).sum(axis=-1), 1e-18)
    t = np.clip(((points[:, None, :] - a) * ab).sum(axis=-1) / length2, 0.0, 1.0)
    gap = points[:, None, :] - (a + t[..., None] * ab)
    return np.sqrt((gap**2).sum(axis=-1))


def _brute_force(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    a, b = polyline[:-1][None], polyline[1:][None]
    out = np.empty(len(points))
    chunk = max(1, 1_000_000 // (len(polyline) - 1))
    for start in range(0, len(points), chunk):
        block = points[start : start + chunk]
        out[start : start + chunk] = _segment_distances(block, a, b).min(axis=1)
    return out


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Exact distance of each point (n, 3) to a polyline (m, 3)."""
    points = np.asarray(points, dtype=float)
    polyline = np.asarray(polyline, dtype=float)
    if len(polyline) == 1 or len(points) == 0:
        return np.linalg.norm(points - polyline[0], axis=1)
    segments = len(polyline) - 1
    if segments * len(points) <= 200_000:
        return _brute_force(points, polyline)
    from scipy.spatial import cKDTree

    # The closest segment has an endpoint within d + L/2 of the point (d: distance found,
    # L: longest segment); candidates come from the k nearest vertices, and any point for
    # which that bound is not covered is measured against every segment.
    longest = float(np.linalg.norm(np.diff(polyline, axis=0), axis=1).max())
    k = min(8, len(polyline))
    vertex_distance, nearest = cKDTree(polyline).query(points, k)
    first = np.clip(np.concatenate([nearest - 1, nearest], axis=1), 0, segments - 1)
    found = _segment_distances(points, polyline[first], polyline[first + 1]).min(axis=1)
    if k < len(polyline):
        unsure = vertex_distance[:, -1] < found + longest / 2
        if unsure.any():
            found[unsure] = _brute_force(points[unsure], polyline)
    return found


def outside_distance(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """How far each 2D point lies outside a polygon (0 inside or on it), metres."""
    import cv2

    contour = np.asarray(polygon, dtype=np.float32).reshape(-1, 1, 2)
    signed = np.array(
        [cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in points]
    )
    return np.maximum(-signed, 0.0)
