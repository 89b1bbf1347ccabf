"""One planning session: ask the backend, validate, repair, record every attempt, use the cache."""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from keymps.errors import KeympsError
from keymps.planning.answer import Step, answer_schema
from keymps.planning.redaction import redact
from keymps.run_files import write_atomically
from keymps.types import AnswerMode, BackendAnswer, PlanRequest, VlmCall

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.plugin.components import VlmBackend
    from keymps.run import Run


def image_reference(image_url: str, image_file: str) -> str:
    """What the records hold instead of the image: its digest and the file it is kept in."""
    return f"sha256:{hashlib.sha256(image_url.encode()).hexdigest()} (file: {image_file})"


def _without_image(value: Any, image_url: str, reference: str) -> Any:
    """`value` with every string equal to the image's data URL replaced by `reference`."""
    if isinstance(value, dict):
        return {k: _without_image(v, image_url, reference) for k, v in value.items()}
    if isinstance(value, list):
        return [_without_image(v, image_url, reference) for v in value]
    return reference if isinstance(value, str) and value == image_url else value


@dataclass
class PlanSession:
    """One plan stage's conversation with a backend: requests, repairs, cache and records."""

    task: Task
    run: Run
    backend_name: str
    backend: VlmBackend
    base: PlanRequest
    system_template: str
    template_source: str
    image_url: str
    calls: list[VlmCall] = field(default_factory=list)
    convention: str = "pixels"
    """How the model writes points (keymps.planning.coordinates)."""
    answer_mode: AnswerMode = "pairs"
    """pairs, design or either (planner.answer)."""
    family: str = "cutting"
    """The prompt's family: which examples and named designs it shows."""

    def __post_init__(self) -> None:
        from keymps.plugin.components import BackendAbilities

        planner = self.task.planner
        self.abilities = BackendAbilities.of(self.backend)
        self.use_cache = (
            self.abilities.cacheable and planner.cache and not self.run.options.no_cache
        )
        self.vlm_folder = self.run.folder / "vlm"
        self.image_reference = image_reference(self.image_url, "crop.png")

    def request_for(
        self, step: Step, keyword: str | None, history: list[tuple[str, list[str]]]
    ) -> PlanRequest:
        from keymps.planning.objects import describe_objects
        from keymps.planning.prompt import build_messages, render_template, template_values

        values = template_values(
            instruction=self.base.instruction,
            primitives=self.base.primitives,
            crop_size_px=self.base.crop_size_px,
            metres_per_px=self.base.metres_per_px,
            object_height=self.base.object_height,
            max_pairs=self.base.max_pairs,
            step=step,
            convention=self.convention,
            answer=self.answer_mode,
            family=self.family,
        )
        system_text = render_template(self.system_template, values, self.template_source)
        messages = build_messages(
            system_text,
            self.base.instruction,
            self.image_url,
            self.base.crop_size_px,
            keyword,
            history,
            objects=describe_objects(self.base.objects),
        )
        schema = answer_schema(
            step,
            list(self.base.primitives),
            self.base.max_pairs,
            self.answer_mode,
            self.convention,
            self.family,
        )
        return replace(
            self.base,
            messages=messages,
            schema=schema,
            step=step,
            keyword=keyword,
            answer_mode=self.answer_mode,
            previous_errors=tuple(history[-1][1]) if history else (),
            attempt=len(history) + 1,
            share_key=self._cache_key(messages, schema) if self.use_cache else None,
        )

    def ask_own_prompt(
        self,
        label: str,
        user_text: str,
        with_image: bool,
        schema: dict[str, Any],
        validate: Callable[[Any], tuple[Any, list[str]]],
    ) -> Any:
        """The validated answer to a caller's own prompt (`keymps eval`'s direct methods):
        `system_template` (already filled), `user_text` with the crop when `with_image`, the
        plan stage's repair messages; `validate(data)` checks the answer's JSON object and
        returns (parsed or None, problems). Cache, cassette and records as for the plan steps."""
        from keymps.planning.answer import extract_json
        from keymps.planning.prompt import conversation

        image_url = self.image_url if with_image else None

        def request_for(history: list[tuple[str, list[str]]]) -> PlanRequest:
            messages = conversation(self.system_template, user_text, image_url, history)
            share_key = self._cache_key(messages, schema) if self.use_cache else None
            attempt = len(history) + 1
            return replace(
                self.base, messages=messages, schema=schema, attempt=attempt, share_key=share_key
            )

        def parse(text: str) -> tuple[Any, list[str]]:
            try:
                return validate(extract_json(text))
            except ValueError as error:
                return None, [f"the answer is not a JSON object ({error})"]

        return self.ask_until_valid(label, request_for, parse)

    def ask(
        self,
        step: Step,
        keyword: str | None = None,
        earlier: Sequence[tuple[str, list[str]]] = (),
    ) -> Any:
        """The validated answer to one planning step (keyword, pairs or combined); `earlier`:
        answers already given and their problems (an outcome repair), shown to the model."""
        from keymps.planning.answer import parse_and_validate

        def validate(text: str) -> tuple[Any, list[str]]:
            parsed, problems = parse_and_validate(
                text,
                step,
                list(self.base.primitives),
                self.base.crop_size_px,
                self.base.max_pairs,
                self.answer_mode,
                self.convention,
                self.family,
            )
            return _on_one_object_each(parsed, problems, self.base, self.convention)

        return self.ask_until_valid(
            label=f"{step} answer",
            request_for=lambda history: self.request_for(step, keyword, history),
            validate=validate,
            earlier=earlier,
        )

    def ask_until_valid(
        self,
        label: str,
        request_for: Callable[[list[tuple[str, list[str]]]], PlanRequest],
        validate: Callable[[str], tuple[Any, list[str]]],
        earlier: Sequence[tuple[str, list[str]]] = (),
    ) -> Any:
        """Ask, validate and repair up to planner.attempts times, every attempt recorded.

        `request_for(history)` builds the next request from the earlier (answer, problems),
        `earlier` first; `validate(text)` returns (parsed or None, problems). Cache, cassette and
        redaction apply to every caller alike (the planner's steps and eval's direct methods).
        """
        history: list[tuple[str, list[str]]] = list(earlier)
        attempts = self.task.planner.attempts
        for _ in range(attempts):
            request = request_for(history)
            answer, cached = self._complete(request)
            parsed, problems = validate(answer.text)
            if parsed is None:  # what the model said about its answer comes first
                problems = [*ended_early(answer, self.task.planner.max_tokens), *problems]
            self._record(request, answer, problems, cached)
            if parsed is not None:
                if request.share_key is not None and not cached:
                    self._cache_put(request.share_key, answer)
                return parsed
            history.append((answer.text, problems))
        last = "; ".join(history[-1][1][:4])
        raise KeympsError(
            f"the {self.backend_name} planner gave no valid {label} in {attempts} "
            f"attempt(s): {last} (every attempt is in {self.vlm_folder})"
        )

    def _cache_key(self, messages: list[dict[str, Any]], schema: dict[str, Any]) -> str:
        """The answer cache's key, also the request's share key (keymps.eval.broker)."""
        from keymps.planning.cache import request_digest

        # the server is part of the key: two servers may serve different weights under one name
        where = f"{self.base.model or self.backend_name}@{self.task.planner.api_base or ''}"
        return request_digest(messages, schema, where)

    def _cache_put(self, key: str, answer: Any) -> None:
        from keymps.planning.cache import AnswerCache

        AnswerCache().put(
            key,
            {
                "text": redact(answer.text),
                "prompt_tokens": answer.prompt_tokens,
                "completion_tokens": answer.completion_tokens,
                "cost_usd": answer.cost_usd,
                "model": answer.model,
            },
        )

    def _complete(self, request: PlanRequest) -> tuple[BackendAnswer, bool]:
        if request.share_key is not None:
            from keymps.planning.cache import AnswerCache

            hit = AnswerCache().get(request.share_key)
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
        dispatch = self.run.options.dispatch
        try:
            if dispatch is not None and self.abilities.supports_async:
                answer = dispatch(self.backend, request)
            else:
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
        return answer, answer.shared

    def _record(
        self, request: PlanRequest, answer: BackendAnswer, problems: list[str], cached: bool
    ) -> None:
        from keymps.planning.cache import append_to_cassette, request_digest

        index = len(self.calls) + 1
        request_record = {
            "backend": self.backend_name,
            "model": request.model,
            "step": request.step,
            "attempt": request.attempt,
            "temperature": request.temperature,
            "messages": _without_image(request.messages, self.image_url, self.image_reference),
            "response_format": {"type": "json_schema", "json_schema": request.schema},
        }
        request_record = redact(request_record)
        answer_text = redact(answer.text)
        error = "; ".join(problems) if problems else None
        call = VlmCall(
            attempt=request.attempt,
            request=request_record,
            answer_text=answer_text,
            error=redact(error) if error else None,
            latency_s=answer.latency_s,
            prompt_tokens=answer.prompt_tokens,
            completion_tokens=answer.completion_tokens,
            cost_usd=answer.cost_usd,
            cached=cached,
            model_call=self.abilities.asks_model,
        )
        self.calls.append(call)
        self.vlm_folder.mkdir(parents=True, exist_ok=True)
        record = {
            "request": request_record,
            "answer": answer_text,
            "errors": redact(problems),
            "valid": not problems,
            "cached": cached,
            "latency_s": answer.latency_s,
            "prompt_tokens": answer.prompt_tokens,
            "completion_tokens": answer.completion_tokens,
            "cost_usd": answer.cost_usd,
            "retries": redact(list(answer.retries)),
        }
        path = self.vlm_folder / f"{index:02d}-{request.step}-attempt{request.attempt}.json"
        write_atomically(path, json.dumps(record, indent=2))
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


def _on_one_object_each(
    parsed: Any, problems: list[str], base: PlanRequest, convention: Any
) -> tuple[Any, list[str]]:
    """A valid answer whose pairs each lie on one object (several objects); a pair spanning two
    is a problem sent back for repair like any other."""
    import numpy as np

    from keymps.planning.coordinates import to_pixels
    from keymps.planning.objects import assign_pairs

    pairs = getattr(parsed, "pairs", None)
    if parsed is None or pairs is None or len(base.objects) < 2:
        return parsed, problems
    answered = np.asarray(pairs, dtype=float).reshape(-1, 2, 2)
    try:
        assign_pairs(to_pixels(answered, convention, base.crop_size_px), base.objects)
    except KeympsError as error:
        return None, [str(error)]
    return parsed, problems


def ended_early(answer: BackendAnswer, max_tokens: int | None) -> list[str]:
    """Why an answer that is no valid plan ended where it did, when the backend says: the first
    problem named, to the user and in the repair request (else it reads as "no JSON object")."""
    if answer.refusal:
        return [f"the model refused: {answer.refusal!r}"]
    if answer.finish_reason == "length":
        limit = f"now {max_tokens}" if max_tokens else "unset: the server's own limit"
        return [
            "the answer stopped at the model's output token limit (finish_reason 'length') "
            f"before it was complete: raise planner.max_tokens ({limit})"
        ]
    if answer.finish_reason == "content_filter":
        return ["the provider's content filter stopped the answer (finish_reason 'content_filter')"]
    if answer.finish_reason == "tool_calls":
        return ["the model called a tool instead of answering in text (keymps offers no tools)"]
    return []
