"""The warm planner's process: `python -m keymps.planning.warm.server [--idle-timeout S]`.

It takes its lock (one planner per user and installation: a second one leaves at once),
imports the litellm backend once, with no key in its environment (`keymps.planning.warm.client`
starts it with a short list of harmless variables), listens on its Unix socket and, for each
connection:

- refuses it unless the kernel says the peer runs as the same user (SO_PEERCRED);
- answers `hello` (its status; it also restarts the idle clock) and `stop` itself;
- for `plan`, forks a child that alone reads the request's body: the caller's key variables,
  its working folder, the backend options, the request. The child sets exactly that
  environment, asks the backend as a run in the caller's process would, sends the answer
  and exits. Nothing of a request stays in this process, so no request can use the key of
  another, and a client killed mid-request ends only its own child.

It exits after `idle_timeout_s` without a connection or a request running (default 10 min), on
`stop`, or on SIGTERM; the children of requests still running finish them on their own.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import os
import select
import signal
import socket
import sys
import threading
import time
from typing import Any

from keymps.errors import KeympsError
from keymps.planning.backend_choice import AUTO_VLM
from keymps.planning.warm.place import Place, peer
from keymps.planning.warm.wire import (
    PROTOCOL,
    WireError,
    answer_to_wire,
    receive,
    request_from_wire,
    send,
)

IDLE_TIMEOUT_S = 600.0
"""The planner exits after this long without a connection and with no request running."""
BACKEND = AUTO_VLM
"""The one backend it serves: litellm, whose import is what a warm process saves."""
MAX_CHILDREN = 32
"""Requests answered at once; further connections wait in the socket's queue."""
HEAD_TIMEOUT_S = 5.0
"""A connection says what it wants within this time, or it is closed."""
BODY_TIMEOUT_S = 30.0


def log(message: str) -> None:
    """One line of the planner's log (its stderr: the log file when started in the background).
    It names events, never a request's content."""
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} [{os.getpid()}] {message}", file=sys.stderr)
    sys.stderr.flush()


def take_lock(place: Place) -> int | None:
    """The lock file's descriptor, held for the planner's life; None when another holds it."""
    descriptor = os.open(place.lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(descriptor)
        return None
    return descriptor


class Server:
    """The listening process: its socket, its children, its idle clock."""

    def __init__(self, place: Place, idle_timeout_s: float, lock: int) -> None:
        self.place = place
        self.idle_timeout_s = idle_timeout_s
        self.lock = lock
        self.children: set[int] = set()
        self.served = 0
        self.started = time.time()
        self.last_seen = time.monotonic()
        self.stopping = False
        self.base: dict[str, str] = dict(os.environ)
        self.loaded: dict[str, str] = {}
        self.listener: socket.socket | None = None
        self.inode: int | None = None

    def prepare(self) -> None:
        """Import the backend now. What the import put into the environment (litellm reads a
        .env file beside its installation) is kept apart and given to each request that does
        not set it itself, as a run's own import of litellm would; this process keeps the
        environment it was started with."""
        from keymps.plugin.components import prepare_backend
        from keymps.plugin.manager import create_vlm_backend

        before = dict(os.environ)
        prepare_backend(create_vlm_backend(BACKEND, {}))
        self.loaded = {k: v for k, v in os.environ.items() if before.get(k) != v}
        os.environ.clear()
        os.environ.update(before)

    def listen(self) -> None:
        path = self.place.socket
        # the lock is ours: a socket file left there is a dead planner's
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        mask = os.umask(0o177)  # the socket is the user's alone from its first moment
        try:
            listener.bind(str(path))
        finally:
            os.umask(mask)
        listener.listen(64)
        self.listener, self.inode = listener, path.lstat().st_ino
        self.last_seen = time.monotonic()  # idle from now, not from before the import

    def serve(self) -> str:
        """Accept connections until asked to stop or idle for too long; the reason."""
        assert self.listener is not None
        while not self.stopping:
            self.reap()
            idle = time.monotonic() - self.last_seen
            if not self.children and idle >= self.idle_timeout_s:
                return f"idle for {idle:.0f} s"
            waiting = [self.listener] if len(self.children) < MAX_CHILDREN else []
            # (a request may run past the idle timeout: the clock restarts when it ends)
            wait_s = min(1.0, max(0.05, self.idle_timeout_s - idle))
            ready, _, _ = select.select(waiting, [], [], wait_s)
            if ready:
                connection, _ = self.listener.accept()
                with connection:
                    self.handle(connection)
        return "asked to stop"

    def reap(self) -> None:
        for pid in list(self.children):
            try:
                done, _ = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:  # (reaped already)
                done = pid
            if done:
                self.children.discard(pid)
                self.last_seen = time.monotonic()

    def handle(self, connection: socket.socket) -> None:
        pid, uid = peer(connection)
        if uid != os.getuid():
            log(f"refused a connection from process {pid} of user {uid}")
            return
        self.last_seen = time.monotonic()
        connection.settimeout(HEAD_TIMEOUT_S)
        try:
            head = receive(connection)
            if head.get("protocol") != PROTOCOL:
                send(connection, {"error": f"protocol {head.get('protocol')!r}, not {PROTOCOL}"})
                return
            kind = head.get("kind")
            if kind == "hello":
                send(connection, self.status())
            elif kind == "stop":
                self.stopping = True
                send(connection, {"ok": True})
            elif kind == "plan":
                self.fork(connection)
            else:
                send(connection, {"error": f"unknown request {kind!r}"})
        except (WireError, OSError):  # the client left or spoke nonsense: the next one counts
            return

    def status(self) -> dict[str, Any]:
        return {
            "ok": True,
            "pid": os.getpid(),
            "socket": str(self.place.socket),
            "started": self.started,
            "idle_timeout_s": self.idle_timeout_s,
            "requests": self.served,
            "busy": len(self.children),
        }

    def fork(self, connection: socket.socket) -> None:
        pid = os.fork()
        if pid == 0:
            self._child(connection)
        self.children.add(pid)
        self.served += 1

    def _child(self, connection: socket.socket) -> None:
        """The forked child: answer one request, then exit (never return into the loop)."""
        code = 1
        try:
            os.close(self.lock)  # the lock stays with the planner (flock follows every copy)
            assert self.listener is not None
            self.listener.close()
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            quiet = os.open(os.devnull, os.O_WRONLY)  # the log never holds a request's content
            os.dup2(quiet, 1)
            os.dup2(quiet, 2)
            connection.settimeout(BODY_TIMEOUT_S)
            body = receive(connection)
            connection.settimeout(None)
            _end_when_the_client_leaves(connection)
            send(connection, answer(body, self.base, self.loaded))
            code = 0
        except BaseException:  # noqa: S110 - the client sees the connection close
            pass
        finally:
            os._exit(code)

    def close(self) -> None:
        if self.listener is not None:
            self.listener.close()
            with contextlib.suppress(OSError):  # only our own socket, not a successor's
                if self.place.socket.lstat().st_ino == self.inode:
                    self.place.socket.unlink()
        os.close(self.lock)


def _end_when_the_client_leaves(connection: socket.socket) -> None:
    """Exit the child as soon as the client hangs up (killed, Ctrl-C): no one waits for the
    answer. The client sends nothing more, so any read that returns means it is gone."""

    def watch() -> None:
        with contextlib.suppress(OSError):
            connection.recv(1)
        os._exit(0)

    threading.Thread(target=watch, name="keymps-warm-client-watch", daemon=True).start()


def adopt_caller_environment(
    body: dict[str, Any], base: dict[str, str], loaded: dict[str, str]
) -> None:
    """This child process as the caller's run would be: the planner's harmless start-up variables,
    the caller's key variables, what litellm's import loaded where the caller set nothing, and
    the caller's working folder (relative paths in variables resolve there)."""
    os.environ.clear()
    os.environ.update(base)
    os.environ.update({str(k): str(v) for k, v in body["environment"].items()})
    for name, value in loaded.items():
        os.environ.setdefault(name, value)
    with contextlib.suppress(OSError, TypeError):
        os.chdir(body["cwd"])


def answer(body: dict[str, Any], base: dict[str, str], loaded: dict[str, str]) -> dict[str, Any]:
    """The reply to one plan request: {"answer": ...}, {"error": line} for the backend's own
    errors (a KeympsError in a run), {"failure": line} for anything else (a bug)."""
    from keymps.planning.redaction import redact_text
    from keymps.plugin.manager import create_vlm_backend
    from keymps.types import BackendAnswer

    try:
        adopt_caller_environment(body, base, loaded)
        backend = create_vlm_backend(BACKEND, body["options"])
        answered = backend.complete(request_from_wire(body["request"]))
        if not isinstance(answered, BackendAnswer):
            raise TypeError(f"the backend returned {type(answered).__name__}")
        return {"answer": answer_to_wire(answered)}
    except KeympsError as error:
        return {"error": redact_text(str(error))}
    except Exception as error:
        return {"failure": redact_text(f"{type(error).__name__}: {error}")}


def main(arguments: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m keymps.planning.warm.server")
    parser.add_argument("--idle-timeout", type=float, default=IDLE_TIMEOUT_S)
    parser.add_argument(
        "--detach", action="store_true", help="go on in a child once the lock is held, and exit"
    )
    given = parser.parse_args(arguments)
    place = Place.for_user()
    try:
        place.check(create=True)
    except KeympsError as error:
        log(f"not started: {error}")
        return 1
    lock = take_lock(place)
    if lock is None:
        log("not started: another warm planner of this installation holds the lock")
        return 0
    if given.detach and os.fork():
        # The starter waits for this process alone: once it has exited, the lock being held
        # means the planner (the child, which holds it now) is alive.
        os._exit(0)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    server = Server(place, max(0.1, given.idle_timeout), lock)
    reason = "stopped"
    try:
        server.prepare()
        server.listen()
        log(f"listening on {place.socket} (idle timeout {server.idle_timeout_s:g} s)")
        reason = server.serve()
    finally:
        server.close()
        log(f"exits: {reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
