"""keymps-mujoco: physics simulation of keymps runs in MuJoCo (executor and image source)."""

from __future__ import annotations

import os

from keymps.plugin import RegisterExecutor, RegisterImageSource, hookimpl

# MuJoCo picks its OpenGL platform when it is first imported: headless EGL unless the user
# chose another (osmesa, glfw). Mesa's EGL renders in software where there is no GPU.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    from keymps_mujoco.executor import NAME, make_executor

    register(NAME, make_executor)


@hookimpl
def register_image_sources(register: RegisterImageSource) -> None:
    from keymps_mujoco.image_source import NAME, make_source

    register(NAME, make_source)
