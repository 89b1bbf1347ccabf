"""How a run's (or an evaluation's) litellm calls reach the warm planner.

`keymps run` and `keymps eval` use the warm planner for the litellm backend when one is up
(`use`, the commands' default), start one when none is and they are asked to (`start`:
`--warm-planner` or KEYMPS_WARM_PLANNER=1), or never touch it (`off`: `--no-warm-planner`,
KEYMPS_WARM_PLANNER=0, and the Python API's default). Whatever happens to the planner, the
work goes on: a planner that is not there, does not start, or dies mid-request leaves the call
to the caller's own process, as without it.
"""

from __future__ import annotations

import os
import warnings
from typing import TYPE_CHECKING, Any

from keymps.errors import KeympsError
from keymps.planning.backend_choice import AUTO_VLM

if TYPE_CHECKING:
    import subprocess

    from keymps.planning.warm.client import PlannerUnavailable, WarmPlanner
    from keymps.types import BackendAnswer, PlanRequest

MODES = ("off", "use", "start")
ENVIRONMENT_VARIABLE = "KEYMPS_WARM_PLANNER"


def mode_from(flag: bool | None) -> str:
    """The command's mode: --warm-planner (start) or --no-warm-planner (off), else
    $KEYMPS_WARM_PLANNER (1/start, 0/off, use), else use."""
    if flag is not None:
        return "start" if flag else "off"
    value = os.environ.get(ENVIRONMENT_VARIABLE, "").strip().lower()
    named = {"": "use", "use": "use", "1": "start", "start": "start", "0": "off", "off": "off"}
    if value not in named:
        raise KeympsError(
            f"${ENVIRONMENT_VARIABLE}={value!r}: 1 (start the warm planner when none is up), "
            "0 (never use it), or use (use one that is up)"
        )
    return named[value]


class WarmDispatch:
    """A run's `dispatch(backend, request)` (and `acall` for an evaluation's broker): litellm's
    calls go to the warm planner, any other backend's to the backend itself; without a
    planner, the backend answers in this process."""

    def __init__(
        self,
        planner: WarmPlanner,
        starting: bool = False,
        process: subprocess.Popen[bytes] | None = None,
    ) -> None:
        self.planner = planner
        self.starting = starting
        """A planner is starting: wait for it at the first request."""
        self.process = process
        """The process this run started it with, if it did."""
        self.gone: str | None = None
        """Why the planner is not used any more (the rest of the run asks in this process)."""

    def __call__(self, backend: Any, request: PlanRequest) -> BackendAnswer:
        from keymps.planning.warm.client import PlannerUnavailable

        options = self._options(backend)
        if options is not None:
            try:
                if self.starting:
                    self.planner.wait_until_up(self.process)
                    self.starting = False
                return self.planner.plan(options, request)
            except PlannerUnavailable as reason:
                self._give_up(reason)
        answer: BackendAnswer = backend.complete(request)
        return answer

    async def acall(self, backend: Any, request: PlanRequest) -> BackendAnswer:
        """The same on an event loop (`keymps eval`'s broker): waits without a thread."""
        import asyncio

        from keymps.planning.warm.client import PlannerUnavailable

        options = self._options(backend)
        if options is not None:
            try:
                if self.starting:
                    await asyncio.to_thread(self.planner.wait_until_up, self.process)
                    self.starting = False
                return await self.planner.aplan(options, request)
            except PlannerUnavailable as reason:
                self._give_up(reason)
        answer: BackendAnswer = await backend.acomplete(request)
        return answer

    def _options(self, backend: Any) -> dict[str, Any] | None:
        """The options of a litellm backend whose calls go to the planner, else None."""
        options = getattr(backend, "options", None)
        if getattr(backend, "name", None) != AUTO_VLM or options is None or self.gone:
            return None
        dumped: dict[str, Any] = options.model_dump()
        return dumped

    def _give_up(self, reason: PlannerUnavailable) -> None:
        if self.gone is None:
            self.gone = f"the warm planner {reason}: planning in this process"
            warnings.warn(self.gone, RuntimeWarning, stacklevel=3)


def warm_dispatch(mode: str) -> WarmDispatch | None:
    """A run's dispatch through the warm planner, or None when the run asks in its own
    process: mode off, or no planner up and `use`. `start` starts one when none is up (the
    run then waits for it at its first request, while its own stages run meanwhile)."""
    from keymps.planning.warm.place import supported

    if mode not in MODES:
        raise KeympsError(f"warm_planner={mode!r}: one of {', '.join(MODES)}")
    if mode == "off" or not supported():  # (not on Windows, macOS: no SO_PEERCRED)
        return None
    from keymps.planning.warm.client import WarmPlanner

    planner = WarmPlanner()
    if problem := planner.folder_problem():
        warnings.warn(f"{problem}: planning in this process", RuntimeWarning, stacklevel=2)
        return None
    if planner.status() is not None:
        return WarmDispatch(planner)
    if mode == "use":
        return None
    if planner.lock_held():  # another run is starting one: wait for it as for one's own
        return WarmDispatch(planner, starting=True)
    try:
        return WarmDispatch(planner, starting=True, process=planner.start())
    except KeympsError as error:
        warnings.warn(f"{error}: planning in this process", RuntimeWarning, stacklevel=2)
        return None
