"""Light robot meshes for Rerun: COLLADA visuals read, decimated and written as small GLB files.

The UR3's visual meshes are 75,000 triangles of COLLADA text (3.7 MB in every recording). Here
each link is read (every <triangles> and all-triangle <polylist>, with the node transforms and
the materials' diffuse colours), simplified by quadric-error edge collapse (Garland and
Heckbert 1997) to within 0.2 mm of the original surface, and written as binary glTF with one
primitive per colour: 11,400 triangles, 0.4 MB. Deterministic, numpy only; about 2 s for the
whole arm, once per machine (robot.light_mesh caches the files).
"""

from __future__ import annotations

import json
import struct
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from keymps.sorted_values import distinct

TOLERANCE_M = 0.0002
"""An edge is merged while the merged vertex stays this close (RMS) to the surface it replaces."""
BORDER_WEIGHT = 10.0
"""Weight of the planes that hold open borders in place, relative to the faces' planes."""
MAX_ROUNDS = 60
CREASE_DEG = 45.0
"""Faces meeting at more than this angle are shaded with a sharp edge between them."""


@dataclass(frozen=True)
class Part:
    """Triangles of one colour: corner positions and normals (n, 3, 3), linear RGBA."""

    corners: np.ndarray
    normals: np.ndarray
    color: tuple[float, float, float, float]


@dataclass(frozen=True)
class LightMesh:
    """An indexed, decimated mesh: per colour, vertices, normals and triangles."""

    positions: tuple[np.ndarray, ...]
    normals: tuple[np.ndarray, ...]
    triangles: tuple[np.ndarray, ...]
    colors: tuple[tuple[float, float, float, float], ...]

    @property
    def triangle_count(self) -> int:
        return sum(len(t) for t in self.triangles)


# ---------------------------------------------------------------- COLLADA


def _tag(element: ElementTree.Element) -> str:
    return element.tag.rsplit("}", 1)[-1]


def _children(element: ElementTree.Element, name: str) -> list[ElementTree.Element]:
    return [child for child in element if _tag(child) == name]


def _floats(text: str | None) -> np.ndarray:
    return np.array((text or "").split(), dtype=float)


def _node_matrix(node: ElementTree.Element) -> np.ndarray:
    """The node's own transform: its <matrix>, <translate>, <rotate> and <scale> in order."""
    matrix = np.eye(4)
    for child in node:
        kind, values = _tag(child), _floats(child.text)
        step = np.eye(4)
        if kind == "matrix":
            step = values.reshape(4, 4)  # COLLADA matrices are row-major
        elif kind == "translate":
            step[:3, 3] = values
        elif kind == "scale":
            step[:3, :3] = np.diag(values)
        elif kind == "rotate":
            axis = values[:3] / np.linalg.norm(values[:3])
            angle = np.radians(values[3])
            cross = np.array(
                [[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]]
            )
            step[:3, :3] = np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross
        else:
            continue
        matrix = matrix @ step
    return matrix


def _diffuse_colors(root: ElementTree.Element) -> dict[str, tuple[float, float, float, float]]:
    """Material id -> the diffuse colour of its effect (what Rerun's COLLADA importer draws)."""
    effects: dict[str, tuple[float, float, float, float]] = {}
    for effect in root.iter():
        if _tag(effect) != "effect":
            continue
        for shader in effect.iter():
            if _tag(shader) not in ("phong", "blinn", "lambert"):
                continue
            for diffuse in _children(shader, "diffuse"):
                for color in _children(diffuse, "color"):
                    r, g, b, a = (list(_floats(color.text)) + [1.0])[:4]
                    effects[effect.get("id", "")] = (r, g, b, a)
    materials = {}
    for material in root.iter():
        if _tag(material) == "material":
            for instance in _children(material, "instance_effect"):
                url = instance.get("url", "").lstrip("#")
                if url in effects:
                    materials[material.get("id", "")] = effects[url]
    return materials


def _primitive_corners(
    primitive: ElementTree.Element, sources: dict[str, np.ndarray], vertices: dict[str, str]
) -> tuple[np.ndarray, np.ndarray] | None:
    """(corners, normals) of a <triangles> or all-triangle <polylist>, each (n, 3, 3)."""
    if _tag(primitive) == "polylist":
        counts = _floats(next(iter(_children(primitive, "vcount")), primitive).text)
        if len(counts) == 0 or np.any(counts != 3):
            return None
    inputs = _children(primitive, "input")
    stride = 1 + max(int(i.get("offset", 0)) for i in inputs)
    indices = np.array(
        (next(iter(_children(primitive, "p")), primitive).text or "").split(), dtype=np.int64
    ).reshape(-1, stride)
    positions = normals = None
    for item in inputs:
        semantic, source = item.get("semantic"), item.get("source", "").lstrip("#")
        column = indices[:, int(item.get("offset", 0))]
        if semantic == "VERTEX":
            positions = sources[vertices[source]][column]
        elif semantic == "NORMAL":
            normals = sources[source][column]
    if positions is None or len(positions) % 3:
        return None
    if normals is None:
        normals = np.zeros_like(positions)
    return positions.reshape(-1, 3, 3), normals.reshape(-1, 3, 3)


def read_collada(path: Path) -> list[Part]:
    """Every triangle of a COLLADA file's visual scene, in metres, grouped by material."""
    root = ElementTree.parse(path).getroot()
    unit = next((float(e.get("meter", 1.0)) for e in root.iter() if _tag(e) == "unit"), 1.0)
    colors = _diffuse_colors(root)
    geometries: dict[str, list[tuple[np.ndarray, np.ndarray, str]]] = {}
    for geometry in root.iter():
        if _tag(geometry) != "geometry":
            continue
        for mesh in _children(geometry, "mesh"):
            sources = {
                s.get("id", ""): _floats(
                    next(e for e in s.iter() if _tag(e) == "float_array").text
                ).reshape(
                    -1, int(next(e for e in s.iter() if _tag(e) == "accessor").get("stride", 3))
                )
                for s in _children(mesh, "source")
            }
            vertices = {
                v.get("id", ""): i.get("source", "").lstrip("#")
                for v in _children(mesh, "vertices")
                for i in _children(v, "input")
                if i.get("semantic") == "POSITION"
            }
            for primitive in mesh:
                if _tag(primitive) not in ("triangles", "polylist"):
                    continue
                found = _primitive_corners(primitive, sources, vertices)
                if found is not None:
                    geometries.setdefault(geometry.get("id", ""), []).append(
                        (*found, primitive.get("material", ""))
                    )
    parts: list[Part] = []

    def visit(node: ElementTree.Element, parent: np.ndarray) -> None:
        matrix = parent @ _node_matrix(node)
        for instance in _children(node, "instance_geometry"):
            bound = {
                m.get("symbol", ""): m.get("target", "").lstrip("#")
                for m in instance.iter()
                if _tag(m) == "instance_material"
            }
            for corners, normals, symbol in geometries.get(instance.get("url", "").lstrip("#"), []):
                placed = corners @ matrix[:3, :3].T + matrix[:3, 3]
                turned = normals @ np.linalg.inv(matrix[:3, :3])
                color = colors.get(bound.get(symbol, symbol), (1.0, 1.0, 1.0, 1.0))
                parts.append(Part(placed * unit, turned, color))
        for child in _children(node, "node"):
            visit(child, matrix)

    for scene in root.iter():
        if _tag(scene) == "visual_scene":
            for node in _children(scene, "node"):
                visit(node, np.eye(4))
    return parts


# ---------------------------------------------------------------- decimation


def decimate(parts: list[Part], tolerance_m: float = TOLERANCE_M) -> LightMesh:
    """All parts welded (each its own shell), simplified together (`collapse_edges`) and
    given crease-aware normals, one primitive per part."""
    corners = np.concatenate([part.corners for part in parts])
    labels = np.repeat(np.arange(len(parts)), [len(part.corners) for part in parts])
    points, faces, labels = weld(corners, labels)
    points, faces, labels = collapse_edges(points, faces, labels, tolerance_m)
    positions, normals, triangles, colors = [], [], [], []
    for index, part in enumerate(parts):
        own = faces[labels == index]
        if len(own) == 0:
            continue
        vertices, vertex_normals, indices = crease_normals(points, own)
        positions.append(vertices.astype(np.float32))
        normals.append(vertex_normals.astype(np.float32))
        triangles.append(indices.astype(np.uint32))
        colors.append(part.color)
    return LightMesh(tuple(positions), tuple(normals), tuple(triangles), tuple(colors))


def weld(corners: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, faces, labels) from (n, 3, 3) corners: equal positions (to 0.1 um) of one
    label (part) become one vertex; degenerate and repeated faces are dropped."""
    flat = corners.reshape(-1, 3)
    key = np.column_stack([np.round(flat * 1e7).astype(np.int64), np.repeat(labels, 3)])
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1, 3)
    kept = _kept_faces(faces)
    return flat[first].astype(float), faces[kept], labels[kept]


def _kept_faces(faces: np.ndarray) -> np.ndarray:
    """Indices of the faces with three distinct vertices, each vertex set once (the first)."""
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    rows = np.flatnonzero(ok)
    ordered = np.sort(faces[rows], axis=1).astype(np.int64)
    width = int(ordered.max()) + 1 if len(ordered) else 1
    key = (ordered[:, 0] * width + ordered[:, 1]) * width + ordered[:, 2]
    _, first = np.unique(key, return_index=True)
    return rows[np.sort(first)]


def _edges(faces: np.ndarray, count: int) -> np.ndarray:
    """The mesh's edges (a < b), each once, sorted."""
    pairs = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    key = distinct(pairs[:, 0].astype(np.int64) * count + pairs[:, 1])
    return np.column_stack([key // count, key % count])


def _planes(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (and zero for slivers) and areas of the faces."""
    cross = np.cross(
        points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]]
    )
    length = np.linalg.norm(cross, axis=1)
    unit = np.divide(cross, length[:, None], out=np.zeros_like(cross), where=length[:, None] > 0)
    return unit, length / 2.0


def _initial_quadrics(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex: the area-weighted sum of its faces' plane quadrics, and that area; open
    edges add a plane across them so that the border does not shrink."""
    unit, area = _planes(points, faces)
    plane = np.column_stack([unit, -np.einsum("ij,ij->i", unit, points[faces[:, 0]])])
    quadric = area[:, None, None] * plane[:, :, None] * plane[:, None, :]
    q = np.zeros((len(points), 4, 4))
    weight = np.zeros(len(points))
    for corner in range(3):
        np.add.at(q, faces[:, corner], quadric)
        np.add.at(weight, faces[:, corner], area)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    owner = np.tile(np.arange(len(faces)), 3)
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    open_edge = counts[inverse.reshape(-1)] == 1
    a, b = edges[open_edge, 0], edges[open_edge, 1]
    along = points[b] - points[a]
    across = np.cross(along, unit[owner[open_edge]])
    length = np.linalg.norm(across, axis=1)
    across = np.divide(
        across, length[:, None], out=np.zeros_like(across), where=length[:, None] > 0
    )
    border = np.column_stack([across, -np.einsum("ij,ij->i", across, points[a])])
    strength = (BORDER_WEIGHT * np.einsum("ij,ij->i", along, along))[:, None, None]
    border_quadric = strength * border[:, :, None] * border[:, None, :]
    np.add.at(q, a, border_quadric)
    np.add.at(q, b, border_quadric)
    return q, np.maximum(weight, 1e-30)


def _edge_costs(
    points: np.ndarray, q: np.ndarray, weight: np.ndarray, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per edge, the best place for the merged vertex (the quadric's minimum if it lies near
    the edge, else the better end or the middle) and its mean squared distance to the planes."""
    a, b = edges[:, 0], edges[:, 1]
    total = q[a] + q[b]
    pa, pb = points[a], points[b]
    candidates = [pa, pb, (pa + pb) / 2.0]
    matrix, vector = total[:, :3, :3], total[:, :3, 3]
    scale = np.trace(matrix, axis1=1, axis2=2) / 3.0
    det = np.linalg.det(matrix)
    solvable = np.abs(det) > 1e-6 * np.maximum(scale, 1e-300) ** 3
    safe = np.where(solvable[:, None, None], matrix, np.eye(3))
    optimum = np.linalg.solve(safe, -vector[:, :, None])[:, :, 0]
    near = np.linalg.norm(optimum - candidates[2], axis=1) <= np.linalg.norm(pb - pa, axis=1)
    candidates.append(np.where((solvable & near)[:, None], optimum, candidates[2]))
    stacked = np.stack(candidates, axis=1)
    homogeneous = np.concatenate([stacked, np.ones((len(edges), 4, 1))], axis=2)
    errors = np.einsum("kci,kij,kcj->kc", homogeneous, total, homogeneous)
    best = np.argmin(errors, axis=1)
    rows = np.arange(len(edges))
    cost = np.maximum(errors[rows, best], 0.0) / (weight[a] + weight[b])
    return stacked[rows, best], cost


def collapse_edges(
    points: np.ndarray, faces: np.ndarray, labels: np.ndarray, tolerance_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quadric-error edge collapse (Garland and Heckbert 1997), in rounds: every round merges,
    all at once, the cheapest edges whose neighbourhoods do not touch, as long as the merged
    vertex stays within `tolerance_m` (RMS) of the original surface, no face flips over and
    the surface stays a surface (the link condition)."""
    q, weight = _initial_quadrics(points, faces)
    points = points.copy()
    limit = tolerance_m**2
    for _ in range(MAX_ROUNDS):
        edges = _edges(faces, len(points))
        targets, cost = _edge_costs(points, q, weight, edges)
        candidate = cost <= limit
        candidate &= _link_condition(edges, candidate, faces)
        candidate &= ~_flips(points, faces, edges, candidate, targets)
        if not candidate.any():
            break
        # Cheapest first, by classes of cost (a factor of 1.4 apart), in a fixed pseudo-random
        # order within a class: many edges of a smooth region can go in the same round.
        bucket = np.floor(2.0 * np.log2(np.maximum(cost, 1e-30) / limit)).clip(-40, 0)
        scramble = (edges[:, 0] * 2654435761 + edges[:, 1] * 40503) % 1000003
        order = np.flatnonzero(candidate)[np.lexsort((scramble[candidate], bucket[candidate]))]
        big = len(edges)
        rank = np.full(len(edges), big)
        rank[order] = np.arange(len(order))
        lowest = _min_at(len(points), edges.reshape(-1), np.repeat(rank, 2), big)
        chosen = candidate & (rank == lowest[edges[:, 0]]) & (rank == lowest[edges[:, 1]])
        while chosen.any():  # merges that share a face are checked together, until none flips
            bad = _joint_flips(points, faces, edges, chosen, targets, rank)
            if not bad.any():
                break
            chosen &= ~bad
        if not chosen.any():
            break
        a, b = edges[chosen, 0], edges[chosen, 1]
        points[a] = targets[chosen]
        q[a] += q[b]
        weight[a] += weight[b]
        remap = np.arange(len(points))
        remap[b] = a
        faces = remap[faces]
        kept = _kept_faces(faces)
        faces, labels = faces[kept], labels[kept]
    used = distinct(faces)
    index = np.full(len(points), -1)
    index[used] = np.arange(len(used))
    return points[used], index[faces], labels


def _min_at(size: int, index: np.ndarray, values: np.ndarray, empty: int) -> np.ndarray:
    """out[i] = min(values[index == i]) (or `empty`), by sorting (np.minimum.at is slow)."""
    out = np.full(size, empty, dtype=values.dtype)
    order = np.lexsort((values, index))
    index, values = index[order], values[order]
    first = np.concatenate([[True], index[1:] != index[:-1]])
    out[index[first]] = values[first]
    return out


def _joint_flips(
    points: np.ndarray,
    faces: np.ndarray,
    edges: np.ndarray,
    chosen: np.ndarray,
    targets: np.ndarray,
    rank: np.ndarray,
) -> np.ndarray:
    """Per chosen edge: True if, with every chosen edge merged at once, a face it moves turns
    by over 60 degrees or becomes a sliver."""
    picked = np.flatnonzero(chosen)
    edge_at = np.full(len(points), -1)
    edge_at[edges[picked, 0]] = picked
    edge_at[edges[picked, 1]] = picked
    touching = edge_at[faces]
    moved = touching >= 0
    rows = np.flatnonzero(moved.any(axis=1))
    own = touching[rows]
    same = (own[:, 0] >= 0) & ((own[:, 0] == own[:, 1]) | (own[:, 0] == own[:, 2]))
    same |= (own[:, 1] >= 0) & (own[:, 1] == own[:, 2])
    rows, own = rows[~same], own[~same]  # faces on a merged edge disappear
    before, area_before = _planes(points, faces[rows])
    shape = points[faces[rows]]
    r, c = np.nonzero(own >= 0)
    shape[r, c] = targets[own[r, c]]
    cross = np.cross(shape[:, 1] - shape[:, 0], shape[:, 2] - shape[:, 0])
    length = np.linalg.norm(cross, axis=1)
    failed = (np.einsum("ij,ij->i", cross, before) < 0.5 * length) | (
        length / 2.0 < 1e-3 * area_before
    )
    # A face moved by two merges blames the later one: the earlier may go on its own.
    culprits = own[failed]
    order = np.where(culprits >= 0, rank[np.maximum(culprits, 0)], -1)
    blamed = culprits[np.arange(len(culprits)), np.argmax(order, axis=1)]
    return np.bincount(blamed, minlength=len(edges)) > 0


def _link_condition(edges: np.ndarray, chosen: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per edge: True unless merging it would pinch the surface (its ends share a neighbour
    that is not the third corner of a face on the edge)."""
    ok = np.ones(len(edges), dtype=bool)
    picked = np.flatnonzero(chosen)
    if len(picked) == 0:
        return ok
    both = np.concatenate([edges, edges[:, ::-1]])
    both = both[np.lexsort((both[:, 1], both[:, 0]))]
    starts = np.searchsorted(both[:, 0], np.arange(both[:, 0].max() + 2))
    width = int(both.max()) + 1
    keys = both[:, 0] * width + both[:, 1]
    a, b = (
        np.minimum(edges[picked, 0], edges[picked, 1]),
        np.maximum(edges[picked, 0], edges[picked, 1]),
    )
    degree = starts[a + 1] - starts[a]
    owner = np.repeat(np.arange(len(picked)), degree)
    offsets = np.arange(degree.sum()) - np.repeat(np.cumsum(degree) - degree, degree)
    neighbour = both[starts[a][owner] + offsets, 1]
    lookup = b[owner] * width + neighbour
    found = np.searchsorted(keys, lookup)
    shared = (found < len(keys)) & (keys[np.minimum(found, len(keys) - 1)] == lookup)
    common = np.bincount(owner, weights=shared, minlength=len(picked))
    face_edges = np.sort(
        np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [0, 2]]]), axis=1
    )
    face_keys, per_key = np.unique(face_edges[:, 0] * width + face_edges[:, 1], return_counts=True)
    wanted = a * width + b
    at = np.searchsorted(face_keys, wanted).clip(0, len(face_keys) - 1)
    faces_on_edge = np.where(face_keys[at] == wanted, per_key[at], 0)
    ok[picked] = common <= faces_on_edge
    return ok


def _flips(
    points: np.ndarray,
    faces: np.ndarray,
    edges: np.ndarray,
    chosen: np.ndarray,
    targets: np.ndarray,
) -> np.ndarray:
    """Per edge (each on its own): True if merging it would turn one of the faces around it
    by over 60 degrees or squash it to a sliver."""
    picked = np.flatnonzero(chosen)
    if len(picked) == 0:
        return np.zeros(len(edges), dtype=bool)
    corner_vertex = faces.reshape(-1)
    order = np.argsort(corner_vertex, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(corner_vertex, minlength=len(points)))])
    pairs_edge, pairs_face = [], []
    for end in (0, 1):
        ends = edges[picked, end]
        degree = start[ends + 1] - start[ends]
        owner = np.repeat(np.arange(len(picked)), degree)
        offsets = np.arange(degree.sum()) - np.repeat(np.cumsum(degree) - degree, degree)
        pairs_edge.append(owner)
        pairs_face.append(order[start[ends][owner] + offsets] // 3)
    owner, face = np.concatenate(pairs_edge), np.concatenate(pairs_face)
    corners = faces[face]
    a, b = edges[picked[owner], 0], edges[picked[owner], 1]
    moved = (corners == a[:, None]) | (corners == b[:, None])
    keep = moved.sum(axis=1) == 1  # faces on the edge itself disappear
    owner, face, moved = owner[keep], face[keep], moved[keep]
    before, area_before = _planes(points, faces[face])
    shape = points[faces[face]]
    rows, cols = np.nonzero(moved)
    shape[rows, cols] = targets[picked[owner[rows]]]
    cross = np.cross(shape[:, 1] - shape[:, 0], shape[:, 2] - shape[:, 0])
    length = np.linalg.norm(cross, axis=1)
    turned = np.einsum("ij,ij->i", cross, before) < 0.5 * length
    sliver = length / 2.0 < 1e-3 * area_before
    return np.bincount(picked[owner], weights=turned | sliver, minlength=len(edges)) > 0


def crease_normals(
    points: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, normals and triangles where a corner's normal averages the faces around its
    vertex that turn less than CREASE_DEG from its own face: round surfaces shade smooth,
    edges stay sharp (a vertex on an edge is split in two)."""
    unit, area = _planes(points, faces)
    corner_vertex = faces.reshape(-1)
    corner_face = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(corner_vertex, kind="stable")
    degree = np.bincount(corner_vertex, minlength=len(points))
    start = np.concatenate([[0], np.cumsum(degree)])
    count = degree[corner_vertex]
    owner = np.repeat(np.arange(len(corner_vertex)), count)
    offsets = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    other = corner_face[order[start[corner_vertex[owner]] + offsets]]
    mine = corner_face[owner]
    close = np.einsum("ij,ij->i", unit[mine], unit[other]) >= np.cos(np.radians(CREASE_DEG))
    summed = np.zeros((len(corner_vertex), 3))
    np.add.at(summed, owner[close], unit[other[close]] * area[other[close], None])
    summed /= np.maximum(np.linalg.norm(summed, axis=1, keepdims=True), 1e-30)
    keys = np.column_stack([corner_vertex, np.round(summed * 1e4).astype(np.int64)])
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return points[corner_vertex[first]], summed[first], inverse.reshape(-1, 3)


# ---------------------------------------------------------------- glTF


_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
"""glTF bufferView targets: vertex attributes, vertex indices."""
_FLOAT, _UNSIGNED_SHORT, _UNSIGNED_INT = 5126, 5123, 5125
"""glTF accessor component types."""


def glb_bytes(mesh: LightMesh) -> bytes:
    """A binary glTF 2.0 file: one mesh, one primitive (and material) per colour."""
    buffer = _GlbBuffer()
    primitives: list[dict[str, object]] = []
    materials: list[dict[str, object]] = []
    for positions, normals, triangles, color in zip(
        mesh.positions, mesh.normals, mesh.triangles, mesh.colors, strict=True
    ):
        primitives.append(_add_primitive(buffer, positions, normals, triangles, len(materials)))
        materials.append(
            {"pbrMetallicRoughness": {"baseColorFactor": list(color), "metallicFactor": 0.0}}
        )
    blob = buffer.padded()
    document = {
        "asset": {"version": "2.0", "generator": "keymps"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": primitives}],
        "materials": materials,
        "accessors": buffer.accessors,
        "bufferViews": buffer.views,
        "buffers": [{"byteLength": len(blob)}],
    }
    return _glb_container(json.dumps(document, separators=(",", ":")).encode(), blob)


class _GlbBuffer:
    """The binary chunk of a glb file, with the bufferViews and accessors describing it."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict[str, int]] = []
        self.accessors: list[dict[str, object]] = []

    def add(self, array: np.ndarray, target: int, kind: str, component: int, bounds: bool) -> int:
        """Append `array` (its own bufferView, 4-byte aligned); returns its accessor's index.
        `kind` is VEC3 ((n, 3) array) or SCALAR ((n,)); `bounds` adds its min and max."""
        self.padded()
        self.views.append(
            {
                "buffer": 0,
                "byteOffset": len(self.blob),
                "byteLength": array.nbytes,
                "target": target,
            }
        )
        self.blob.extend(array.tobytes())
        accessor: dict[str, object] = {
            "bufferView": len(self.views) - 1,
            "componentType": component,
            "count": int(array.size // (3 if kind == "VEC3" else 1)),
            "type": kind,
        }
        if bounds:
            accessor["min"] = array.min(axis=0).tolist()
            accessor["max"] = array.max(axis=0).tolist()
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def padded(self) -> bytes:
        """The chunk so far, zero-padded to a multiple of 4 bytes."""
        self.blob.extend(bytes(-len(self.blob) % 4))
        return bytes(self.blob)


def _add_primitive(
    buffer: _GlbBuffer,
    positions: np.ndarray,
    normals: np.ndarray,
    triangles: np.ndarray,
    material: int,
) -> dict[str, object]:
    """The glTF primitive of float32 positions and normals (n, 3) and triangles (m, 3),
    indexed in 16 bits when n allows."""
    small = len(positions) < 65536
    indices = triangles.astype(np.uint16 if small else np.uint32).reshape(-1)
    return {
        "attributes": {
            "POSITION": buffer.add(positions, _ARRAY_BUFFER, "VEC3", _FLOAT, True),
            "NORMAL": buffer.add(normals, _ARRAY_BUFFER, "VEC3", _FLOAT, False),
        },
        "indices": buffer.add(
            indices,
            _ELEMENT_ARRAY_BUFFER,
            "SCALAR",
            _UNSIGNED_SHORT if small else _UNSIGNED_INT,
            False,
        ),
        "material": material,
    }


def _glb_container(text: bytes, blob: bytes) -> bytes:
    """The glb file of a JSON chunk `text` and a binary chunk `blob` (4-byte aligned)."""
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return b"".join(
        [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(text), b"JSON"),
            text,
            struct.pack("<I4s", len(blob), b"BIN\x00"),
            blob,
        ]
    )
