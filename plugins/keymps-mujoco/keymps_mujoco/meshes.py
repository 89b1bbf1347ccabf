"""The UR3's link meshes for MuJoCo: read once from example-robot-data's STL files, then cached.

MuJoCo cannot read the URDF's visual meshes (COLLADA), so the collision STLs serve for both
drawing and contact. Each is converted once into welded vertices and faces (an .npz in the user
cache folder, keyed by the STL's content), which MuJoCo takes directly: no STL parsing or
vertex welding on later runs.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

LINK_MESHES = {
    "base_link": "base",
    "shoulder_link": "shoulder",
    "upper_arm_link": "upperarm",
    "forearm_link": "forearm",
    "wrist_1_link": "wrist1",
    "wrist_2_link": "wrist2",
    "wrist_3_link": "wrist3",
}
"""URDF link -> its mesh file stem (meshes/ur3/collision/STEM.stl)."""
WELD_M = 1e-6
"""Vertices closer than this are one vertex."""
CACHE_VERSION = 1


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray
    """(n, 3) float, metres, in the link frame."""
    faces: np.ndarray
    """(m, 3) int, counter-clockwise seen from outside."""


def cache_dir() -> Path:
    """KEYMPS_CACHE_DIR/mujoco-meshes, else the user's cache folder (platformdirs)."""
    configured = os.environ.get("KEYMPS_CACHE_DIR")
    if configured:
        return Path(configured).expanduser() / "mujoco-meshes"
    import platformdirs

    return Path(platformdirs.user_cache_dir("keymps")) / "mujoco-meshes"


def mesh_folder() -> Path:
    from keymps.robot.description import ur_urdf_path

    return ur_urdf_path().parent.parent / "meshes" / "ur3" / "collision"


def arm_meshes() -> dict[str, Mesh]:
    """Every UR3 link's mesh, by URDF link name (converted on first use, then from the cache)."""
    folder = mesh_folder()
    return {link: cached_mesh(folder / f"{stem}.stl") for link, stem in LINK_MESHES.items()}


def cached_mesh(stl: Path) -> Mesh:
    """The STL file as welded vertices and faces, from the cache when it was converted before."""
    data = stl.read_bytes()
    key = hashlib.sha256(data).hexdigest()[:16]
    target = cache_dir() / f"{stl.stem}-{key}-v{CACHE_VERSION}.npz"
    if target.is_file():
        try:
            with np.load(target) as stored:
                return Mesh(stored["vertices"], stored["faces"])
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache entry: convert again
    mesh = weld(read_stl(data, str(stl)))
    _store(target, mesh)
    return mesh


def _store(target: Path, mesh: Mesh) -> None:
    """Write atomically; a read-only cache only costs the conversion next time."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(partial, vertices=mesh.vertices, faces=mesh.faces)
        partial.replace(target)
    except OSError:
        pass


def read_stl(data: bytes, name: str = "mesh") -> np.ndarray:
    """(m, 3, 3) triangle corners of a binary or ASCII STL file."""
    if len(data) >= 84:
        count = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if len(data) == 84 + 50 * count:
            record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
            return np.frombuffer(data, record, count, 84)["corners"].astype(float)
    text = data.decode("ascii", errors="replace")
    numbers = [line.split()[1:4] for line in text.splitlines() if line.strip().startswith("vertex")]
    if not numbers or len(numbers) % 3:
        raise ValueError(f"{name}: not an STL file")
    return np.array(numbers, dtype=float).reshape(-1, 3, 3)


def weld(triangles: np.ndarray) -> Mesh:
    """Shared vertices for the triangles' corners; degenerate triangles dropped."""
    corners = triangles.reshape(-1, 3)
    keys = np.round(corners / WELD_M).astype(np.int64)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    faces = inverse.reshape(-1, 3)
    keep = (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    )
    return Mesh(unique.astype(float) * WELD_M, faces[keep].astype(np.int32))
