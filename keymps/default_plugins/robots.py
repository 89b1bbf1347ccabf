"""The built-in arms, registered exactly as a third party's robot plugin would register its own:
the Universal Robots family, the Franka Emika Panda, the SO-101, and `urdf`, any URDF a task
names (`robot: {urdf: arm.urdf, tip_link: tool0, limits: {...}}`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from keymps.plugin import ArmSpec, RegisterRobot, hookimpl, parse_options
from keymps.robot import catalog

URDF = "urdf"
"""The name the engine creates a task's own URDF arm by."""


class UrdfOptions(BaseModel):
    """What a task's `robot:` section says about its own URDF arm (keymps.config.task)."""

    model_config = ConfigDict(extra="forbid", defer_build=True)
    urdf: Path = Field(description="the URDF file, already checked to be inside the task's tree")
    tip_link: str = Field(min_length=1, description="the link the tool is mounted on")
    joints: tuple[str, ...] = ()
    velocity: tuple[float, ...] | None = None
    acceleration: tuple[float, ...] | None = None
    jerk: tuple[float, ...] | None = None
    home: tuple[float, ...] | None = None
    rate_hz: float = Field(125.0, ge=10, le=1000)
    package_dirs: tuple[Path, ...] = ()
    standoff: float = Field(0.2, ge=0.0, le=3.0)


def make_urdf_arm(options: dict[str, Any]) -> ArmSpec:
    """A task's own URDF arm; the limits a URDF holds (position, velocity) are its own unless
    the task gives them."""
    parsed = parse_options(UrdfOptions, options, "robot urdf")
    return ArmSpec(
        name=parsed.urdf.stem,
        urdf=parsed.urdf,
        tip_link=parsed.tip_link,
        joint_names=parsed.joints,
        velocity_limits=parsed.velocity,
        acceleration_limits=parsed.acceleration,
        jerk_limits=parsed.jerk,
        home=parsed.home,
        standoff=parsed.standoff,
        rate_hz=parsed.rate_hz,
        package_dirs=parsed.package_dirs,
        description=f"the URDF {parsed.urdf.name}",
    )


def _no_options(make: Any, name: str) -> Any:
    def factory(options: dict[str, Any]) -> ArmSpec:
        parse_options(_NoOptions, options, f"robot {name}")
        return make()  # type: ignore[no-any-return]

    return factory


class _NoOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", defer_build=True)


@hookimpl
def register_robots(register: RegisterRobot) -> None:
    for name in catalog.UR_ARMS:
        register(name, _no_options(lambda name=name: catalog.ur_spec(name), name))
    register("panda", _no_options(catalog.panda_spec, "panda"))
    register("so101", _no_options(catalog.so101_spec, "so101"))
    register(URDF, make_urdf_arm)
