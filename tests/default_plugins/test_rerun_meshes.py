"""The recorder's light robot meshes: COLLADA read, edge collapse within its tolerance, GLB."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from keymps.default_plugins.rerun import meshes
from keymps.default_plugins.rerun.robot import light_mesh, ur3_urdf_path


def _sphere(radius: float, rings: int, sectors: int, center: np.ndarray) -> np.ndarray:
    """A UV sphere as (n, 3, 3) corners, outward-facing."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, sectors + 1)
    grid = np.stack(
        [
            np.sin(theta)[:, None] * np.cos(phi)[None, :],
            np.sin(theta)[:, None] * np.sin(phi)[None, :],
            np.cos(theta)[:, None] * np.ones_like(phi)[None, :],
        ],
        axis=-1,
    )
    points = center + radius * grid
    faces = []
    for i in range(rings):
        for j in range(sectors):
            a, b, c, d = points[i, j], points[i + 1, j], points[i + 1, j + 1], points[i, j + 1]
            if i > 0:
                faces.append([a, b, d])
            if i < rings - 1:
                faces.append([b, c, d])
    return np.array(faces)


def _box(half: np.ndarray, steps: int) -> np.ndarray:
    """An axis-aligned box, each face a steps x steps grid of triangle pairs."""
    faces = []
    u = np.linspace(-1.0, 1.0, steps + 1)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            i, j = [k for k in range(3) if k != axis]
            for a in range(steps):
                for b in range(steps):
                    quad = []
                    for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[axis], p[i], p[j] = sign, u[a + da], u[b + db]
                        quad.append(p * half)
                    first = [quad[0], quad[1], quad[2]]
                    second = [quad[0], quad[2], quad[3]]
                    if sign < 0:
                        first, second = first[::-1], second[::-1]
                    faces.extend([first, second])
    return np.array(faces)


def _flat_normals(corners: np.ndarray) -> np.ndarray:
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    unit = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    return np.repeat(unit[:, None, :], 3, axis=1)


def _area(points: np.ndarray, faces: np.ndarray) -> float:
    corners = points[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return float(np.linalg.norm(cross, axis=1).sum() / 2.0)


def _volume(points: np.ndarray, faces: np.ndarray) -> float:
    corners = points[faces]
    return float(
        np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6.0
    )


@pytest.mark.parametrize("seed", range(12))
def test_a_fine_sphere_is_simplified_within_the_tolerance_and_stays_closed(seed):
    """Generated spheres of varied size, tessellation and place: every kept vertex lies on the
    sphere to the tolerance, the surface stays closed and oriented, far fewer triangles."""
    rng = np.random.default_rng(seed)
    radius = rng.uniform(0.01, 0.06)
    rings, sectors = int(rng.integers(30, 60)), int(rng.integers(40, 90))
    center = rng.uniform(-0.2, 0.2, 3)
    tolerance = rng.uniform(0.0001, 0.0005)
    corners = _sphere(radius, rings, sectors, center)
    part = meshes.Part(corners, _flat_normals(corners), (0.2, 0.4, 0.8, 1.0))
    mesh = meshes.decimate([part], tolerance)
    points, faces = mesh.positions[0].astype(float), mesh.triangles[0]
    assert mesh.triangle_count < 0.6 * len(corners)
    off = np.abs(np.linalg.norm(points - center, axis=1) - radius)
    # The original facets lie inside the sphere by up to their sagitta: allow it on top.
    sagitta = radius * (1.0 - np.cos(np.pi / min(rings, sectors)))
    assert off.max() <= 3.0 * tolerance + sagitta, (off.max(), tolerance, sagitta)
    # Closed and oriented: every edge used twice, once in each direction (welded by position).
    _, vertex = np.unique(np.round(points * 1e6), axis=0, return_inverse=True)
    welded = vertex.reshape(-1)[faces]
    directed = np.concatenate([welded[:, [0, 1]], welded[:, [1, 2]], welded[:, [2, 0]]])
    forward = {tuple(e) for e in directed}
    assert len(forward) == len(directed) and all((b, a) in forward for a, b in forward)
    # The volume lost is on average less than the tolerance deep (measured: 0.2-0.6 of it).
    welded_points, welded_faces, _ = meshes.weld(corners, np.zeros(len(corners), int))
    lost = _volume(welded_points, welded_faces) - _volume(points, faces)
    assert 0.0 <= lost <= _area(welded_points, welded_faces) * tolerance
    normals = mesh.normals[0]
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    outward = np.einsum("ij,ij->i", normals, (points - center) / radius)
    assert outward.min() > 0.9  # smooth shading, pointing out


@pytest.mark.parametrize("seed", range(8))
def test_a_finely_split_box_becomes_a_box_with_sharp_edges(seed):
    """Flat faces cost nothing to merge: a box split into many triangles keeps its eight
    corners exactly and its faces flat, and its edges are shaded sharp (split normals)."""
    rng = np.random.default_rng(100 + seed)
    half = rng.uniform(0.01, 0.08, 3)
    corners = _box(half, int(rng.integers(3, 9)))
    part = meshes.Part(corners, _flat_normals(corners), (0.5, 0.5, 0.5, 1.0))
    mesh = meshes.decimate([part], 0.0002)
    points, faces = mesh.positions[0].astype(float), mesh.triangles[0]
    assert mesh.triangle_count <= 0.5 * len(corners)
    assert np.abs(np.abs(points) - half).min(axis=1).max() < 1e-6  # every vertex on a face
    for corner in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3):
        assert np.linalg.norm(points - corner * half, axis=1).min() < 1e-6
    assert _area(points, faces) == pytest.approx(
        _area(*meshes.weld(corners, np.zeros(len(corners), int))[:2]), rel=1e-6
    )
    axis_aligned = np.abs(mesh.normals[0]).max(axis=1)
    assert axis_aligned.min() > 1 - 1e-6  # no normal averaged across an edge


def _glb_document(blob: bytes) -> dict:
    magic, version, length = struct.unpack_from("<4sII", blob)
    assert (magic, version, length) == (b"glTF", 2, len(blob))
    json_length, kind = struct.unpack_from("<I4s", blob, 12)
    assert kind == b"JSON" and json_length % 4 == 0
    return json.loads(blob[20 : 20 + json_length])


def _glb_meshes(blob: bytes, document: dict) -> list[tuple[np.ndarray, np.ndarray]]:
    """(positions, triangles) of each primitive of a GLB file."""
    (json_length,) = struct.unpack_from("<I", blob, 12)
    binary = blob[28 + json_length :]

    def read(index: int, dtype: type, width: int) -> np.ndarray:
        accessor = document["accessors"][index]
        view = document["bufferViews"][accessor["bufferView"]]
        data = binary[view["byteOffset"] : view["byteOffset"] + view["byteLength"]]
        return np.frombuffer(data, dtype=dtype).reshape(-1, width)[: accessor["count"]]

    shapes = []
    for primitive in document["meshes"][0]["primitives"]:
        positions = read(primitive["attributes"]["POSITION"], np.float32, 3).astype(float)
        kind = document["accessors"][primitive["indices"]]["componentType"]
        indices = read(primitive["indices"], {5123: np.uint16, 5125: np.uint32}[kind], 1)
        shapes.append((positions, indices.reshape(-1, 3).astype(np.int64)))
    return shapes


def test_the_ur3_links_are_light_faithful_and_keep_their_colours():
    """The installed URDF's COLLADA visuals: each link's GLB is a fraction of its triangles,
    spans the same box (to 2 mm), keeps its surface area (5 %) and its materials' colours."""
    visual = ur3_urdf_path().parents[1] / "meshes" / "ur3" / "visual"
    files = sorted(visual.glob("*.dae"))
    assert len(files) == 7
    total_in = total_out = 0
    for path in files:
        parts = meshes.read_collada(path)
        corners = np.concatenate([p.corners for p in parts])
        glb = light_mesh(path)
        assert glb.suffix == ".glb" and glb.stat().st_size < 200_000
        document = _glb_document(glb.read_bytes())
        blob = glb.read_bytes()
        if path.name == "wrist1.dae":  # deterministic, and what is cached
            assert meshes.glb_bytes(meshes.decimate(parts)) == blob
        shapes = _glb_meshes(blob, document)
        points = np.concatenate([pos for pos, _ in shapes])
        np.testing.assert_allclose(
            points.min(axis=0), corners.reshape(-1, 3).min(axis=0), atol=2e-3
        )
        np.testing.assert_allclose(
            points.max(axis=0), corners.reshape(-1, 3).max(axis=0), atol=2e-3
        )
        before = sum(
            _area(*meshes.weld(p.corners, np.zeros(len(p.corners), int))[:2]) for p in parts
        )
        after = sum(_area(pos, tri) for pos, tri in shapes)
        assert after == pytest.approx(before, rel=0.05), path.name
        colors = {
            tuple(m["pbrMetallicRoughness"]["baseColorFactor"]) for m in document["materials"]
        }
        assert colors == {p.color for p in parts}, path.name
        total_in += len(corners)
        total_out += sum(len(tri) for _, tri in shapes)
    assert total_in > 60_000 and total_out < total_in / 4


def test_light_mesh_is_cached_per_process(monkeypatch):
    visual = ur3_urdf_path().parents[1] / "meshes" / "ur3" / "visual" / "wrist3.dae"
    first = light_mesh(visual)
    monkeypatch.setattr(meshes, "decimate", lambda *a, **k: pytest.fail("decimated again"))
    assert light_mesh(visual) == first


def test_a_polylist_of_triangles_is_read(tmp_path: Path):
    """wrist3.dae's flange is a <polylist> of triangles (Rerun's own importer drops it)."""
    visual = ur3_urdf_path().parents[1] / "meshes" / "ur3" / "visual" / "wrist3.dae"
    assert "<polylist" in visual.read_text()
    parts = meshes.read_collada(visual)
    assert sum(len(p.corners) for p in parts) == 418 + 110
