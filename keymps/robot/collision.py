"""An arm's collision model: the URDF's collision shapes as convex hulls in Pinocchio (coal),
and how far the arm stays from the board and from itself along a trajectory.

Meshes are read once per process (binary or ASCII STL in numpy, other formats through coal's
loader) and replaced by their convex hulls: never smaller than the mesh, and distances between
hulls cost microseconds. Pairs of links that always touch (neighbours in the chain, and pairs
in contact at the arm's home and at most sampled configurations, as MoveIt's setup assistant
finds them) are not checked against each other.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from keymps.robot.probes import probe_configurations

STEP_M = 0.01
"""No point of the arm moves more than this between two configurations the check measures;
every distance to the board measured is lowered by it (a bound for the samples in between),
every distance between two links by how far the joints between them can move one relative to
the other until the next measured configuration."""
SELF_REFINE_BELOW = 0.005
"""Pairs of links this close (hulls) at a measured configuration are measured again at every
sample, between their meshes."""
ALWAYS_TOUCHING = 0.9
"""Pairs of links in contact at this fraction of sampled configurations are never checked."""


@dataclass(frozen=True)
class Shape:
    """One <collision> element: its link, its placement in the link frame and its geometry."""

    link: str
    origin: np.ndarray
    """(4, 4) in the link frame."""
    kind: str
    """mesh, box, cylinder or sphere."""
    size: tuple[float, ...]
    """box: x, y, z; cylinder: radius, length; sphere: radius; mesh: its scale."""
    path: Path | None = None


def collision_shapes(urdf: ElementTree.Element) -> list[Shape]:
    """Every collision shape of the URDF (mesh paths as the URDF holds them: absolute)."""
    shapes = []
    for link in urdf.iter("link"):
        for element in link.findall("collision"):
            geometry = element.find("geometry")
            if geometry is None or len(geometry) == 0:
                continue
            child = geometry[0]
            shapes.append(_shape(link.get("name", ""), element.find("origin"), child))
    return shapes


def _floats(text: str | None, default: str) -> tuple[float, ...]:
    return tuple(float(v) for v in (text or default).split())


def _shape(link: str, origin: ElementTree.Element | None, child: ElementTree.Element) -> Shape:
    xyz = _floats(origin.get("xyz") if origin is not None else None, "0 0 0")
    rpy = _floats(origin.get("rpy") if origin is not None else None, "0 0 0")
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = _rpy(*rpy), xyz
    if child.tag == "mesh":
        return Shape(link, pose, "mesh", _floats(child.get("scale"), "1 1 1"),
                     Path(child.get("filename", "")))  # fmt: skip
    if child.tag == "box":
        return Shape(link, pose, "box", _floats(child.get("size"), "0 0 0"))
    if child.tag == "cylinder":
        size = (float(child.get("radius", 0)), float(child.get("length", 0)))
        return Shape(link, pose, "cylinder", size)
    return Shape(link, pose, "sphere", (float(child.get("radius", 0)),))


def _rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


@cache
def mesh_points(path: Path, scale: tuple[float, ...]) -> np.ndarray:
    """(n, 3) the distinct vertices of a mesh file, scaled (metres)."""
    data = path.read_bytes()
    if path.suffix.lower() == ".stl":
        points = _stl_points(data)
    else:
        import coal

        points = np.asarray(coal.MeshLoader().load(str(path), np.ones(3)).vertices(), float)
    return _distinct_rows(np.asarray(points, dtype=float)) * np.asarray(scale, float)


def _distinct_rows(points: np.ndarray) -> np.ndarray:
    """The distinct rows of (n, 3) points (sorted; np.unique's row mode imports numpy.ma, which
    a run never loads: keymps.sorted_values)."""
    if len(points) == 0:
        return points.reshape(0, 3)
    ordered = points[np.lexsort((points[:, 2], points[:, 1], points[:, 0]))]
    keep = np.concatenate([[True], np.any(ordered[1:] != ordered[:-1], axis=1)])
    return ordered[keep]


def _stl_points(data: bytes) -> np.ndarray:
    """Triangle corners of a binary or ASCII STL file, (m, 3)."""
    if len(data) >= 84:
        count = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if len(data) == 84 + 50 * count:  # 50-byte records: normal, 3 corners, attribute
            records = np.frombuffer(data, np.uint8, 50 * count, 84).reshape(count, 50)
            corners = np.ascontiguousarray(records[:, 12:48]).view("<f4")
            return corners.reshape(-1, 3)
    text = data.decode("ascii", errors="replace")
    rows = [line.split()[1:4] for line in text.splitlines() if line.strip().startswith("vertex")]
    if not rows:
        raise ValueError("not an STL file")
    return np.array(rows, dtype=float)


@cache
def mesh_bvh(path: str, scale: tuple[float, ...]) -> Any:
    """The mesh itself as coal's bounding-volume hierarchy (built once per process: a few
    tenths of a second for a detailed link)."""
    import coal

    data = Path(path).read_bytes()
    if path.lower().endswith(".stl"):
        corners = _stl_points(data).astype(float) * np.asarray(scale, float)
        model = coal.BVHModelOBBRSS()
        model.beginModel(len(corners) // 3, len(corners))
        model.addVertices(corners)
        model.addTriangles(np.arange(len(corners)).reshape(-1, 3))
        model.endModel()
        return model
    return coal.MeshLoader().load(path, np.asarray(scale, float))


def _hull(points: np.ndarray) -> Any:
    import coal

    vertices = coal.StdVec_Vec3s()
    vertices.extend(list(np.asarray(points, float)))
    return coal.Convex.convexHull(vertices, False, None)


def shape_geometry(shape: Shape) -> Any:
    """The coal geometry of a shape (a mesh's convex hull)."""
    import coal

    if shape.kind == "mesh":
        assert shape.path is not None
        return _hull(mesh_points(shape.path, shape.size))
    if shape.kind == "box":
        return coal.Box(*shape.size)
    if shape.kind == "cylinder":
        return coal.Cylinder(*shape.size)
    return coal.Sphere(shape.size[0])


def build_geometry(model: Any, shapes: list[Shape]) -> Any:
    """A pinocchio.GeometryModel of the shapes on `model`'s links (frames of the same name)."""
    import pinocchio as pin

    geometry = pin.GeometryModel()
    for index, shape in enumerate(shapes):
        if not model.existFrame(shape.link):
            continue
        frame = model.frames[model.getFrameId(shape.link)]
        placement = frame.placement * pin.SE3(shape.origin)
        item = pin.GeometryObject(
            f"{shape.link}_{index}",
            int(frame.parentJoint),
            int(model.getFrameId(shape.link)),
            placement,
            shape_geometry(shape),
        )
        if shape.path is not None:  # the mesh itself, for the exact distance of near pairs
            item.meshPath = str(shape.path)
            item.meshScale = np.asarray(shape.size, dtype=float)
        geometry.addGeometryObject(item)
    return geometry


class Clearances:
    """Distances from an arm placed on the board to the board's plane and between its links."""

    def __init__(self, model: Any, geometry: Any, home: np.ndarray, base_in_board: Any) -> None:
        import coal
        import pinocchio as pin

        self.model = model
        self.geometry = geometry.copy()
        for item in self.geometry.geometryObjects:
            if item.parentJoint == 0:
                item.placement = base_in_board * item.placement
        moving = [i for i, g in enumerate(self.geometry.geometryObjects) if g.parentJoint > 0]
        board = pin.GeometryObject(
            "board", 0, 0, pin.SE3.Identity(), coal.Halfspace(np.array([0, 0, 1.0]), 0.0)
        )
        board_id = self.geometry.addGeometryObject(board)
        low = [i for i in moving if not self._turns_about_vertical(i)]
        self.board_pairs = [(board_id, i) for i in low]
        self.self_pairs = self._self_pairs(moving, home)
        for a, b in [*self.board_pairs, *self.self_pairs]:
            self.geometry.addCollisionPair(pin.CollisionPair(a, b))
        self.data = model.createData()
        self.geometry_data = pin.GeometryData(self.geometry)
        self.reach = self._joint_reach()

    def _turns_about_vertical(self, index: int) -> bool:
        """A link on the first joint when that joint turns about the board's vertical: it
        cannot come down to the board (the UR shoulder, the Panda's link 1)."""
        joint = self.geometry.geometryObjects[index].parentJoint
        if joint != 1:
            return False
        axis = _joint_axis(self.model, 1)
        rotation = np.array(self.model.jointPlacements[1].rotation)
        return bool(abs(abs((rotation @ axis)[2]) - 1.0) < 1e-6)

    def _self_pairs(self, moving: list[int], home: np.ndarray) -> list[tuple[int, int]]:
        """Pairs of links not neighbours in the chain and not (nearly) always in contact."""
        import pinocchio as pin

        objects = self.geometry.geometryObjects
        parents = self.model.parents
        candidates = [
            (a, b)
            for k, a in enumerate(moving)
            for b in moving[k + 1 :]
            if objects[a].parentJoint != objects[b].parentJoint
            and parents[objects[a].parentJoint] != objects[b].parentJoint
            and parents[objects[b].parentJoint] != objects[a].parentJoint
        ]
        if not candidates:
            return []
        probe = self.geometry.copy()
        for a, b in candidates:
            probe.addCollisionPair(pin.CollisionPair(a, b))
        data, probe_data = self.model.createData(), pin.GeometryData(probe)
        spread = probe_configurations(32, self.model.nq)
        lower, upper = self.model.lowerPositionLimit, self.model.upperPositionLimit
        samples = lower + (spread + math.pi) / (2 * math.pi) * (upper - lower)
        touching = np.zeros(len(candidates))
        for q in samples:
            pin.computeCollisions(self.model, data, probe, probe_data, q, False)
            touching += [r.isCollision() for r in probe_data.collisionResults]
        pin.computeCollisions(self.model, data, probe, probe_data, home, False)
        at_home = np.array([r.isCollision() for r in probe_data.collisionResults])
        keep = (touching < ALWAYS_TOUCHING * len(samples)) & ~at_home
        return [pair for pair, kept in zip(candidates, keep, strict=True) if kept]

    def _joint_reach(self) -> np.ndarray:
        """Per joint, a bound on the distance from its axis to any collision point it moves:
        the joint offsets after it plus the farthest hull point (how far a turn of 1 rad can
        move the arm)."""
        model = self.model
        offsets = np.array([np.linalg.norm(model.jointPlacements[j].translation)
                            for j in range(model.njoints)])  # fmt: skip
        farthest = np.zeros(model.njoints)
        for item in self.geometry.geometryObjects:
            if item.parentJoint == 0 or not hasattr(item.geometry, "points"):
                continue
            points = np.asarray(item.geometry.points(), float)
            local = np.array(item.placement.rotation) @ points.T
            radius = np.linalg.norm(local.T + np.array(item.placement.translation), axis=1).max()
            farthest[item.parentJoint] = max(farthest[item.parentJoint], radius)
        reach = np.zeros(model.nq)
        for joint in range(1, model.njoints):
            after = range(joint + 1, model.njoints)
            chain = sum(offsets[k] for k in after)
            reach[model.joints[joint].idx_q] = chain + max(farthest[joint:].max(), 0.0) + 0.05
        return reach

    def measured_samples(self, qs: np.ndarray) -> np.ndarray:
        """Indexes of the samples to measure: from each measured sample, the next is the last
        one every point of the arm reaches within STEP_M of joint-space travel (or the very
        next sample after a larger step), so every sample and the motion between samples lies
        within STEP_M of a measured configuration."""
        travelled = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(qs, axis=0)) @ self.reach)])
        picked = [0]
        while picked[-1] < len(qs) - 1:
            here = picked[-1]
            after = int(np.searchsorted(travelled, travelled[here] + STEP_M, side="right")) - 1
            picked.append(max(after, here + 1))
        return np.array(picked)

    def distances(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
        """At the measured samples (indexes): lower bounds on the arm's distance to the board
        plane and between its links over the motion from each measured sample to the next,
        metres, and the pair of links closest to each other."""
        import pinocchio as pin

        qs = np.asarray(qs, float)
        picked = self.measured_samples(qs)
        found = np.empty((len(picked), len(self.board_pairs) + len(self.self_pairs)))
        model, data, geometry, results = self.model, self.data, self.geometry, self.geometry_data
        for k, i in enumerate(picked.tolist()):
            pin.computeDistances(model, data, geometry, results, qs[i])
            found[k] = [r.min_distance for r in results.distanceResults]
        boards = len(self.board_pairs)
        board = found[:, :boards].min(axis=1) - STEP_M if boards else np.full(len(picked), np.inf)
        if not self.self_pairs:
            return picked, board, np.full(len(picked), np.inf), [""] * len(picked)
        apart = found[:, boards:] - self._relative_motion(qs, picked)
        for k, column in zip(*np.nonzero(apart < SELF_REFINE_BELOW), strict=True):
            apart[k, column] = self._every_sample(qs, picked, int(k), int(column))
        closest = np.argmin(apart, axis=1)
        names = [g.name for g in geometry.geometryObjects]
        labels = [f"{names[a]} and {names[b]}" for a, b in self.self_pairs]
        return picked, board, apart.min(axis=1), [labels[j] for j in closest]

    def _every_sample(self, qs: np.ndarray, picked: np.ndarray, k: int, column: int) -> float:
        """The distance between one pair of links measured at every sample from measured sample
        k to the next (between the meshes themselves, not their hulls, where both are meshes),
        each lowered by the pair's relative motion to the sample after it."""
        import coal
        import pinocchio as pin

        stop = int(picked[min(k + 1, len(picked) - 1)])
        window = qs[int(picked[k]) : stop + 1]
        motion = self._relative_motion(window, np.arange(len(window)))[:, column]
        a, b = self.self_pairs[column]
        objects = self.geometry.geometryObjects
        exact = [_mesh_of(objects[i]) for i in (a, b)]
        worst = np.inf
        model, data, geometry, results = self.model, self.data, self.geometry, self.geometry_data
        request = coal.DistanceRequest()
        for q, moved in zip(window, motion, strict=True):
            pin.updateGeometryPlacements(model, data, geometry, results, q)
            if exact[0] is not None and exact[1] is not None:
                poses = [results.oMg[i] for i in (a, b)]
                distance = coal.distance(
                    exact[0], coal.Transform3s(poses[0].rotation, poses[0].translation),
                    exact[1], coal.Transform3s(poses[1].rotation, poses[1].translation),
                    request, coal.DistanceResult(),
                )  # fmt: skip
            else:
                pair = len(self.board_pairs) + column
                distance = pin.computeDistance(geometry, results, pair).min_distance
            worst = min(worst, distance - moved)
        return float(worst)

    def _relative_motion(self, qs: np.ndarray, picked: np.ndarray) -> np.ndarray:
        """(measured, pairs): how far one link of each pair can move relative to the other from
        a measured sample to the next (only the joints between them count)."""
        objects = self.geometry.geometryObjects
        steps = np.abs(np.diff(qs, axis=0))
        out = np.empty((len(picked), len(self.self_pairs)))
        for column, (a, b) in enumerate(self.self_pairs):
            low, high = sorted((objects[a].parentJoint, objects[b].parentJoint))
            between = np.zeros(len(self.reach))
            for joint in range(low + 1, high + 1):
                index = self.model.joints[joint].idx_q
                between[index] = self.reach[index]
            travelled = np.concatenate([[0.0], np.cumsum(steps @ between)])
            ahead = travelled[np.append(picked[1:], picked[-1])] - travelled[picked]
            out[:, column] = ahead
        return out


def _mesh_of(item: Any) -> Any:
    """The exact mesh of a geometry object built from a mesh file, else None."""
    if not item.meshPath:
        return None
    return mesh_bvh(item.meshPath, tuple(float(v) for v in item.meshScale))


def _joint_axis(model: Any, joint: int) -> np.ndarray:
    name = model.joints[joint].shortname()
    axes = {"JointModelRX": (1.0, 0, 0), "JointModelRY": (0, 1.0, 0), "JointModelRZ": (0, 0, 1.0)}
    if name in axes:
        return np.array(axes[name])
    return np.array(getattr(model.joints[joint], "axis", (0, 0, 1.0)), dtype=float)
