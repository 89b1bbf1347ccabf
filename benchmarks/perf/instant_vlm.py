"""A VLM stand-in for the benchmarks: an OpenAI-compatible server on 127.0.0.1 in its own process.

It answers every chat completion at once, or after a latency that can be changed while it runs,
with the text a benchmark's `answer(body)` function makes of the request body. It runs in a
process of its own so that its CPU and memory stay out of keymps' figures (`InstantVlm.pid`).

    with InstantVlm(answer, latency_s=0.2) as server:
        ... --api-base server.api_base ...

The scripts beside this file import it by name (`python benchmarks/perf/SCRIPT.py` puts this
folder first on sys.path); the server process is started with multiprocessing's "spawn", which
hands it that sys.path, so `answer` must be a module-level function of the script.
"""

from __future__ import annotations

import json
import multiprocessing
import re
import time
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

Answer = Callable[[dict[str, Any]], str]
"""The model's answer (the message content) to one request's JSON body."""

CROP = re.compile(r"(\d+) x (\d+) pixels")


def crop_size(body: dict[str, Any]) -> tuple[int, int]:
    """The (width, height) in pixels of the crop the request shows, as its prompt states it."""
    texts = []
    for message in body.get("messages", []):
        content = message.get("content")
        parts = content if isinstance(content, list) else [{"text": str(content)}]
        texts += [part.get("text", "") for part in parts if isinstance(part, dict)]
    width, height = CROP.findall(json.dumps(texts))[-1]
    return int(width), int(height)


def completion(content: str, model: str) -> dict[str, Any]:
    """An OpenAI chat completion carrying `content`, with fixed token counts."""
    return {
        "id": "instant-vlm",
        "object": "chat.completion",
        "created": int(time.time()),
        "model": model,
        "choices": [
            {
                "index": 0,
                "message": {"role": "assistant", "content": content},
                "finish_reason": "stop",
            }
        ],
        "usage": {"prompt_tokens": 100, "completion_tokens": 50, "total_tokens": 150},
    }


class _Server(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, answer: Answer, latency: Any):
        super().__init__(("127.0.0.1", 0), _Handler)
        self.answer = answer
        self.latency = latency
        """Seconds before each answer: a multiprocessing Value the parent may change."""


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"  # keeps connections open, as VLM servers do
    # Headers and body go out as two writes; with Nagle's algorithm on, the body would wait for
    # the client's delayed ACK (40 ms on Linux). Servers like uvicorn set TCP_NODELAY.
    disable_nagle_algorithm = True

    def log_message(self, format: str, *args: Any) -> None:
        pass

    def do_POST(self) -> None:
        body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
        time.sleep(self.server.latency.value)
        reply = completion(self.server.answer(body), str(body.get("model", "instant-vlm")))
        data = json.dumps(reply).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)


def _serve(answer: Answer, latency: Any, port: Any) -> None:
    """The server process: publishes its port, then answers until it is terminated."""
    server = _Server(answer, latency)
    port.value = server.server_address[1]
    server.serve_forever()


class InstantVlm:
    """The server process; `api_base` is its OpenAI base URL, `pid` its process id (a string,
    as /proc names it)."""

    def __init__(self, answer: Answer, latency_s: float = 0.0):
        """Starts the process and waits until it listens.

        Args:
            answer: makes the answer's text of a request's JSON body; a module-level function
                (the process is spawned: the function is sent by name).
            latency_s: seconds the server waits before each answer.
        """
        context = multiprocessing.get_context("spawn")
        self._latency = context.Value("d", latency_s)
        port = context.Value("i", 0)
        self.process = context.Process(
            target=_serve, args=(answer, self._latency, port), daemon=True
        )
        self.process.start()
        while not port.value:
            if not self.process.is_alive():
                raise SystemExit(f"the VLM stand-in ended at start (exit {self.process.exitcode})")
            time.sleep(0.01)
        self.api_base = f"http://127.0.0.1:{port.value}/v1"
        self.pid = str(self.process.pid)

    def set_latency(self, seconds: float) -> None:
        """Seconds before each later answer."""
        self._latency.value = seconds

    def close(self) -> None:
        self.process.terminate()
        self.process.join(timeout=5)

    def __enter__(self) -> InstantVlm:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()
