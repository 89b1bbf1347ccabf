"""A real local VLM server for tests: OpenAI-compatible and Ollama-style endpoints on 127.0.0.1.

Answers are scripted: queue them with `server.script(...)`; when the queue is empty the default
responder answers. Every request is recorded (path, headers, JSON body; None for a GET) for
assertions.

    with VlmServer() as server:
        server.script(Reply.text("not json"), Reply.text('{"keyword": ...}'))
        litellm.completion(model="openai/test-vlm", api_base=server.openai_base, ...)
        server.requests[0].body["messages"]
"""

from __future__ import annotations

import contextlib
import json
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any


@dataclass(frozen=True)
class Reply:
    """One scripted reply: a model answer, an HTTP error, a slow answer, or a cut connection."""

    kind: str
    text: str = ""
    status: int = 200
    headers: dict[str, str] = field(default_factory=dict)
    delay_s: float = 0.0
    finish_reason: str = "stop"
    message: dict[str, Any] = field(default_factory=dict)
    """Fields of the answer's message beside its content (refusal, tool_calls ...)."""
    body: bytes = b""

    @staticmethod
    def text_answer(text: str, delay_s: float = 0.0) -> Reply:
        return Reply("answer", text=text, delay_s=delay_s)

    @staticmethod
    def json_answer(data: Any, delay_s: float = 0.0) -> Reply:
        return Reply("answer", text=json.dumps(data), delay_s=delay_s)

    @staticmethod
    def ended(text: str | None, finish_reason: str, **message: Any) -> Reply:
        """An answer that ended as `finish_reason` says ("length" for Ollama's done_reason too),
        its message carrying `message` beside `text` (None: "content": null)."""
        if text is None:
            message = {"content": None, **message}
        return Reply("answer", text=text or "", finish_reason=finish_reason, message=message)

    @staticmethod
    def raw(body: bytes, headers: dict[str, str] | None = None) -> Reply:
        """These bytes as the whole body of a 200 answer, with these headers (Content-Encoding
        ...): a compressed answer, a huge one, a bomb."""
        return Reply("raw", headers=headers or {}, body=body)

    @staticmethod
    def redirect(status: int, to_path: str) -> Reply:
        """A redirect (301, 302, 307 ...) to this path on the same server, or to this URL."""
        return Reply("redirect", status=status, text=to_path)

    @staticmethod
    def bad_chunks() -> Reply:
        """A chunked answer whose second chunk header is not a number."""
        return Reply("bad_chunks")

    @staticmethod
    def error(status: int, retry_after: float | None = None, message: str = "") -> Reply:
        headers = {"Retry-After": f"{retry_after:g}"} if retry_after is not None else {}
        return Reply("error", status=status, headers=headers, text=message or f"error {status}")

    @staticmethod
    def truncated() -> Reply:
        return Reply("truncated")

    @staticmethod
    def reset() -> Reply:
        """Read the request, then reset the connection (TCP RST) without a byte of answer."""
        return Reply("reset")

    @staticmethod
    def broken_json(status: int = 200) -> Reply:
        """A complete HTTP response whose JSON body is cut in the middle."""
        return Reply("broken_json", status=status)

    @staticmethod
    def trickle(interval_s: float = 1.0) -> Reply:
        """Headers at once, then the answer one byte every `interval_s` (each read is quick,
        the whole answer takes minutes: a per-read timeout never fires)."""
        return Reply("trickle", text='{"keyword": "line", "pairs": []}', delay_s=interval_s)

    @staticmethod
    def not_http() -> Reply:
        """Bytes that are not an HTTP response at all, then the connection closes."""
        return Reply("not_http")


@dataclass(frozen=True)
class Recorded:
    path: str
    headers: dict[str, str]
    body: Any
    at: float = field(default_factory=time.monotonic)
    """When the request arrived (time.monotonic)."""
    method: str = "POST"


Responder = Callable[[Recorded], str]


def _openai_completion(
    text: str | None, model: str, finish_reason: str = "stop", message: dict[str, Any] | None = None
) -> dict[str, Any]:
    return {
        "id": "chatcmpl-test",
        "object": "chat.completion",
        "created": int(time.time()),
        "model": model,
        "choices": [
            {
                "index": 0,
                "message": {"role": "assistant", "content": text, **(message or {})},
                "finish_reason": finish_reason,
            }
        ],
        "usage": {"prompt_tokens": 321, "completion_tokens": 45, "total_tokens": 366},
    }


def _ollama_completion(
    text: str, model: str, chat: bool, done_reason: str = "stop"
) -> dict[str, Any]:
    reply: dict[str, Any] = {
        "model": model,
        "created_at": "2026-01-01T00:00:00Z",
        "done": True,
        "done_reason": done_reason,
        "prompt_eval_count": 321,
        "eval_count": 45,
    }
    if chat:
        reply["message"] = {"role": "assistant", "content": text}
    else:
        reply["response"] = text
    return reply


class VlmServer:
    """Serves on 127.0.0.1 at an ephemeral port (or the one given), in a background thread."""

    def __init__(self, responder: Responder | None = None, port: int = 0):
        """`port`: 0 for a free one; another is taken as it is (OSError when in use)."""
        self.responder = responder or (lambda request: '{"keyword": "x", "pairs": []}')
        self.requests: list[Recorded] = []
        self._queue: list[Reply] = []
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._server = _HttpServer(self, port)
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)

    @property
    def port(self) -> int:
        return int(self._server.server_address[1])

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def openai_base(self) -> str:
        return f"{self.url}/v1"

    def script(self, *replies: Reply) -> None:
        with self._lock:
            self._queue.extend(replies)

    def reset(self) -> None:
        with self._lock:
            self._queue.clear()
            self.requests.clear()

    @property
    def chat_requests(self) -> list[Recorded]:
        return [
            r
            for r in self.requests
            if r.method == "POST"
            and r.path.endswith(("/chat/completions", "/api/chat", "/api/generate"))
        ]

    def __enter__(self) -> VlmServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._closing.set()
        self._server.shutdown()
        self._server.server_close()

    def _record(self, request: Recorded) -> None:
        with self._lock:
            self.requests.append(request)

    def _reply_to(self, request: Recorded) -> Reply:
        """The next scripted reply, or else the responder's answer to this request."""
        with self._lock:
            scripted = self._queue.pop(0) if self._queue else None
        return scripted or Reply.text_answer(self.responder(request))


class _HttpServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, owner: VlmServer, port: int):
        self.owner = owner
        super().__init__(("127.0.0.1", port), _Handler)


class _Handler(BaseHTTPRequestHandler):
    """One connection: records each request, then answers as the next Reply says (a method
    per kind of reply)."""

    server: _HttpServer
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True  # else each answer waits 40 ms for a delayed ACK

    def log_message(self, format: str, *args: Any) -> None:
        return None

    def do_GET(self) -> None:
        headers = {k.lower(): v for k, v in self.headers.items()}
        self.server.owner._record(Recorded(self.path, headers, None, method="GET"))
        if self.path.rstrip("/").endswith(("/models", "/api/tags")):
            self._send_json(200, {"object": "list", "data": [], "models": []})
        else:
            self._send_json(404, {"error": {"message": "not found"}})

    def do_POST(self) -> None:
        # the client may give up first (a timeout test): nothing left to answer
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            self._answer_post()

    def _answer_post(self) -> None:
        body = self._read_json()
        record = Recorded(self.path, {k.lower(): v for k, v in self.headers.items()}, body)
        self.server.owner._record(record)
        if self.path.endswith("/api/show"):  # Ollama's model description
            self._send_json(200, {"model_info": {}, "details": {}, "template": ""})
            return
        reply = self.server.owner._reply_to(record)
        if reply.kind != "trickle":  # a trickle's delay_s is its pause between bytes
            time.sleep(reply.delay_s)
        replies: dict[str, Callable[[Reply, str], None]] = {
            "answer": self._reply_answer,
            "error": self._reply_error,
            "redirect": self._reply_redirect,
            "raw": self._reply_raw,
            "trickle": self._reply_trickle,
            "bad_chunks": self._reply_bad_chunks,
            "truncated": self._reply_truncated,
            "broken_json": self._reply_broken_json,
            "not_http": self._reply_not_http,
            "reset": self._reply_reset,
        }
        replies[reply.kind](reply, str(body.get("model", "test")))

    def _read_json(self) -> Any:
        """The request's JSON body ({} when empty; {"_raw": text} when it is no JSON)."""
        length = int(self.headers.get("Content-Length", "0"))
        raw = self.rfile.read(length) if length else b""
        try:
            return json.loads(raw or b"{}")
        except json.JSONDecodeError:
            return {"_raw": raw.decode("utf-8", "replace")}

    def _reply_answer(self, reply: Reply, model: str) -> None:
        """The model's answer in the endpoint's own format (Ollama chat or generate, OpenAI)."""
        ended = reply.finish_reason
        if self.path.endswith("/api/chat"):
            self._send_json(200, _ollama_completion(reply.text, model, True, ended))
        elif self.path.endswith("/api/generate"):
            self._send_json(200, _ollama_completion(reply.text, model, False, ended))
        else:
            self._send_json(200, _openai_completion(reply.text, model, ended, reply.message))

    def _reply_error(self, reply: Reply, model: str) -> None:
        error = {"message": reply.text, "type": "server_error", "code": reply.status}
        self._send_json(reply.status, {"error": error}, reply.headers)

    def _reply_redirect(self, reply: Reply, model: str) -> None:
        self.send_response(reply.status)
        elsewhere = reply.text.startswith(("http://", "https://"))
        self.send_header("Location", ("" if elsewhere else self.server.owner.url) + reply.text)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def _reply_raw(self, reply: Reply, model: str) -> None:
        self.send_response(200)
        if "Content-Type" not in reply.headers:
            self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(reply.body)))
        for key, value in reply.headers.items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(reply.body)

    def _reply_trickle(self, reply: Reply, model: str) -> None:
        """Headers at once, then one byte of the answer every reply.delay_s until it is sent or
        the server closes."""
        payload = json.dumps(_openai_completion(reply.text, model)).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(payload)))
        self.end_headers()
        self.wfile.flush()
        for index in range(len(payload)):
            if self.server.owner._closing.wait(reply.delay_s):
                break
            self.wfile.write(payload[index : index + 1])
            self.wfile.flush()
        self.close_connection = True

    def _reply_bad_chunks(self, reply: Reply, model: str) -> None:
        """A chunked answer whose second chunk header is not a number."""
        self._cut_short({"Transfer-Encoding": "chunked"}, b'5\r\n{"cho\r\nZZZ\r\n')

    def _reply_truncated(self, reply: Reply, model: str) -> None:
        """4096 bytes announced, 42 sent."""
        self._cut_short({"Content-Length": "4096"}, b'{"id": "chatcmpl-test", "choices": [{"mess')

    def _reply_broken_json(self, reply: Reply, model: str) -> None:
        payload = b'{"id": "chatcmpl-test", "choices": [{"message": {"content": "{\\"ke'
        self.send_response(reply.status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(payload)))
        self.end_headers()
        self.wfile.write(payload)

    def _reply_not_http(self, reply: Reply, model: str) -> None:
        self.wfile.write(b"\x00\x01garbage, not HTTP\r\n\r\n")
        self.wfile.flush()
        self.close_connection = True

    def _reply_reset(self, reply: Reply, model: str) -> None:
        linger = struct.pack("ii", 1, 0)  # close with RST, not FIN
        self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, linger)
        self.close_connection = True

    def _send_json(self, status: int, data: Any, headers: dict[str, str] | None = None) -> None:
        payload = json.dumps(data).encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(payload)))
        for key, value in (headers or {}).items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(payload)

    def _cut_short(self, headers: dict[str, str], start: bytes) -> None:
        """A 200 with these headers and the first bytes of a body, then the close."""
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        for key, value in headers.items():
            self.send_header(key, value)
        self.end_headers()
        self.wfile.write(start)
        self.wfile.flush()
        self.close_connection = True
