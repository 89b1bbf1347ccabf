"""The `replay` planner backend: answers from a cassette recorded with --record.

A cassette is a JSONL file; each line holds a request digest (sha256 of the messages, image
included, and the answer schema), the answer text and its usage. Keys never reach it: requests
are stored only as digests.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict

from keymps.errors import KeympsError
from keymps.plugin import BackendBase, RegisterVlmBackend, hookimpl, parse_options

if TYPE_CHECKING:
    from keymps.types import BackendAnswer, PlanRequest


class ReplayOptions(BaseModel):
    model_config = ConfigDict(defer_build=True, extra="allow")
    cassette: str | None = None


class ReplayBackend(BackendBase):
    name = "replay"

    def __init__(self, cassette: Path):
        from keymps.planning.cache import read_cassette

        self.cassette = cassette
        self.entries = read_cassette(cassette)

    def complete(self, request: PlanRequest) -> BackendAnswer:
        from keymps.planning.cache import request_digest
        from keymps.types import BackendAnswer

        started = time.perf_counter()
        digest = request_digest(request.messages, request.schema)
        entry = self.entries.get(digest)
        if entry is None:
            raise KeympsError(
                f"cassette {self.cassette} has no answer for this request ({request.step} call, "
                f"attempt {request.attempt}, digest {digest[:12]}): the instruction, image, "
                "prompt, primitives or limits differ from the recording; record again with "
                "--record"
            )
        return BackendAnswer(
            text=str(entry["answer"]),
            prompt_tokens=entry.get("prompt_tokens"),
            completion_tokens=entry.get("completion_tokens"),
            latency_s=time.perf_counter() - started,
            cost_usd=0.0,
            model=entry.get("model"),
        )


def _factory(options: dict[str, Any]) -> ReplayBackend:
    parsed = parse_options(ReplayOptions, options, "replay backend")
    if not parsed.cassette:
        raise KeympsError(
            "the replay backend needs a cassette: set planner.cassette or pass --cassette FILE.jsonl"
        )
    return ReplayBackend(Path(parsed.cassette))


@hookimpl
def register_vlm_backends(register: RegisterVlmBackend) -> None:
    register("replay", _factory)
