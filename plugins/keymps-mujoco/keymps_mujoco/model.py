"""The MuJoCo model of a task: the run's arm with its tool, the board, the objects, two cameras.

Everything is placed in keymps' board frame (metres, z up out of the board, the board's top at
z = 0). The arm's kinematic tree, joint limits, inertias and link geometry (the convex hulls of
its collision shapes) come from the same Pinocchio model keymps plans and checks with
(keymps.robot.urdf_model, for any arm), so simulated and planned kinematics agree exactly.
Contacts: the tool and the arm's links touch the board; nothing touches the food (no fracture
is simulated: cuts are measured from where the blade went).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

if TYPE_CHECKING:
    from keymps.robot.description import Tool
    from keymps.robot.model import RobotModel

TORQUE_LIMITS_NM = (56.0, 56.0, 28.0, 12.0, 12.0, 12.0)
"""UR3/UR3e peak joint torques (Universal Robots' "Max. joint torques" article): base,
shoulder, elbow, wrists; every arm's own come from its ArmSpec (RobotModel.effort_limits)."""
ARMATURE_PER_NM = 0.2 / 56.0
"""Reflected rotor inertia of a joint's drive per N m of its peak torque, kg m^2 (not published:
the UR3's estimate, 0.2 kg m^2 at 56 N m, 0.043 at 12 N m; it mostly steadies light wrists)."""
BOARD_THICKNESS_M = 0.02
TOP_CAMERA = "top"
PERSPECTIVE_CAMERA = "perspective"
ARM_GROUP = 1
"""Geom group of the arm and tool (hidden for the outcome image)."""
CONTACT_BOARD, CONTACT_TOOL = 1, 2
"""Collision bits: the board touches the tool and the arm; nothing else touches anything."""
ARM_RGBA = (0.62, 0.66, 0.72, 1.0)
JOINT_CAP_RGBA = (0.25, 0.45, 0.75, 1.0)
STEEL_RGBA = (0.78, 0.8, 0.83, 1.0)
HANDLE_RGBA = (0.12, 0.12, 0.12, 1.0)
BAG_RGBA = (0.92, 0.92, 0.95, 0.85)


@dataclass(frozen=True)
class Prop:
    """An object on the board: its footprint (board metres) extruded to its height."""

    outline_m: np.ndarray
    """(N, 2), counter-clockwise."""
    height: float
    rgba: tuple[float, float, float, float] = (0.8, 0.6, 0.35, 1.0)
    name: str = "object"


@dataclass(frozen=True)
class Settings:
    """How the physics is integrated and how stiff the joint servos are."""

    timestep_s: float = 0.002
    bandwidth_hz: float = 12.0
    """Natural frequency of each joint's position servo."""
    damping_ratio: float = 1.0
    top_size_px: tuple[int, int] = (600, 360)
    perspective_size_px: tuple[int, int] = (480, 360)


@dataclass
class SimScene:
    """The compiled model, its state, and the ids the executor reads."""

    model: Any
    data: Any
    spec: Any
    tcp_site: int
    tool_geoms: frozenset[int]
    board_geom: int
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    kp: np.ndarray
    kv: np.ndarray
    timestep_s: float
    """The physics step the scene was built with (a simulation shortens the model's to divide
    its controller period; `reset` puts this one back)."""
    texture_id: int = -1
    """The 2D texture on the board's and the objects' tops (-1: plain colours)."""
    texture_size: tuple[int, int] = (0, 0)
    props: tuple[Prop, ...] = field(default=())

    def set_joints(self, q: np.ndarray) -> None:
        """Put the arm at `q` at rest and hold it there."""
        import mujoco

        self.data.qpos[self.qpos_adr] = q
        self.data.qvel[self.dof_adr] = 0.0
        self.data.ctrl[:] = q
        mujoco.mj_forward(self.model, self.data)

    def reset(self, q: np.ndarray) -> None:
        """Back to the state of a newly built scene, the arm at rest at `q` (radians): time 0,
        no velocity, actuator state, contact or solver warm start left from an earlier
        simulation, and the built timestep."""
        import mujoco

        mujoco.mj_resetData(self.model, self.data)
        self.model.opt.timestep = self.timestep_s
        self.set_joints(q)


def build_scene(
    robot: RobotModel | None,
    board_size: tuple[float, float],
    board_shift: tuple[float, float],
    props: tuple[Prop, ...] = (),
    texture_rgb: np.ndarray | None = None,
    settings: Settings = Settings(),
) -> SimScene:
    """Compile the scene (without an arm when `robot` is None).

    Args:
        robot: The arm with its tool, or None for the board and objects alone.
        board_size: The workspace's (width, height), metres.
        board_shift: The board frame's position of the workspace's bottom-left corner, metres.
        props: The objects on the board.
        texture_rgb: (H, W, 3) uint8 RGB image spanning the workspace, painted on the tops of
            the board and the objects; None: plain colours.
        settings: The integration and servo settings and the cameras' image sizes.

    Returns:
        The compiled model and its data, at rest (the arm, if any, at its working pose).
    """
    import mujoco

    spec = _new_spec(settings)
    image = None if texture_rgb is None else _texture_rows(texture_rgb)
    top_material = None if image is None else _add_top_material(spec, image)
    _add_surroundings(spec, board_size, board_shift)
    _add_board(spec, board_size, board_shift, top_material)
    for index, prop in enumerate(props):
        _add_prop(spec, prop, index, board_size, board_shift, top_material)
    tool_names = [] if robot is None else _add_arm(spec, robot)
    _add_cameras(spec, board_size, board_shift, settings)
    model = spec.compile()
    if image is not None:
        _paint_texture(model, image)
    scene = _sim_scene(model, spec, robot, tool_names, props)
    if robot is not None:
        _tune_servos(scene, robot, settings)
    mujoco.mj_forward(model, scene.data)  # place every geom before anything is rendered
    return scene


def _new_spec(settings: Settings) -> Any:
    """An empty MjSpec with the physics options, the offscreen buffer and the lighting."""
    import mujoco

    spec = mujoco.MjSpec()
    spec.modelname = "keymps"
    spec.option.timestep = settings.timestep_s
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.compiler.degree = False
    spec.visual.global_.offwidth = max(settings.top_size_px[0], settings.perspective_size_px[0])
    spec.visual.global_.offheight = max(settings.top_size_px[1], settings.perspective_size_px[1])
    spec.visual.quality.shadowsize = 1024
    # headlight + sun add up to about 1 on the board seen from above: the top-down camera
    # shows the texture's own colours
    spec.visual.headlight.ambient = [0.3, 0.3, 0.3]
    spec.visual.headlight.diffuse = [0.25, 0.25, 0.25]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.stat.extent = 1.0
    return spec


def _texture_rows(texture_rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 image in OpenGL's row order (row 0 at v = 0, the image's bottom)."""
    return np.ascontiguousarray(texture_rgb[::-1], dtype=np.uint8)


def _add_top_material(spec: Any, image: np.ndarray) -> str:
    """The `tops` texture, sized for `image` (H, W, 3), and its material; returns its name."""
    import mujoco

    spec.add_texture(
        name="tops",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        width=int(image.shape[1]),
        height=int(image.shape[0]),
        nchannel=3,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_FLAT,  # a placeholder the image overwrites
        rgb1=[0.5, 0.5, 0.5],
        rgb2=[0.5, 0.5, 0.5],
    )
    material = spec.add_material(name="tops", rgba=[1, 1, 1, 1], specular=0.0, shininess=0.0)
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "tops"
    return "tops"


def _paint_texture(model: Any, image: np.ndarray) -> None:
    """Write the pixels of `image` (H, W, 3) straight into the compiled `tops` texture."""
    import mujoco

    texture = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXTURE, "tops")
    start = int(model.tex_adr[texture])
    model.tex_data[start : start + image.size] = image.ravel()


def _add_surroundings(spec: Any, size: tuple[float, float], shift: tuple[float, float]) -> None:
    """The sun, the sky and the table the board lies on."""
    import mujoco

    world = spec.worldbody
    world.add_light(
        name="sun",
        pos=[shift[0] + 0.3, shift[1] - 0.4, 1.2],
        dir=[-0.25, 0.35, -1],
        diffuse=[0.5, 0.5, 0.5],
        specular=[0.1, 0.1, 0.1],
        castshadow=True,
    )
    spec.add_texture(
        name="sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.85, 0.88, 0.92],
        rgb2=[0.35, 0.38, 0.42],
        width=64,
        height=64,
    )
    world.add_geom(  # seen by the perspective camera only
        name="table",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[1.5, 1.5, 0.05],
        pos=[shift[0] + size[0] / 2, shift[1], -BOARD_THICKNESS_M],
        rgba=[0.55, 0.57, 0.6, 1.0],
        contype=0,
        conaffinity=0,
    )


def _sim_scene(
    model: Any, spec: Any, robot: RobotModel | None, tool_names: list[str], props: tuple[Prop, ...]
) -> SimScene:
    """The SimScene of a compiled model: fresh data and the ids and addresses the executor
    reads (the servo gains still zero)."""
    import mujoco

    def named(kind: Any, name: str) -> int:
        return int(mujoco.mj_name2id(model, kind, name))

    joints = (
        [] if robot is None else [named(mujoco.mjtObj.mjOBJ_JOINT, n) for n in robot.joint_names]
    )
    texture_id = named(mujoco.mjtObj.mjOBJ_TEXTURE, "tops")
    return SimScene(
        model=model,
        data=mujoco.MjData(model),
        spec=spec,
        tcp_site=-1 if robot is None else named(mujoco.mjtObj.mjOBJ_SITE, "tcp"),
        tool_geoms=frozenset(named(mujoco.mjtObj.mjOBJ_GEOM, name) for name in tool_names),
        board_geom=named(mujoco.mjtObj.mjOBJ_GEOM, "board"),
        qpos_adr=np.array([model.jnt_qposadr[j] for j in joints], dtype=int),
        dof_adr=np.array([model.jnt_dofadr[j] for j in joints], dtype=int),
        kp=np.zeros(len(joints)),
        kv=np.zeros(len(joints)),
        timestep_s=float(model.opt.timestep),
        texture_id=texture_id,
        texture_size=(0, 0) if texture_id < 0 else _texture_size(model, texture_id),
        props=props,
    )


def _texture_size(model: Any, texture_id: int) -> tuple[int, int]:
    """(width, height) of a compiled texture, pixels."""
    return int(model.tex_width[texture_id]), int(model.tex_height[texture_id])


def _tune_servos(scene: SimScene, robot: RobotModel, settings: Settings) -> None:
    """kp = I w^2 and kv = 2 zeta I w per joint, I the joint's inertia at a working pose."""
    import mujoco

    model, data = scene.model, scene.data
    from keymps.errors import KeympsError

    try:
        q = robot.tool_down_seed(np.array([*_board_centre(robot), 0.1]), 0.0)
    except KeympsError:  # an arm that cannot point there: its home configuration
        q = robot.arm_model.home
    scene.set_joints(q)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    inertia = np.diag(full)[scene.dof_adr]
    omega = 2 * math.pi * settings.bandwidth_hz
    scene.kp[:] = inertia * omega**2
    scene.kv[:] = 2 * settings.damping_ratio * inertia * omega
    for index in range(len(scene.dof_adr)):
        model.actuator_gainprm[index, 0] = scene.kp[index]
        model.actuator_biasprm[index, 1] = -scene.kp[index]
        model.actuator_biasprm[index, 2] = -scene.kv[index]


def _board_centre(robot: RobotModel) -> tuple[float, float]:
    width, height = robot.board_size
    return width / 2, height / 2


def prism(
    outline: np.ndarray, bottom: float, top: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, faces and the board xy of each vertex for `outline` extruded from bottom to
    top: a triangulated top face and the side walls (each wall quad with its own vertices)."""
    ring = np.asarray(outline, dtype=float).reshape(-1, 2)
    n = len(ring)
    top_faces = triangulate(ring)
    vertices = [np.column_stack([ring, np.full(n, top)])]
    faces = [top_faces]
    nxt = np.roll(np.arange(n), -1)
    a, b = ring, ring[nxt]
    walls = np.stack(
        [
            np.column_stack([a, np.full(n, bottom)]),
            np.column_stack([b, np.full(n, bottom)]),
            np.column_stack([b, np.full(n, top)]),
            np.column_stack([a, np.full(n, top)]),
        ],
        axis=1,
    ).reshape(-1, 3)
    base = n + 4 * np.arange(n)[:, None]
    wall_faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
    vertices.append(walls)
    faces.append(wall_faces)
    all_vertices = np.concatenate(vertices)
    return all_vertices, np.concatenate(faces).astype(np.int32), all_vertices[:, :2]


def triangulate(ring: np.ndarray) -> np.ndarray:
    """(n - 2, 3) triangles of a simple counter-clockwise polygon (ear clipping)."""
    remaining = list(range(len(ring)))
    triangles: list[tuple[int, int, int]] = []
    guard = 0
    while len(remaining) > 3 and guard < 4 * len(ring):
        guard += 1
        count = len(remaining)
        for k in range(count):
            i, j, m = remaining[k - 1], remaining[k], remaining[(k + 1) % count]
            if _is_ear(ring, i, j, m, remaining):
                triangles.append((i, j, m))
                del remaining[k]
                break
        else:  # no ear (a self-touching outline): fan the rest
            break
    for k in range(1, len(remaining) - 1):
        triangles.append((remaining[0], remaining[k], remaining[k + 1]))
    return np.array(triangles, dtype=np.int32).reshape(-1, 3)


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def _is_ear(ring: np.ndarray, i: int, j: int, m: int, remaining: list[int]) -> bool:
    a, b, c = ring[i], ring[j], ring[m]
    if _cross(a, b, c) <= 1e-14:
        return False
    for k in remaining:
        if k in (i, j, m):
            continue
        p = ring[k]
        if _cross(a, b, p) >= 0 and _cross(b, c, p) >= 0 and _cross(c, a, p) >= 0:
            return False
    return True


def _texcoords(xy: np.ndarray, size: tuple[float, float], shift: tuple[float, float]) -> Any:
    """Each vertex's place in the workspace image (u right, v up: OpenGL)."""
    u = (xy[:, 0] - shift[0]) / size[0]
    v = (xy[:, 1] - shift[1]) / size[1]
    return np.column_stack([u, v]).ravel().tolist()


def _add_board(
    spec: Any, size: tuple[float, float], shift: tuple[float, float], material: str | None
) -> None:
    import mujoco

    w, h = size
    sx, sy = shift
    ring = np.array([[sx, sy], [sx + w, sy], [sx + w, sy + h], [sx, sy + h]])
    vertices, faces, xy = prism(ring, -BOARD_THICKNESS_M, 0.0)
    mesh = spec.add_mesh(name="board", uservert=vertices.ravel().tolist())
    mesh.userface = faces.ravel().tolist()
    if material:
        mesh.usertexcoord = _texcoords(xy, size, shift)
    geom = spec.worldbody.add_geom(
        name="board",
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname="board",
        contype=CONTACT_BOARD,
        conaffinity=CONTACT_TOOL,
        rgba=[0.72, 0.56, 0.38, 1.0],
        solref=[0.01, 1.0],  # a wooden or plastic board gives a little
        friction=[0.3, 0.005, 0.0001],
    )
    if material:
        geom.material = material
        geom.rgba = [1.0, 1.0, 1.0, 1.0]  # the texture's own colours


def _add_prop(
    spec: Any,
    prop: Prop,
    index: int,
    size: tuple[float, float],
    shift: tuple[float, float],
    material: str | None,
) -> None:
    import mujoco

    name = f"object_{index + 1}"
    vertices, faces, xy = prism(prop.outline_m, 0.0, max(prop.height, 0.001))
    mesh = spec.add_mesh(name=name, uservert=vertices.ravel().tolist())
    mesh.userface = faces.ravel().tolist()
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
    if material:
        mesh.usertexcoord = _texcoords(xy, size, shift)
    geom = spec.worldbody.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname=name,
        contype=0,
        conaffinity=0,
        rgba=list(prop.rgba),
    )
    if material:
        geom.material = material
        geom.rgba = [1.0, 1.0, 1.0, 1.0]


def _add_arm(spec: Any, robot: RobotModel) -> list[str]:
    """The arm's kinematic tree from its Pinocchio model (one body per joint), the convex hulls
    of its collision shapes on their bodies, a servo on every joint; returns the tool geoms."""
    pin_model = robot.model
    base_pose = robot.base_in_board
    base = spec.worldbody.add_body(
        name="arm_base", pos=list(base_pose.translation), quat=_quat(base_pose.rotation)
    )
    bodies = {0: base}
    for joint in range(1, pin_model.njoints):
        placement = pin_model.jointPlacements[joint]
        if pin_model.parents[joint] == 0:  # the base placement is folded into these
            placement = base_pose.inverse() * placement
        parent = bodies[pin_model.parents[joint]]
        bodies[joint] = _add_joint_body(spec, parent, robot, joint, placement)
    _add_link_geoms(spec, robot, bodies)
    return _add_tool(bodies[robot.arm_model.flange_joint], robot)


def _add_joint_body(spec: Any, parent: Any, robot: RobotModel, joint: int, placement: Any) -> Any:
    """The body moved by Pinocchio joint `joint`, its hinge and its position servo."""
    import mujoco

    pin_model = robot.model
    inertia = pin_model.inertias[joint]
    name = pin_model.names[joint]
    index = pin_model.joints[joint].idx_q
    body = parent.add_body(
        name=f"{name}_body",
        pos=list(placement.translation),
        quat=_quat(placement.rotation),
        mass=max(float(inertia.mass), 1e-3),
        ipos=list(inertia.lever),
        fullinertia=_full_inertia(np.array(inertia.inertia) + 1e-6 * np.eye(3)),
        gravcomp=1.0,
    )
    shortname = pin_model.joints[joint].shortname()
    axes: dict[str, list[float]] = {"JointModelRX": [1.0, 0, 0], "JointModelRY": [0, 1.0, 0]}
    axis = axes.get(shortname, [0, 0, 1.0])
    if shortname == "JointModelRevoluteUnaligned":
        axis = [float(v) for v in pin_model.joints[joint].axis]
    effort = float(robot.effort_limits[index]) or 50.0
    body.add_joint(
        name=name,
        type=mujoco.mjtJoint.mjJNT_HINGE,
        axis=axis,
        range=[float(robot.lower[index]), float(robot.upper[index])],
        armature=ARMATURE_PER_NM * effort,
        damping=0.0,
        actgravcomp=True,
    )
    actuator = spec.add_actuator(
        name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT, inheritrange=0.0
    )
    actuator.set_to_position(kp=1.0, kv=0.0)
    actuator.ctrllimited = False
    return body


def _add_link_geoms(spec: Any, robot: RobotModel, bodies: dict[int, Any]) -> None:
    """Each collision shape's convex hull (MuJoCo takes the hull of the points it is given)
    on the body of its joint, drawn in the arm's group; the links beyond the first joint
    touch the board."""
    import mujoco

    first = {j for j in bodies if j > 0 and robot.model.parents[j] == 0}
    for index, item in enumerate(robot.arm_model.collision.geometryObjects):
        if not hasattr(item.geometry, "points"):
            continue  # a box, cylinder or sphere of the URDF: not drawn
        mesh_name = f"arm_mesh_{index}"
        points = np.asarray(item.geometry.points(), dtype=float)
        spec.add_mesh(name=mesh_name, uservert=points.ravel().tolist())
        joint = int(item.parentJoint)
        bodies[joint].add_geom(
            name=f"arm_{item.name}",
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mesh_name,
            pos=list(item.placement.translation),
            quat=_quat(item.placement.rotation),
            group=ARM_GROUP,
            contype=0 if joint == 0 or joint in first else CONTACT_TOOL,
            conaffinity=0,
            rgba=list(JOINT_CAP_RGBA if joint in first else ARM_RGBA),
        )


def _add_tool(wrist: Any, robot: RobotModel) -> list[str]:
    """The tool body at the tool mount (tool z out of it) with the `tcp` site at its tip."""
    pin_model = robot.model
    flange = pin_model.frames[robot.flange_frame].placement
    body = wrist.add_body(
        name="tool", pos=list(flange.translation), quat=_quat(flange.rotation), gravcomp=1.0
    )
    tool = robot.tool
    names = tool_geoms(body, tool)
    body.add_site(name="tcp", pos=list(tool.tcp), size=[0.002, 0.002, 0.002], group=ARM_GROUP)
    return names


@dataclass(frozen=True)
class _ToolPart:
    """One geom of a tool in the flange frame (metres, kilograms)."""

    name: str
    shape: Literal["box", "cylinder"]
    size: list[float]
    """MuJoCo's size: half extents of a box; radius and half length of a cylinder."""
    pos: list[float]
    rgba: tuple[float, ...]
    mass: float
    along: np.ndarray | None = None
    """(3,) the direction of a cylinder not along the flange's z axis."""


def tool_geoms(body: Any, tool: Tool) -> list[str]:
    """Geometry of the tool in the flange frame; returns the names of its geoms."""
    import mujoco

    shapes = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER}
    names = []
    for part in _tool_parts(tool):
        geom = body.add_geom(
            name=part.name,
            type=shapes[part.shape],
            size=part.size,
            pos=part.pos,
            rgba=list(part.rgba),
            mass=part.mass,
            group=ARM_GROUP,
            contype=CONTACT_TOOL,
            conaffinity=CONTACT_BOARD,
            solref=[0.01, 1.0],
        )
        if part.along is not None:
            quat = np.zeros(4)
            mujoco.mju_quatZ2Vec(quat, part.along)
            geom.quat = quat.tolist()
        names.append(part.name)
    return names


def _tool_parts(tool: Tool) -> list[_ToolPart]:
    """A knife, a piping bag, or for any other tool a rod from the flange to its tip."""
    tip = np.asarray(tool.tcp, dtype=float)
    if tool.blade_length > 0:
        return _knife_parts(tip, float(tool.blade_length))
    if tool.name == "piping_bag":
        return _piping_bag_parts(tip)
    length = float(np.linalg.norm(tip))
    along = tip / max(length, 1e-9)
    return [
        _ToolPart(
            "tool_rod", "cylinder", [0.006, length / 2, 0], list(tip / 2), STEEL_RGBA, 0.2, along
        )
    ]


def _knife_parts(tip: np.ndarray, blade_length: float) -> list[_ToolPart]:
    """A shank down from the flange, the blade at the tip (`tip` (3,) in the flange frame)."""
    reach = float(tip[2])
    blade_height = min(0.04, 0.5 * reach)
    shank = reach - blade_height
    return [
        _ToolPart(
            "tool_shank", "cylinder", [0.012, shank / 2, 0], [0, 0, shank / 2], HANDLE_RGBA, 0.3
        ),
        _ToolPart(
            "tool_blade",
            "box",
            [blade_length / 2, 0.001, blade_height / 2],
            [tip[0] - blade_length / 2, tip[1], reach - blade_height / 2],
            STEEL_RGBA,
            0.15,
        ),
    ]


def _piping_bag_parts(tip: np.ndarray) -> list[_ToolPart]:
    """A bag tapering to a nozzle whose end is the tip (`tip` (3,) in the flange frame)."""
    reach = float(tip[2])
    bag, taper = 0.6 * reach, 0.25 * reach
    nozzle = reach - bag - taper
    return [
        _ToolPart("tool_bag", "cylinder", [0.035, bag / 2, 0], [0, 0, bag / 2], BAG_RGBA, 0.3),
        _ToolPart(
            "tool_taper", "cylinder", [0.015, taper / 2, 0], [0, 0, bag + taper / 2], BAG_RGBA, 0.05
        ),
        _ToolPart(
            "tool_nozzle",
            "cylinder",
            [0.004, nozzle / 2, 0],
            [tip[0], tip[1], reach - nozzle / 2],
            STEEL_RGBA,
            0.01,
        ),
    ]


def _add_cameras(
    spec: Any, size: tuple[float, float], shift: tuple[float, float], settings: Settings
) -> None:
    """`top`: orthographic, straight down, spanning the workspace exactly as the task's image
    does (image x = board x, image y = -board y); `perspective`: from the front left, above."""
    import mujoco

    w, h = size
    cx, cy = shift[0] + w / 2, shift[1] + h / 2
    top = spec.worldbody.add_camera(name=TOP_CAMERA, pos=[cx, cy, 1.5], quat=[1, 0, 0, 0])
    top.proj = mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC
    # orthographic: fovy is the image's height in metres; the pixel aspect sets its width
    top.fovy = h
    # from beyond the board's far edge (the arm's base is at the near edge), looking back
    eye = np.array([cx + 0.25 * w + 0.15, cy + 0.5 * h + 0.42, 0.42])
    target = np.array([cx, cy - 0.08, 0.06])
    spec.worldbody.add_camera(
        name=PERSPECTIVE_CAMERA, pos=eye.tolist(), quat=_look_at(eye, target), fovy=45.0
    )


def _look_at(eye: np.ndarray, target: np.ndarray) -> list[float]:
    """Camera quaternion looking from eye to target with board z up in the image."""
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rotation = np.column_stack([right, up, -forward])  # camera x, y, z in the world
    return _quat(rotation)


def _quat(rotation: np.ndarray) -> list[float]:
    import mujoco

    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation, dtype=float).ravel())
    return quat.tolist()


def _full_inertia(matrix: np.ndarray) -> list[float]:
    m = matrix
    return [m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2]]
