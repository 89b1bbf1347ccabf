"""The typed plugin contract: create_* return their Protocol (checked by mypy and at run time),
backend abilities are declared flags, and the answer mode travels on the request."""

from __future__ import annotations

import asyncio
import json
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from keymps.default_plugins.offline import OfflineBackend
from keymps.errors import KeympsError
from keymps.plugin import BackendAbilities, BackendBase, hookimpl
from keymps.plugin.manager import (
    create_detector,
    create_executor,
    create_image_source,
    create_robot,
    create_vlm_backend,
)
from keymps.run import RunOptions, RunOverrides
from keymps.types import AnswerMode, BackendAnswer, PlanRequest

REPO = Path(__file__).resolve().parents[2]


class PlainBackend:
    """Written against the plain VlmBackend Protocol: no base class, no flags."""

    name = "plain"

    def complete(self, request: PlanRequest) -> BackendAnswer:
        return OfflineBackend().complete(request)


class AsyncBackend(BackendBase):
    """Declares supports_async: eval's broker calls acomplete on its loop."""

    name = "async-offline"
    asks_model = False
    supports_async = True
    calls: list[str] = []

    def complete(self, request: PlanRequest) -> BackendAnswer:
        AsyncBackend.calls.append("complete")
        return OfflineBackend().complete(request)

    async def acomplete(self, request: PlanRequest) -> BackendAnswer:
        AsyncBackend.calls.append("acomplete")
        await asyncio.sleep(0)
        return OfflineBackend().complete(request)


class FlagWithoutMethod(BackendBase):
    name = "flag-only"
    supports_async = True

    def complete(self, request: PlanRequest) -> BackendAnswer:
        return BackendAnswer(text="{}")


class NoDetect:
    def find(self, scene: Any) -> None:
        return None


class TypedPlugin:
    @hookimpl
    def register_vlm_backends(self, register: Any) -> None:
        register("plain", lambda options: PlainBackend())
        register("async-offline", lambda options: AsyncBackend())
        register("flag-only", lambda options: FlagWithoutMethod())
        register("none", lambda options: None)

    @hookimpl
    def register_detectors(self, register: Any) -> None:
        register("no-detect", lambda options: NoDetect())

    @hookimpl
    def register_executors(self, register: Any) -> None:
        register("none", lambda options: None)

    @hookimpl
    def register_robots(self, register: Any) -> None:
        register("half-arm", lambda options: NoDetect())


@pytest.fixture
def typed_plugins(keymps_plugins: Any) -> Any:
    keymps_plugins.register(TypedPlugin(), name="typed-test-plugin")
    AsyncBackend.calls = []
    return keymps_plugins


def _task(tmp_path: Path) -> Path:
    text = (REPO / "tasks/cake_icing.yaml").read_text()
    text = text.replace("scenes/round_cake.png", str(REPO / "tasks/scenes/round_cake.png"))
    text = text.replace("../prompts/icing.md", str(REPO / "prompts/icing.md"))
    path = tmp_path / "task.yaml"
    path.write_text(text)
    return path


def test_mypy_sees_each_create_function_return_its_protocol(tmp_path: Path) -> None:
    """No Any flows out of the manager into Components: mypy proves the types (a wrong
    assert_type in the same snippet is reported, so the check can fail)."""
    from mypy import api

    snippet = tmp_path / "typed_snippet.py"
    snippet.write_text(
        textwrap.dedent(
            """
            from typing import assert_type

            from keymps.pipeline.engine import Components
            from keymps.planning.session import PlanSession
            from keymps.plugin.components import Arm, Detector, Executor, ImageSource, VlmBackend
            from keymps.plugin.manager import (
                create_detector, create_executor, create_image_source, create_robot,
                create_vlm_backend,
            )

            assert_type(create_detector("board"), Detector)
            assert_type(create_image_source("file"), ImageSource)
            assert_type(create_executor("sim"), Executor)
            assert_type(create_robot("ur3"), Arm)
            assert_type(create_vlm_backend("offline"), VlmBackend)

            def parts(components: Components, session: PlanSession) -> None:
                assert_type(components.detector, Detector | None)
                assert_type(components.image_source, ImageSource | None)
                assert_type(components.executor, Executor | None)
                assert_type(session.backend, VlmBackend)
                assert_type(create_detector("board"), Executor)  # wrong on purpose
            """
        )
    )
    out, err, status = api.run(
        [str(snippet), "--warn-return-any", "--no-error-summary", "--hide-error-context"]
    )
    errors = [line for line in out.splitlines() if ": error:" in line]
    assert len(errors) == 1, out + err
    assert "typed_snippet.py:23:" in errors[0] and "assert-type" in errors[0]
    assert status == 1


def test_a_backend_without_the_base_class_gets_the_defaults(
    typed_plugins: Any, tmp_path: Path
) -> None:
    backend = create_vlm_backend("plain")
    assert BackendAbilities.of(backend) == BackendAbilities()
    assert BackendAbilities() == BackendAbilities(
        asks_model=True, cacheable=False, supports_async=False
    )
    assert BackendAbilities.of(OfflineBackend()).asks_model is False
    run = __import__("keymps").run_task(
        _task(tmp_path),
        options=RunOptions(rerun="off", no_cache=True),
        overrides=RunOverrides(backend="plain", executor="sim", out=tmp_path / "run"),
    )
    record = json.loads((run.folder / "run.json").read_text())
    assert run.stages.execute is not None and run.stages.execute.ok
    assert record["backend"] == "plain"
    assert all(call.model_call for call in run.stages.plan.calls)  # asks_model's default


def test_a_backend_declaring_supports_async_is_dispatched_by_the_broker(
    typed_plugins: Any, tmp_path: Path
) -> None:
    """The plan stage hands each call to eval's VlmBroker, which awaits acomplete."""
    import keymps
    from keymps.eval.broker import VlmBroker

    broker = VlmBroker(2)
    try:
        run = keymps.run_task(
            _task(tmp_path),
            options=RunOptions(rerun="off", no_cache=True, dispatch=broker.complete),
            overrides=RunOverrides(backend="async-offline", out=tmp_path / "run"),
            through="ground",
        )
        plain = keymps.run_task(
            _task(tmp_path),
            options=RunOptions(rerun="off", no_cache=True, dispatch=broker.complete),
            overrides=RunOverrides(backend="plain", out=tmp_path / "plain"),
            through="ground",
        )
    finally:
        broker.close()
    assert run.stages.plan is not None and plain.stages.plan is not None
    assert AsyncBackend.calls and set(AsyncBackend.calls) == {"acomplete"}


def test_supports_async_without_acomplete_is_refused_naming_the_backend(
    typed_plugins: Any,
) -> None:
    with pytest.raises(KeympsError) as caught:
        create_vlm_backend("flag-only")
    assert str(caught.value) == (
        "vlm backend 'flag-only' declares supports_async but implements no async acomplete(request)"
    )


@pytest.mark.parametrize(
    ("create", "name", "expected"),
    [
        (
            create_executor,
            "none",
            "executor 'none' of plugin 'typed-test-plugin': its factory returned None, "
            "not an Executor (keymps.plugin.Executor)",
        ),
        (
            create_vlm_backend,
            "none",
            "vlm backend 'none' of plugin 'typed-test-plugin': its factory returned None, "
            "not a VlmBackend (keymps.plugin.VlmBackend)",
        ),
        (
            create_detector,
            "no-detect",
            "detector 'no-detect' of plugin 'typed-test-plugin': its factory returned a "
            "NoDetect without detect(), not a Detector (keymps.plugin.Detector)",
        ),
        (
            create_robot,
            "half-arm",
            "robot 'half-arm' of plugin 'typed-test-plugin': its factory returned a NoDetect "
            "without acceleration_limits, not an Arm (keymps.plugin.Arm)",
        ),
    ],
)
def test_a_factory_returning_a_wrong_object_is_one_line_naming_the_plugin(
    typed_plugins: Any, create: Any, name: str, expected: str
) -> None:
    with pytest.raises(KeympsError) as caught:
        create(name)
    assert str(caught.value) == expected


def test_a_wrong_executor_stops_the_run_before_any_stage_at_its_task_field(
    typed_plugins: Any, tmp_path: Path
) -> None:
    import keymps

    with pytest.raises(KeympsError) as caught:
        keymps.run_task(
            _task(tmp_path),
            overrides=RunOverrides(executor="none", out=tmp_path / "run"),
        )
    message = str(caught.value)
    assert "\n" not in message and "task.yaml:" in message
    assert message.endswith(
        "executor: executor 'none' of plugin 'typed-test-plugin': its "
        "factory returned None, not an Executor (keymps.plugin.Executor)"
    )
    assert not (tmp_path / "run").exists()
    assert create_image_source("file") is not None


def _request(mode: AnswerMode, step: Any = "combined") -> PlanRequest:
    """A request as the session builds it, but with no schema: the mode is the only hint."""
    return PlanRequest(
        instruction="cut it into 6 equal slices",
        crop=np.full((240, 240, 3), 200, np.uint8),
        crop_mask=None,
        metres_per_px=(0.001, 0.001),
        primitives={"cut": "a straight knife cut", "line": "an icing line"},
        object_height=0.05,
        max_pairs=20,
        messages=[],
        schema={},
        step=step,
        answer_mode=mode,
    )


@pytest.mark.parametrize(
    ("mode", "keys"),
    [
        ("pairs", {"keyword", "pairs", "rationale"}),
        ("either", {"keyword", "pairs", "rationale"}),
        ("design", {"keyword", "design", "rationale"}),
    ],
)
def test_the_offline_backend_answers_the_mode_on_the_request(
    mode: AnswerMode, keys: set[str]
) -> None:
    answer = json.loads(OfflineBackend().complete(_request(mode)).text)
    assert set(answer) == keys
    pairs_only = json.loads(OfflineBackend().complete(_request(mode, "pairs")).text)
    assert set(pairs_only) == keys - {"keyword"}
    keyword_only = json.loads(OfflineBackend().complete(_request(mode, "keyword")).text)
    assert set(keyword_only) == {"keyword", "rationale"}
    if mode == "design":
        assert (answer["design"]["name"], answer["design"]["count"]) == ("equal", 6)
    else:
        assert len(answer["pairs"]) == 3  # 6 equal slices: 3 cuts through the centre
