"""Planning (Sec. IV-B/C): the primitive keyword and K keypoint pairs, from any backend.

make_plan renders the prompt, asks the backend (one combined call, or keyword then pairs),
validates each answer, sends invalid ones back with the problems for repair, records every
attempt under run.folder/vlm, and answers from the cache or records to a cassette on request.

Backend protocol (what a `register_vlm_backends` factory returns; see docs/vlm.md):

    class MyBackend:
        name = "mine"
        cacheable = True          # answers may be cached on disk (paid or slow backends)
        def complete(self, request: PlanRequest) -> BackendAnswer: ...

The factory receives the planner options: model, api_base, api_key_env, temperature,
timeout_s, cassette (None when unset).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from keymps.errors import KeympsError
from keymps.plan_answer import Step, answer_schema, parse_and_validate
from keymps.stages import Detection, Plan, SceneImage, VlmCall

if TYPE_CHECKING:
    from keymps.run import Run
    from keymps.task import Task


@dataclass(frozen=True)
class PlanRequest:
    """Everything a backend may use to answer one planning call."""

    instruction: str
    crop: np.ndarray
    """The image sent (BGR, uint8): the object's crop."""
    crop_mask: np.ndarray | None
    """The object's pixels in the crop (bool), when the detector gives them."""
    metres_per_px: tuple[float, float]
    """Metres per crop pixel along x and y."""
    primitives: Mapping[str, str]
    """Primitive name -> description (the keyword must be one of the names)."""
    object_height: float
    max_pairs: int
    messages: list[dict[str, Any]]
    """The rendered chat: system prompt, the sentence with the crop as a PNG data URL, repairs."""
    schema: dict[str, Any]
    """The answer's JSON schema ({"name", "strict", "schema"}, OpenAI response_format style)."""
    step: Step = "combined"
    keyword: str | None = None
    """For step 'pairs': the primitive chosen by the 'keyword' call."""
    previous_errors: tuple[str, ...] = ()
    """Problems with the previous attempt's answer (empty on the first attempt)."""
    attempt: int = 1
    model: str | None = None
    temperature: float = 0.0
    timeout_s: float = 60.0
    task_name: str = ""

    @property
    def crop_size_px(self) -> tuple[int, int]:
        return int(self.crop.shape[1]), int(self.crop.shape[0])


@dataclass(frozen=True)
class BackendAnswer:
    """A backend's raw answer and what it cost."""

    text: str
    prompt_tokens: int | None = None
    completion_tokens: int | None = None
    latency_s: float = 0.0
    cost_usd: float | None = None
    """None where the price is unknown (e.g. a local model without a registered price)."""
    model: str | None = None


class PlannerBackend(Protocol):
    name: str
    cacheable: bool

    def complete(self, request: PlanRequest) -> BackendAnswer: ...


# --- choosing a backend ----------------------------------------------------------------------

PROVIDER_KEYS: dict[str, tuple[str, ...]] = {
    "openai": ("OPENAI_API_KEY",),
    "anthropic": ("ANTHROPIC_API_KEY",),
    "gemini": ("GEMINI_API_KEY", "GOOGLE_API_KEY"),
    "vertex_ai": ("GOOGLE_APPLICATION_CREDENTIALS",),
    "azure": ("AZURE_API_KEY",),
    "mistral": ("MISTRAL_API_KEY",),
    "groq": ("GROQ_API_KEY",),
    "openrouter": ("OPENROUTER_API_KEY",),
    "together_ai": ("TOGETHERAI_API_KEY", "TOGETHER_API_KEY"),
    "xai": ("XAI_API_KEY",),
    "deepseek": ("DEEPSEEK_API_KEY",),
    "bedrock": ("AWS_ACCESS_KEY_ID",),
    "ollama": ("OLLAMA_API_BASE",),
    "ollama_chat": ("OLLAMA_API_BASE",),
    "hosted_vllm": ("HOSTED_VLLM_API_BASE",),
}
"""litellm provider prefix -> environment variables that configure it (any one suffices)."""


def model_provider(model: str) -> str:
    """The litellm provider of a model string ('openai/gpt-4o' -> 'openai', 'claude-...')."""
    if "/" in model:
        return model.split("/", 1)[0]
    if model.startswith("claude"):
        return "anthropic"
    if model.startswith("gemini"):
        return "gemini"
    return "openai"


def credential_source(task: Task, model: str) -> str | None:
    """Which environment variable configures `model`, or None when none is set."""
    names = ((task.planner.api_key_env,) if task.planner.api_key_env else ()) + PROVIDER_KEYS.get(
        model_provider(model), ()
    )
    return next((name for name in names if os.environ.get(name)), None)


def choose_backend(
    task: Task,
    backend_override: str | None,
    model_override: str | None,
    api_base_override: str | None,
) -> tuple[str, str]:
    """(backend name, one sentence saying why): `auto` means a VLM when one is configured."""
    requested = backend_override or task.planner.backend
    model = model_override or task.planner.model
    api_base = api_base_override or task.planner.api_base
    if requested != "auto":
        origin = "--backend" if backend_override else "the task's planner.backend"
        return requested, f"{origin} asks for the {requested} planner"
    if not model:
        return "offline", "no VLM model is configured (planner.model or --model): offline planner"
    if api_base:
        return "litellm", f"model {model} is served at {api_base}"
    source = credential_source(task, model)
    if source:
        return "litellm", f"model {model} with credentials from ${source}"
    wanted = ((task.planner.api_key_env,) if task.planner.api_key_env else ()) + PROVIDER_KEYS.get(
        model_provider(model), ()
    )
    need = " or ".join(f"${n}" for n in wanted) or "an api_base"
    return (
        "offline",
        f"model {model} has no credentials ({need} unset, no api_base): offline planner",
    )


# --- the planning session --------------------------------------------------------------------


def backend_options(task: Task) -> dict[str, Any]:
    """What a backend factory receives: the planner settings a backend may need."""
    planner = task.planner
    return {
        "model": planner.model,
        "api_base": planner.api_base,
        "api_key_env": planner.api_key_env,
        "temperature": planner.temperature,
        "timeout_s": planner.timeout_s,
        "cassette": str(task.resolve(planner.cassette)) if planner.cassette else None,
    }


def crop_metres_per_px(task: Task, detection: Detection, scene: SceneImage) -> tuple[float, float]:
    """Metres per pixel at the crop's centre, along x and y (Appendix B or the camera's homography)."""
    width, height = scene.size_px
    try:
        from keymps.geometry import ImageFrame
    except ModuleNotFoundError as error:
        if error.name != "keymps.geometry":
            raise
        ws = task.scene.workspace.size
        return ws[0] / width, ws[1] / height
    frame = ImageFrame.from_task(task, (width, height))
    cx = detection.crop_origin_px[0] + detection.crop_size_px[0] / 2
    cy = detection.crop_origin_px[1] + detection.crop_size_px[1] / 2
    board = frame.to_board(np.array([[cx, cy], [cx + 1, cy], [cx, cy + 1]], dtype=float))
    return (
        float(np.linalg.norm(board[1] - board[0])),
        float(np.linalg.norm(board[2] - board[0])),
    )


def crop_mask(detection: Detection, scene: SceneImage) -> np.ndarray | None:
    """The detector's mask cut to the crop (it may cover the crop or the whole image)."""
    mask = detection.mask
    if mask is None:
        return None
    w, h = detection.crop_size_px
    if mask.shape[:2] == (h, w):
        return np.asarray(mask).astype(bool)
    if mask.shape[:2] == scene.image.shape[:2]:
        x0, y0 = detection.crop_origin_px
        return np.asarray(mask[y0 : y0 + h, x0 : x0 + w]).astype(bool)
    return None


_SECRET_KEY = re.compile(r"(api[_-]?key|authorization|secret|token|password)", re.IGNORECASE)


def _secrets(task: Task) -> list[str]:
    names = set(PROVIDER_KEYS.get(model_provider(task.planner.model or ""), ()))
    if task.planner.api_key_env:
        names.add(task.planner.api_key_env)
    names |= {n for n in os.environ if n.endswith(("_API_KEY", "_TOKEN", "_SECRET"))}
    return [v for n in names if len(v := os.environ.get(n, "")) >= 8]


def redact(value: Any, secrets: list[str]) -> Any:
    """Drop credential-like keys and blank out any secret value anywhere in `value`."""
    if isinstance(value, dict):
        return {
            k: (
                "[redacted]"
                if _SECRET_KEY.search(str(k)) and k != "prompt_tokens"
                else redact(v, secrets)
            )
            for k, v in value.items()
        }
    if isinstance(value, list | tuple):
        return [redact(v, secrets) for v in value]
    if isinstance(value, str):
        for secret in secrets:
            value = value.replace(secret, "[redacted]")
        return value
    return value


def _without_image(messages: list[dict[str, Any]], image_url: str, image_file: str) -> list[Any]:
    digest = "sha256:" + hashlib.sha256(image_url.encode()).hexdigest()
    text = json.dumps(messages)
    text = text.replace(json.dumps(image_url), json.dumps(f"{digest} (file: {image_file})"))
    return list(json.loads(text))


@dataclass
class _Session:
    task: Task
    run: Run
    backend_name: str
    backend: Any
    base: PlanRequest
    system_template: str
    template_source: str
    image_url: str
    calls: list[VlmCall] = field(default_factory=list)

    def __post_init__(self) -> None:
        planner = self.task.planner
        self.use_cache = bool(
            getattr(self.backend, "cacheable", False)
            and planner.cache
            and not self.run.options.no_cache
        )
        self.secrets = _secrets(self.task)
        self.vlm_folder = self.run.folder / "vlm"

    def request_for(
        self, step: Step, keyword: str | None, history: list[tuple[str, list[str]]]
    ) -> PlanRequest:
        from keymps.plan_prompt import build_messages, render_template, template_values

        values = template_values(
            instruction=self.base.instruction,
            primitives=self.base.primitives,
            crop_size_px=self.base.crop_size_px,
            metres_per_px=self.base.metres_per_px,
            object_height=self.base.object_height,
            max_pairs=self.base.max_pairs,
            step=step,
        )
        system_text = render_template(self.system_template, values, self.template_source)
        messages = build_messages(
            system_text,
            self.base.instruction,
            self.image_url,
            self.base.crop_size_px,
            keyword,
            history,
        )
        schema = answer_schema(step, list(self.base.primitives), self.base.max_pairs)
        return replace(
            self.base,
            messages=messages,
            schema=schema,
            step=step,
            keyword=keyword,
            previous_errors=tuple(history[-1][1]) if history else (),
            attempt=len(history) + 1,
        )

    def ask(self, step: Step, keyword: str | None = None) -> Any:
        from keymps.plan_answer import parse_and_validate

        history: list[tuple[str, list[str]]] = []
        attempts = self.task.planner.attempts
        for _ in range(attempts):
            request = self.request_for(step, keyword, history)
            answer, cached = self._complete(request)
            parsed, problems = parse_and_validate(
                answer.text,
                step,
                list(self.base.primitives),
                self.base.crop_size_px,
                self.base.max_pairs,
            )
            self._record(request, answer, problems, cached)
            if parsed is not None:
                if self.use_cache and not cached:
                    self._cache_put(request, answer)
                return parsed
            history.append((answer.text, problems))
        last = "; ".join(history[-1][1][:4])
        raise KeympsError(
            f"the {self.backend_name} planner gave no valid {step} answer in {attempts} "
            f"attempt(s): {last} (every attempt is in {self.vlm_folder})"
        )

    def _cache_key(self, request: PlanRequest) -> str:
        from keymps.vlm_cache import request_digest

        return request_digest(request.messages, request.schema, request.model or self.backend_name)

    def _cache_put(self, request: PlanRequest, answer: Any) -> None:
        from keymps.vlm_cache import AnswerCache

        AnswerCache().put(
            self._cache_key(request),
            {
                "text": answer.text,
                "prompt_tokens": answer.prompt_tokens,
                "completion_tokens": answer.completion_tokens,
                "cost_usd": answer.cost_usd,
                "model": answer.model,
            },
        )

    def _complete(self, request: PlanRequest) -> tuple[BackendAnswer, bool]:
        if self.use_cache:
            from keymps.vlm_cache import AnswerCache

            hit = AnswerCache().get(self._cache_key(request))
            if hit is not None:
                return (
                    BackendAnswer(
                        text=hit["text"],
                        prompt_tokens=hit.get("prompt_tokens"),
                        completion_tokens=hit.get("completion_tokens"),
                        latency_s=0.0,
                        cost_usd=0.0,
                        model=hit.get("model"),
                    ),
                    True,
                )
        started = time.perf_counter()
        try:
            answer = self.backend.complete(request)
        except KeympsError as error:
            failed = BackendAnswer(text="", latency_s=time.perf_counter() - started)
            self._record(request, failed, [str(error)], False)
            raise
        if not isinstance(answer, BackendAnswer):
            raise KeympsError(
                f"planner backend {self.backend_name!r} returned {type(answer).__name__}, "
                "not a BackendAnswer"
            )
        return answer, False

    def _record(
        self, request: PlanRequest, answer: BackendAnswer, problems: list[str], cached: bool
    ) -> None:
        from keymps.vlm_cache import append_to_cassette, request_digest

        index = len(self.calls) + 1
        request_record = {
            "backend": self.backend_name,
            "model": request.model,
            "step": request.step,
            "attempt": request.attempt,
            "temperature": request.temperature,
            "messages": _without_image(request.messages, self.image_url, "crop.png"),
            "response_format": {"type": "json_schema", "json_schema": request.schema},
        }
        request_record = redact(request_record, self.secrets)
        answer_text = redact(answer.text, self.secrets)
        error = "; ".join(problems) if problems else None
        call = VlmCall(
            attempt=request.attempt,
            request=request_record,
            answer_text=answer_text,
            error=redact(error, self.secrets) if error else None,
            latency_s=answer.latency_s,
            prompt_tokens=answer.prompt_tokens,
            completion_tokens=answer.completion_tokens,
            cost_usd=answer.cost_usd,
            cached=cached,
        )
        self.calls.append(call)
        self.vlm_folder.mkdir(parents=True, exist_ok=True)
        record = {
            "request": request_record,
            "answer": answer_text,
            "errors": [redact(p, self.secrets) for p in problems],
            "valid": not problems,
            "cached": cached,
            "latency_s": answer.latency_s,
            "prompt_tokens": answer.prompt_tokens,
            "completion_tokens": answer.completion_tokens,
            "cost_usd": answer.cost_usd,
        }
        path = self.vlm_folder / f"{index:02d}-{request.step}-attempt{request.attempt}.json"
        path.write_text(json.dumps(record, indent=2), encoding="utf-8")
        if self.run.options.record is not None and answer.text:
            append_to_cassette(
                Path(self.run.options.record),
                {
                    "digest": request_digest(request.messages, request.schema),
                    "step": request.step,
                    "attempt": request.attempt,
                    "backend": self.backend_name,
                    "model": answer.model or request.model,
                    "answer": answer_text,
                    "prompt_tokens": answer.prompt_tokens,
                    "completion_tokens": answer.completion_tokens,
                },
            )


def make_plan(
    task: Task,
    detection: Detection,
    scene: SceneImage,
    primitives: Mapping[str, str],
    run: Run,
    backend: str,
) -> Plan:
    """Ask `backend` for the keyword and keypoint pairs; validated, repaired, recorded."""
    from keymps.plan_prompt import find_prompt, png_data_url, prompt_family
    from keymps.plugins import create_component

    if not primitives:
        raise KeympsError("primitives: the task lists no primitives to choose from")
    planner = task.planner
    backend_object = create_component("vlm_backend", backend, backend_options(task))
    prompt_path = find_prompt(
        task.resolve(planner.prompt) if planner.prompt else None,
        task.folder,
        prompt_family(primitives),
    )
    image_url = png_data_url(detection.crop)
    base = PlanRequest(
        instruction=task.instruction,
        crop=detection.crop,
        crop_mask=crop_mask(detection, scene),
        metres_per_px=crop_metres_per_px(task, detection, scene),
        primitives=dict(primitives),
        object_height=task.scene.object_height,
        max_pairs=planner.max_pairs,
        messages=[],
        schema={},
        model=planner.model if backend != "offline" else None,
        temperature=planner.temperature,
        timeout_s=planner.timeout_s,
        task_name=task.name,
    )
    session = _Session(
        task=task,
        run=run,
        backend_name=backend,
        backend=backend_object,
        base=base,
        system_template=prompt_path.read_text(encoding="utf-8"),
        template_source=str(prompt_path),
        image_url=image_url,
    )
    session.vlm_folder.mkdir(parents=True, exist_ok=True)
    _write_crop(session.vlm_folder / "crop.png", detection.crop)
    if planner.combined:
        combined = session.ask("combined")
        keyword, pairs, rationale = combined.keyword, combined.pairs, combined.rationale
    else:
        chosen = session.ask("keyword")
        placed = session.ask("pairs", keyword=chosen.keyword)
        keyword, pairs = chosen.keyword, placed.pairs
        rationale = " ".join(r for r in (chosen.rationale, placed.rationale) if r)
    pairs_crop = np.asarray(pairs, dtype=float).reshape(-1, 2, 2)
    pairs_px = pairs_crop + np.asarray(detection.crop_origin_px, dtype=float)
    run.notes["prompt"] = str(prompt_path)
    return Plan(
        keyword=keyword,
        pairs_crop_px=pairs_crop,
        pairs_px=pairs_px,
        backend=backend,
        model=base.model,
        rationale=rationale,
        calls=tuple(session.calls),
    )


def _write_crop(path: Path, crop: np.ndarray) -> None:
    import cv2

    cv2.imwrite(str(path), crop)


__all__ = [
    "BackendAnswer",
    "PlanRequest",
    "PlannerBackend",
    "backend_options",
    "choose_backend",
    "make_plan",
    "parse_and_validate",
]
