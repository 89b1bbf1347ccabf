"""A backend's set-up (`prepare`) goes through one function on both paths that call it: a run's
thread (keymps.planning.planner) and the warm planner's start (keymps.planning.warm.server).
A backend written against the plain VlmBackend Protocol has no `prepare`; BackendBase's is a
no-op; a subclass may override it."""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

import pytest

from keymps.default_plugins.offline import OfflineBackend
from keymps.plugin import BackendBase, RegisterVlmBackend, hookimpl
from keymps.plugin.components import prepare_backend
from keymps.types import BackendAnswer, PlanRequest

PREPARED_VARIABLE = "KEYMPS_TEST_BACKEND_PREPARED"


class PlainBackend:
    """Written against the plain VlmBackend Protocol: no base class, no `prepare`."""

    name = "plain-prepare"
    built = 0

    def __init__(self, options: dict[str, Any]) -> None:
        PlainBackend.built += 1

    def complete(self, request: PlanRequest) -> BackendAnswer:
        return OfflineBackend().complete(request)


class BaseBackend(BackendBase):
    """Inherits BackendBase without overriding `prepare`: the no-op."""

    name = "base-prepare"

    def __init__(self, options: dict[str, Any]) -> None:
        pass


class SlowSetUpBackend(BackendBase):
    """Overrides `prepare`: records the thread it ran on and sets a variable, as an import that
    reads a .env file would."""

    name = "slow-prepare"
    prepared_on: list[str] = []

    def __init__(self, options: dict[str, Any]) -> None:
        pass

    def prepare(self) -> None:
        SlowSetUpBackend.prepared_on.append(threading.current_thread().name)
        os.environ[PREPARED_VARIABLE] = "1"


BACKENDS = (PlainBackend, BaseBackend, SlowSetUpBackend)


class PreparePlugin:
    @hookimpl
    def register_vlm_backends(self, register: RegisterVlmBackend) -> None:
        for backend in BACKENDS:
            register(backend.name, backend)


@pytest.fixture
def backends(keymps_plugins: Any, monkeypatch: pytest.MonkeyPatch) -> Any:
    keymps_plugins.register(PreparePlugin(), name="prepare-test-plugin")
    monkeypatch.delenv(PREPARED_VARIABLE, raising=False)
    PlainBackend.built = 0
    SlowSetUpBackend.prepared_on = []
    return keymps_plugins


@pytest.mark.parametrize("backend", BACKENDS, ids=lambda b: b.name)
def test_prepare_backend_runs_what_the_backend_has(backend: type) -> None:
    prepare_backend(backend({}))
    assert SlowSetUpBackend.prepared_on == (["MainThread"] if backend is SlowSetUpBackend else [])


def test_a_run_prepares_each_kind_of_backend_on_its_own_thread(backends: Any) -> None:
    from keymps.planning.planner import prepare_backend_in_background

    for backend in BACKENDS:
        thread = prepare_backend_in_background(backend.name, {})
        thread.join(timeout=60)
        assert not thread.is_alive()
    assert PlainBackend.built == 1
    assert SlowSetUpBackend.prepared_on == ["keymps-backend-prepare"]


@pytest.mark.parametrize("backend", BACKENDS, ids=lambda b: b.name)
def test_the_warm_planner_prepares_each_kind_of_backend(
    backend: type, backends: Any, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The warm planner serves litellm; another backend name stands in for it here."""
    from keymps.planning.warm import server
    from keymps.planning.warm.place import Place

    monkeypatch.setattr(server, "BACKEND", backend.name)
    planner = server.Server(Place(tmp_path), idle_timeout_s=1.0, lock=-1)
    planner.prepare()
    prepared = backend is SlowSetUpBackend
    assert SlowSetUpBackend.prepared_on == (["MainThread"] if prepared else [])
    # what the set-up put into the environment is kept for the requests, not in the process
    assert planner.loaded == ({PREPARED_VARIABLE: "1"} if prepared else {})
    assert PREPARED_VARIABLE not in os.environ
