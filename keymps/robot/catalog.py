"""The arms keymps ships, described from the URDFs of the example-robot-data wheel and the
makers' published numbers (sources in docs/robot.md): the Universal Robots CB3 and e-Series
arms, the Franka Emika Panda and the LeRobot SO-101."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

from keymps.errors import KeympsError
from keymps.plugin.arms import ArmSpec, degrees

SHARE = "cmeel.prefix/share/example-robot-data/robots"


def example_robot_data(relative: str) -> Path:
    """A file or folder of the example-robot-data wheel (robots/...)."""
    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        raise KeympsError(
            "the built-in arms need the example-robot-data package (pip install example-robot-data)"
        ) from None
    path = Path(str(dist.locate_file(f"{SHARE}/{relative}")))
    if not path.exists():
        raise KeympsError(f"example-robot-data is installed but {path} is missing")
    return path


_FAST = degrees(180, 180, 180, 360, 360, 360)
_EVEN = degrees(180, 180, 180, 180, 180, 180)
_HEAVY = degrees(120, 120, 180, 180, 180, 180)

UR_ARMS: dict[str, dict[str, object]] = {
    # DH (d1, a2, a3, d4, d5, d6): Universal Robots, "DH parameters for calculations of
    # kinematics and dynamics"; joint speeds and torques: each arm's user manual.
    "ur3": {"dh": (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819), "urdf": "ur3",
            "speed": _FAST, "torque": (56, 56, 28, 12, 12, 12), "rate": 125.0},
    "ur5": {"dh": (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823), "urdf": "ur5",
            "speed": _EVEN, "torque": (150, 150, 150, 28, 28, 28), "rate": 125.0},
    "ur10": {"dh": (0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922), "urdf": "ur10",
             "speed": _HEAVY, "torque": (330, 330, 150, 56, 56, 56), "rate": 125.0},
    "ur3e": {"dh": (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921), "urdf": "ur3",
             "speed": _FAST, "torque": (56, 56, 28, 12, 12, 12), "rate": 500.0},
    "ur5e": {"dh": (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996), "urdf": "ur5",
             "speed": _EVEN, "torque": (150, 150, 150, 28, 28, 28), "rate": 500.0},
    "ur10e": {"dh": (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655), "urdf": "ur10",
              "speed": _HEAVY, "torque": (330, 330, 150, 56, 56, 56), "rate": 500.0},
    "ur16e": {"dh": (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655), "urdf": "ur10",
              "speed": _HEAVY, "torque": (330, 330, 150, 54, 54, 54), "rate": 500.0},
    "ur20": {"dh": (0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543), "urdf": "ur10",
             "speed": degrees(120, 120, 150, 210, 210, 210),
             "torque": (738, 738, 433, 107, 107, 107), "rate": 500.0},
}  # fmt: skip
"""Per model: the DH table, the CB3 URDF whose meshes draw it, joint speeds (rad/s), peak
joint torques (N m) and the controller rate (Hz)."""

UR_STANDOFF = {"ur3": 0.22, "ur3e": 0.22, "ur5": 0.25, "ur5e": 0.25, "ur16e": 0.30}
"""Metres from the board's near edge to the base, by model (the others: 0.35)."""
UR_HOME = (0.0, -1.9, 1.9, -1.57, -1.57, 0.0)
"""Elbow up, wrist outward, the tool pointing down in front of the base."""
_URDF_LENGTHS = {"ur3": (-0.24365, -0.21325), "ur5": (-0.425, -0.39225), "ur10": (-0.612, -0.5723)}


def ur_spec(name: str) -> ArmSpec:
    """A Universal Robots arm: the CB3 URDF of its size, its lengths set to its DH table."""
    table = UR_ARMS[name]
    urdf_name = str(table["urdf"])
    dh = table["dh"]
    assert isinstance(dh, tuple)
    # A link the shipped mesh is too short or too long for is stretched along its length.
    a2, a3 = _URDF_LENGTHS[urdf_name]
    stretch = tuple(
        (link, (1.0, 1.0, round(mine / shipped, 6)))
        for link, mine, shipped in (("upper_arm_link", dh[1], a2), ("forearm_link", dh[2], a3))
        if abs(mine - shipped) > 0.01
    )
    package = example_robot_data("ur_description")
    return ArmSpec(
        name=name,
        urdf=package / "urdf" / f"{urdf_name}_robot.urdf",
        tip_link="tool0",
        joint_names=(),
        velocity_limits=table["speed"],  # type: ignore[arg-type]
        effort_limits=tuple(float(v) for v in table["torque"]),  # type: ignore[attr-defined]
        home=UR_HOME,
        standoff=UR_STANDOFF.get(name, 0.35),
        rate_hz=float(table["rate"]),  # type: ignore[arg-type]
        dh=dh,  # type: ignore[arg-type]
        package_dirs=(package,),
        collision_padding=0.02 if name == "ur20" else 0.0,
        mesh_scales=stretch,
        description=f"Universal Robots {name.upper().replace('E', 'e')}",
    )


def panda_spec() -> ArmSpec:
    """The Franka Emika Panda with its hand: the tool is held at the hand's tool centre point
    (between the fingertips, 10.34 cm below the flange), the fingers closed on it."""
    package = example_robot_data("panda_description")
    return ArmSpec(
        name="panda",
        urdf=package / "urdf" / "panda.urdf",
        tip_link="panda_hand_tcp",
        joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)),
        # Franka's "Robot and interface specifications": velocity, acceleration, jerk.
        velocity_limits=(2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
        acceleration_limits=(15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
        jerk_limits=(7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0),
        effort_limits=(87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0),
        home=(0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398),
        standoff=0.30,
        rate_hz=1000.0,
        package_dirs=(package,),
        description="Franka Emika Panda (with the Franka Hand)",
    )


def so101_spec() -> ArmSpec:
    """The SO-101 (LeRobot): five joints, the tool held in its gripper (gripper_frame_link,
    between the jaw tips, z along the jaws)."""
    package = example_robot_data("so_arm_description")
    return ArmSpec(
        name="so101",
        urdf=package / "urdf" / "so101.urdf",
        tip_link="gripper_frame_link",
        joint_names=("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"),
        # Feetech STS3215 (7.4 V): 0.222 s per 60 degrees at no load, 4.7 rad/s.
        velocity_limits=(4.7,) * 5,
        acceleration_limits=(10.0,) * 5,
        jerk_limits=(200.0,) * 5,
        home=(0.0, -0.6, 0.6, 1.4, 0.0),
        # Its reach, gripper pointing down, is 10-30 cm from the base and up to 5 cm above
        # the base's foot: raised by 10 cm, it holds a 10 cm knife down to the board.
        standoff=0.10,
        mount_height=0.10,
        rate_hz=100.0,
        package_dirs=(package,),
        description="SO-101 (LeRobot), 5 joints",
    )
