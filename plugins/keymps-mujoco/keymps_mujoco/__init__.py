"""keymps-mujoco: physics simulation of keymps runs in MuJoCo (executor and image source).

This module is what keymps loads for every command: it only registers factories. The executor
and the image source (MuJoCo, the scene builder) are imported when a task first uses them.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

from keymps.plugin import RegisterExecutor, RegisterImageSource, hookimpl

if TYPE_CHECKING:
    from keymps_mujoco.executor import MujocoExecutor
    from keymps_mujoco.image_source import MujocoSource

# MuJoCo picks its OpenGL platform when it is first imported: headless EGL unless the user
# chose another (osmesa, glfw). Mesa's EGL renders in software where there is no GPU.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"

NAME = "mujoco"
"""The executor's and the image source's name (`executor.name`, `scene.source`)."""


def make_executor(options: dict[str, Any]) -> MujocoExecutor:
    from keymps_mujoco.executor import make_executor as make

    return make(options)


def make_source(options: dict[str, Any]) -> MujocoSource:
    from keymps_mujoco.image_source import make_source as make

    return make(options)


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    register(NAME, make_executor)


@hookimpl
def register_image_sources(register: RegisterImageSource) -> None:
    register(NAME, make_source)
