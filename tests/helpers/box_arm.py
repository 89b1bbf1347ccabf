"""A six-joint arm of boxes and one STL mesh, written as a URDF: a yaw, two pitches, then a wrist
(roll, pitch, roll); nothing like a UR arm (no closed form: the iterative IK solves it)."""

from __future__ import annotations

import struct

URDF = """<?xml version="1.0"?>
<robot name="boxarm">
  <link name="base_link">
    <collision><geometry><mesh filename="{mesh}"/></geometry></collision>
  </link>
  {links}
</robot>
"""
CHAIN = [
    # name, axis, origin in the parent link, box (x, y, z)
    ("j1", "0 0 1", "0 0 0.10", "0.08 0.08 0.08"),
    ("j2", "0 1 0", "0 0 0.06", "0.06 0.06 0.40"),
    ("j3", "0 1 0", "0 0 0.40", "0.35 0.05 0.05"),
    ("j4", "1 0 0", "0.35 0 0", "0.06 0.04 0.04"),
    ("j5", "0 1 0", "0.06 0 0", "0.05 0.04 0.04"),
    ("j6", "1 0 0", "0.05 0 0", "0.02 0.03 0.03"),
]
JOINTS = [name for name, *_ in CHAIN]


def urdf_text(mesh: str = "package://boxarm/meshes/base.stl") -> str:
    """The arm's URDF, its base's collision mesh at `mesh`."""
    parts, parent = [], "base_link"
    for index, (name, axis, origin, box) in enumerate(CHAIN):
        link = f"link{index + 1}"
        along = 2 if index < 2 else 0  # the first links stand up, the others reach forward
        centre = " ".join(str(float(v) / 2) if k == along else "0"
                          for k, v in enumerate(box.split()))  # fmt: skip
        parts.append(
            f'<joint name="{name}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{link}"/><origin xyz="{origin}" rpy="0 0 0"/><axis xyz="{axis}"/>'
            f'<limit lower="-3.0" upper="3.0" velocity="2.0" effort="20"/></joint>'
            f'<link name="{link}"><collision><origin xyz="{centre}"/><geometry>'
            f'<box size="{box}"/></geometry></collision></link>'
        )
        parent = link
    parts.append(
        f'<joint name="flange" type="fixed"><parent link="{parent}"/><child link="tool0"/>'
        '<origin xyz="0.03 0 0" rpy="0 1.5707963267948966 0"/></joint><link name="tool0"/>'
    )
    return URDF.format(mesh=mesh, links="\n  ".join(parts))


def stl_box(half: float) -> bytes:
    """A binary STL of a cube (12 triangles) standing on z = 0."""
    corners = [(x, y, z) for x in (-half, half) for y in (-half, half) for z in (0.0, 2 * half)]
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1)]
    faces += [(2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    body = b"".join(
        struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *corners[i]) for i in f) + b"\0\0"
        for f in faces
    )
    return b"\0" * 80 + struct.pack("<I", len(faces)) + body
