"""litellm's first completion in a process, set up before the first request.

That first completion sets up more than its request (about a second: litellm's proxy types,
the provider configurations its cost calculation reads, the OpenAI client's response types,
the HTTP transport). `warm_up` does it along the litellm backend's own path, with one
completion answered by an in-memory transport and one to a closed local port: nothing leaves
the machine, no key is used (the placeholder is sent to 127.0.0.1:9, where nothing listens).
"""

from __future__ import annotations

import contextlib
import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from keymps.default_plugins.litellm.backend import LitellmBackend
    from keymps.types import PlanRequest

WARM_UP_MODEL = "openai/keymps-warm-up"
WARM_UP_API_BASE = "http://127.0.0.1:9/v1"
"""The warm-up's model and address: a closed local port (the discard service's), no key."""


def _in_memory_client() -> Any:
    """An OpenAI client whose transport answers every request itself, in memory."""
    import openai

    # the HTTP library the OpenAI SDK is built on (httpx, or its fork httpx2 in newer SDKs)
    client_class = next(c for c in openai.DefaultHttpxClient.__mro__ if c.__name__ == "Client")
    http: Any = importlib.import_module(client_class.__module__.split(".")[0])

    def answer(request: Any) -> Any:
        return http.Response(
            200,
            json={
                "id": "keymps-warm-up",
                "object": "chat.completion",
                "created": 0,
                "model": WARM_UP_MODEL,
                "choices": [
                    {
                        "index": 0,
                        "message": {"role": "assistant", "content": "{}"},
                        "finish_reason": "stop",
                    }
                ],
                "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2},
            },
        )

    return openai.OpenAI(
        api_key="no-key-needed",
        base_url=WARM_UP_API_BASE,
        http_client=openai.DefaultHttpxClient(transport=http.MockTransport(answer)),
        max_retries=0,
    )


def _warm_up_request() -> PlanRequest:
    import numpy as np

    from keymps.types import PlanRequest

    tiny_png = "data:image/png;base64,iVBORw0KGgo="
    return PlanRequest(
        instruction="warm-up",
        crop=np.zeros((1, 1, 3), np.uint8),
        crop_mask=None,
        metres_per_px=(0.001, 0.001),
        primitives={"line": "warm-up"},
        object_height=0.0,
        max_pairs=1,
        messages=[
            {"role": "system", "content": "warm-up"},
            {
                "role": "user",
                "content": [
                    {"type": "text", "text": "warm-up"},
                    {"type": "image_url", "image_url": {"url": tiny_png}},
                ],
            },
        ],
        schema={"name": "warm_up", "strict": True, "schema": {"type": "object"}},
        model=WARM_UP_MODEL,
    )


def warm_up(litellm: Any, warm: LitellmBackend) -> None:
    """Set up litellm's first completion in this process, through `warm`, a litellm backend for
    WARM_UP_MODEL at WARM_UP_API_BASE (failures are ignored: the first real call then does what
    is left)."""
    with contextlib.suppress(Exception):
        call = warm.prepare_call(_warm_up_request())
        response = litellm.completion(**call.arguments, client=_in_memory_client())
        warm.answer_from_response(call, response, 0.0, [])
        with contextlib.suppress(Exception):  # litellm's own client, refused by the closed port
            litellm.completion(**call.arguments)
