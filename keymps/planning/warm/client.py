"""The warm planner's client: status, start, stop, and the requests of the litellm backend.

What crosses the socket for a request: the backend options (model, api_base, api_key_env,
temperature, timeout_s, max_tokens, whether the api_base is trusted with a key), the request
(the rendered messages with the image sent, the schema, the step and attempt), the caller's
working folder and `call_environment`: the variables the call may read, nothing else.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from typing import TYPE_CHECKING, Any

from keymps.errors import KeympsError
from keymps.planning.backend_choice import PROVIDER_KEYS, model_provider
from keymps.planning.warm.place import Place, peer, supported

if TYPE_CHECKING:
    from keymps.types import BackendAnswer, PlanRequest

START_TIMEOUT_S = 120.0
"""How long a run waits for a planner it started (its import of litellm) before planning in its
own process."""
CONNECT_TIMEOUT_S = 5.0
MAX_LOG_BYTES = 1 << 20

SERVER_ENVIRONMENT = (
    "HOME", "PATH", "LANG", "LANGUAGE", "TZ", "TMPDIR", "USER", "LOGNAME", "PYTHONPATH",
    "PYTHONHOME", "VIRTUAL_ENV", "XDG_RUNTIME_DIR", "KEYMPS_CONFIG", "XDG_CONFIG_HOME",
)  # fmt: skip
"""The variables the planner is started with (and the prefixes below): none is a credential.
Keys come with each request, for that request alone."""
SERVER_ENVIRONMENT_PREFIXES = ("LC_", "LITELLM_")
"""The locale, and litellm's settings that its import reads (LITELLM_LOG ...)."""
NETWORK_SETTINGS = (
    "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY", "NO_PROXY", "http_proxy", "https_proxy",
    "all_proxy", "no_proxy", "SSL_CERT_FILE", "SSL_CERT_DIR", "REQUESTS_CA_BUNDLE",
    "CURL_CA_BUNDLE",
)  # fmt: skip
"""Proxies and certificate authorities: where and how the request goes."""
PROVIDER_PREFIXES: dict[str, tuple[str, ...]] = {
    "bedrock": ("AWS_",),
    "sagemaker": ("AWS_",),
    "vertex_ai": ("VERTEXAI_", "VERTEX_", "GOOGLE_"),
    "vertex_ai_beta": ("VERTEXAI_", "VERTEX_", "GOOGLE_"),
    "gemini": ("GEMINI_", "GOOGLE_"),
    "together_ai": ("TOGETHERAI_", "TOGETHER_"),
    "ollama_chat": ("OLLAMA_",),
}
"""The variables litellm reads for a provider, by prefix; others: the provider's name in
capitals and `_` (OPENAI_API_KEY, OPENAI_BASE_URL, ANTHROPIC_API_KEY ...)."""


class PlannerUnavailable(Exception):
    """No warm planner answered: not running, not started, or gone before its answer."""


def call_environment(model: str | None, api_key_env: str | None) -> dict[str, str]:
    """The caller's variables a request of `model` may read, and no others: the variable
    planner.api_key_env names, the provider's key and setting variables, proxies and CAs."""
    provider = model_provider(model or "")
    prefixes = PROVIDER_PREFIXES.get(provider, (f"{provider.upper()}_",))
    names = {*PROVIDER_KEYS.get(provider, ()), *NETWORK_SETTINGS}
    if api_key_env:
        names.add(api_key_env)
    return {k: v for k, v in os.environ.items() if k in names or k.startswith(prefixes)}


def server_environment() -> dict[str, str]:
    """What the planner is started with: harmless variables only."""
    return {
        k: v
        for k, v in os.environ.items()
        if k in SERVER_ENVIRONMENT or k.startswith(SERVER_ENVIRONMENT_PREFIXES)
    }


def answer_deadline_s(options: dict[str, Any]) -> float:
    """How long a request may take in the planner: each try's deadline and the longest waits
    between tries (keymps.default_plugins.litellm.retry), and a margin."""
    retries = options.get("retries")
    tries = (3 if retries is None else int(retries)) + 1
    return tries * (float(options.get("timeout_s") or 60.0) + 31.0) + 10.0


class WarmPlanner:
    """Talks to this user's (and installation's) warm planner."""

    def __init__(self, place: Place | None = None) -> None:
        self.place = place or Place.for_user()

    def connect(self) -> socket.socket:
        """A connection to the planner, checked to run as this user."""
        if not supported() or not self.place.socket.exists():
            raise PlannerUnavailable("is not running")
        connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        connection.settimeout(CONNECT_TIMEOUT_S)
        try:
            connection.connect(str(self.place.socket))
            _pid, uid = peer(connection)
        except OSError as error:
            connection.close()
            raise PlannerUnavailable(f"is not answering ({error.strerror or error})") from None
        if uid != os.getuid():  # (its folder is the user's alone: only a bug gets here)
            connection.close()
            raise PlannerUnavailable(f"runs as user {uid}, not as you: not used")
        return connection

    def ask(self, kind: str) -> dict[str, Any]:
        """The planner's reply to `hello` or `stop`."""
        from keymps.planning.warm.wire import PROTOCOL, WireError, receive, send

        with self.connect() as connection:
            try:
                send(connection, {"kind": kind, "protocol": PROTOCOL})
                return receive(connection)
            except (WireError, OSError) as error:
                raise PlannerUnavailable(f"did not answer ({error})") from None

    def status(self) -> dict[str, Any] | None:
        """Its status (pid, socket, idle timeout, requests), or None when none answers.
        Asking restarts its idle clock."""
        if self.folder_problem():
            return None
        try:
            reply = self.ask("hello")
        except PlannerUnavailable:
            return None
        return reply if reply.get("ok") else None

    def folder_problem(self) -> str | None:
        """Why the planner's folder is not to be used, when it exists and is not safe."""
        from keymps.planning.warm.place import folder_problem

        if not supported() or not os.path.lexists(self.place.folder):
            return None
        return folder_problem(self.place.folder)

    def stop(self) -> bool:
        """Ask the planner to exit; False when none was running."""
        try:
            return bool(self.ask("stop").get("ok"))
        except PlannerUnavailable:
            return False

    def lock_held(self) -> bool:
        """Is a planner running or starting (its lock held)?"""
        import fcntl

        try:
            descriptor = os.open(self.place.lock, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        except OSError:
            return False
        try:
            fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        finally:
            os.close(descriptor)
        return False

    def start(self, idle_timeout_s: float | None = None) -> subprocess.Popen[bytes]:
        """Start a planner in the background (its import then runs on another core); returns at
        once. Raises KeympsError when its folder is not safe to use."""
        self.place.check(create=True)
        command = [sys.executable, "-m", "keymps.planning.warm.server", "--detach"]
        if idle_timeout_s is not None:
            command += ["--idle-timeout", f"{idle_timeout_s:g}"]
        with _log_file(self.place) as log:
            return subprocess.Popen(
                command,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
                env=server_environment(),
                cwd="/",
                start_new_session=True,  # no Ctrl-C or hang-up of the terminal reaches it
            )

    def wait_until_up(
        self, process: subprocess.Popen[bytes] | None, timeout_s: float = START_TIMEOUT_S
    ) -> dict[str, Any]:
        """The status of the planner `process` started (None: another process started it);
        PlannerUnavailable when it died or did not come up in time. (The started process
        exits once the planner holds its lock, which it holds until it exits.)"""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            status = self.status()
            if status is not None:
                return status
            code = process.poll() if process is not None else 0
            if code not in (None, 0) or (code == 0 and not self.lock_held()):
                raise PlannerUnavailable(f"did not start: {self.last_log_line()}")
            time.sleep(0.05)
        raise PlannerUnavailable(f"did not start within {timeout_s:g} s")

    def last_log_line(self) -> str:
        try:
            lines = self.place.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            lines = []
        return lines[-1] if lines else f"no log in {self.place.log}"

    def plan(self, options: dict[str, Any], request: PlanRequest) -> BackendAnswer:
        """The backend's answer to one request, asked by the planner as this process would ask
        it. KeympsError for the backend's errors; PlannerUnavailable when no answer came."""
        from keymps.planning.warm.wire import WireError, receive

        with self.connect() as connection:
            try:
                connection.sendall(_request_bytes(options, request))
                connection.settimeout(answer_deadline_s(options))
                reply = receive(connection)
            except TimeoutError:
                raise _no_answer_in_time(options) from None
            except (WireError, OSError) as error:
                raise PlannerUnavailable(f"gave no answer ({error})") from None
        return _answer_of(reply)

    async def aplan(self, options: dict[str, Any], request: PlanRequest) -> BackendAnswer:
        """plan() on an event loop (`keymps eval`'s broker): waits without a thread."""
        import asyncio

        from keymps.planning.warm.wire import WireError, areceive

        if not supported() or not self.place.socket.exists():
            raise PlannerUnavailable("is not running")
        try:
            reader, writer = await asyncio.wait_for(
                asyncio.open_unix_connection(str(self.place.socket)), CONNECT_TIMEOUT_S
            )
        except (OSError, TimeoutError) as error:
            raise PlannerUnavailable(f"is not answering ({error})") from None
        try:
            _pid, uid = peer(writer.get_extra_info("socket"))
            if uid != os.getuid():
                raise PlannerUnavailable(f"runs as user {uid}, not as you: not used")
            writer.write(_request_bytes(options, request))
            await writer.drain()
            reply = await asyncio.wait_for(areceive(reader), answer_deadline_s(options))
        except TimeoutError:
            raise _no_answer_in_time(options) from None
        except (WireError, OSError) as error:
            raise PlannerUnavailable(f"gave no answer ({error})") from None
        finally:
            writer.close()
        return _answer_of(reply)


def _request_bytes(options: dict[str, Any], request: PlanRequest) -> bytes:
    """A plan request as it crosses: its kind, then its body (read by the child alone)."""
    from keymps.planning.warm.wire import PROTOCOL, encode, request_to_wire

    model = request.model or options.get("model")
    body = {
        "options": options,
        "request": request_to_wire(request),
        "environment": call_environment(model, options.get("api_key_env")),
        "cwd": _working_folder(),
    }
    return encode({"kind": "plan", "protocol": PROTOCOL}) + encode(body)


def _answer_of(reply: dict[str, Any]) -> BackendAnswer:
    """The answer in a reply; its error raised as the backend would have raised it."""
    from keymps.planning.warm.wire import answer_from_wire

    if "answer" in reply:
        return answer_from_wire(reply["answer"])
    if "error" in reply:
        raise KeympsError(str(reply["error"]))
    raise RuntimeError(str(reply.get("failure", "the warm planner's reply has no answer")))


def _no_answer_in_time(options: dict[str, Any]) -> KeympsError:
    return KeympsError(f"the warm planner gave no answer within {answer_deadline_s(options):g} s")


def _working_folder() -> str | None:
    try:
        return os.getcwd()
    except OSError:  # removed under the run
        return None


@contextlib.contextmanager
def _log_file(place: Place) -> Any:
    """The planner's log, opened for its output (the user's alone; cut when over 1 MB)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC
    descriptor = os.open(place.log, flags, 0o600)
    try:
        if os.fstat(descriptor).st_size > MAX_LOG_BYTES:
            os.ftruncate(descriptor, 0)
        yield descriptor
    finally:
        os.close(descriptor)
