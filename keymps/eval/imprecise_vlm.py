"""A scripted imprecise VLM for ablations: an OpenAI-compatible server on 127.0.0.1.

It answers what a VLM that understands the sentence but points imprecisely would: the exact
design (the offline grammar's reading, laid out by keymps.designs.place on the very image it is
sent) with every keypoint moved by a random error, and the intent stated correctly. keymps talks
to it over real HTTP through litellm, as to any model (docs/benchmarks.md, the outcome ablation).

The error model (ErrorModel) is an assumption, stated as such: each keypoint coordinate is off by
a normal error of standard deviation `sigma` times the longer side of the image sent. Published
pointing benchmarks (LocateBench, Point-It-Out, pixel-pointing tests of GPT-class models on
synthetic shapes) report that general VLMs land a few percent of the image size from targets
even on clean images; no published number fits our crops, so the ablation reports several
sigmas. A repair request (it carries the problems of the earlier answer) is answered by a new
draw: this model does not learn from the feedback, which makes the ablation's repair gains a
lower bound for a model that does.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import threading
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

MODEL = "openai/imprecise-vlm"
"""The litellm model name to ask it with (any key; it runs on 127.0.0.1)."""


@dataclass(frozen=True)
class ErrorModel:
    """How far a keypoint lands from where the exact design puts it."""

    sigma: float = 0.02
    """Standard deviation of each coordinate's error, as a fraction of the image's longer side
    (0.02: 6 px on a 300 px crop, 3 mm on a 15 cm cake at 0.5 mm per pixel)."""
    overshoot: float = 0.05
    """How far past the object's edge a cut starts and ends, as a fraction of the image's longer
    side (the prompt asks for "just outside its edge"; the image's border limits it)."""
    seed: int = 0


def exact_answer(request: dict[str, Any]) -> tuple[dict[str, Any], np.ndarray, tuple[int, int]]:
    """(the exact answer without pairs, its pairs in pixels of the image sent, that image's
    size) for an OpenAI chat request keymps made."""
    from keymps.designs.grammar import read_instruction
    from keymps.designs.place import place_design
    from keymps.planning.intent import answer_of_intent, intent_of_design

    system, text, image = _parts(request["messages"])
    instruction = re.search(r"Instruction: (.*)", text)
    scale = re.search(r"One pixel is about ([0-9.]+) mm", system)
    if instruction is None or scale is None or image is None:
        raise ValueError("not a keymps planning request")
    design = read_instruction(instruction.group(1))
    metres = float(scale.group(1)) / 1000
    pairs, layout = place_design(design, image, None, (metres, metres), 64)
    schema = request.get("response_format", {}).get("json_schema", {}).get("schema", {})
    keywords = schema.get("properties", {}).get("keyword", {}).get("enum", ["straight"])
    stated = answer_of_intent(intent_of_design(design))
    fields = schema.get("properties", {}).get("intent", {}).get("anyOf", [{}])[0]
    allowed = set(fields.get("properties", stated))
    answer = {
        "keyword": keywords[0],
        "intent": {k: stated.get(k) for k in allowed},
        "rationale": f"imprecise VLM: {layout}",
    }
    size = (int(image.shape[1]), int(image.shape[0]))
    return answer, np.asarray(pairs, float), size


def imprecise_answer(request: dict[str, Any], errors: ErrorModel) -> str:
    """The answer text: the exact design's pairs, each point moved by the model's error."""
    answer, pairs, (width, height) = exact_answer(request)
    if answer.get("intent", {}).get("dots") is None:  # cuts: past the edge, as the prompt asks
        pairs = _past_the_edge(request, pairs, errors.overshoot * max(width, height))
    digest = hashlib.sha256(json.dumps(request["messages"], sort_keys=True).encode()).digest()
    rng = np.random.default_rng([errors.seed, int.from_bytes(digest[:8], "little")])
    moved = pairs + rng.normal(0.0, errors.sigma * max(width, height), pairs.shape)
    moved = np.clip(moved, 0.0, [width, height])
    answer["pairs"] = np.round(moved, 1).tolist()
    return json.dumps(answer)


def _past_the_edge(request: dict[str, Any], pairs: np.ndarray, reach: float) -> np.ndarray:
    """Each cut's ends that lie on the object's edge moved `reach` further out along the cut
    (an end inside the object, a ray's at the centre, stays); all within the image."""
    from keymps.designs.crop_shape import segment_crop

    _, _, image = _parts(request["messages"])
    assert image is not None
    mask = segment_crop(image)
    height, width = image.shape[:2]
    moved = np.array(pairs, dtype=float)
    for pair in moved:
        axis = pair[1] - pair[0]
        length = float(np.linalg.norm(axis))
        if length == 0:
            continue
        axis /= length
        for end, outwards in ((0, -axis), (1, axis)):
            x, y = np.clip(
                np.round(pair[end] - 3 * outwards).astype(int), 0, [width - 1, height - 1]
            )
            if mask is None or not mask[y, x]:  # just inside the end, no food: an edge end
                pair[end] = pair[end] + reach * outwards
    return np.clip(moved, 0.0, [width, height])


def _parts(messages: list[dict[str, Any]]) -> tuple[str, str, np.ndarray | None]:
    """The system text, the first user text and the image it carries (BGR)."""
    import cv2

    system = next((m["content"] for m in messages if m["role"] == "system"), "")
    user = next(m for m in messages if m["role"] == "user")
    text, image = "", None
    for part in user["content"] if isinstance(user["content"], list) else []:
        if part.get("type") == "text":
            text = part["text"]
        elif part.get("type") == "image_url":
            data = base64.b64decode(part["image_url"]["url"].split(",", 1)[1])
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return system, text, image


class ImpreciseVlm:
    """The server, in a thread of this process: `with ImpreciseVlm(ErrorModel(0.02)) as vlm:`
    then ask `MODEL` at `vlm.api_base`."""

    def __init__(self, errors: ErrorModel):
        self.errors = errors
        self.requests = 0
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 (the http.server API)
                length = int(self.headers.get("Content-Length", "0"))
                request = json.loads(self.rfile.read(length))
                outer.requests += 1
                try:
                    body, status = _completion(imprecise_answer(request, outer.errors)), 200
                except (ValueError, KeyError) as error:
                    body, status = {"error": {"message": str(error)}}, 400
                data = json.dumps(body).encode()
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    @property
    def api_base(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}/v1"

    def __enter__(self) -> ImpreciseVlm:
        self.thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.server.shutdown()
        self.server.server_close()


def _completion(text: str) -> dict[str, Any]:
    return {
        "id": "chatcmpl-imprecise",
        "object": "chat.completion",
        "model": MODEL.split("/", 1)[1],
        "choices": [
            {
                "index": 0,
                "message": {"role": "assistant", "content": text},
                "finish_reason": "stop",
            }
        ],
        "usage": {"prompt_tokens": 0, "completion_tokens": 0, "total_tokens": 0},
    }
