"""The `litellm` planner backend and its retry policy.

This module is the plugin keymps registers: it only names the backend. The backend module (its
deadline, retry and failure policies, and through them asyncio) is imported when a task first
uses the backend; litellm itself later still, with the first request.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from keymps.plugin import RegisterVlmBackend, hookimpl

if TYPE_CHECKING:
    from keymps.default_plugins.litellm.backend import LitellmBackend


def make_backend(options: dict[str, Any]) -> LitellmBackend:
    from keymps.default_plugins.litellm.backend import make_backend as make

    return make(options)


@hookimpl
def register_vlm_backends(register: RegisterVlmBackend) -> None:
    register("litellm", make_backend)
