"""The warm planner with real processes: `keymps planner start|stop|status`, `keymps run`
through it against a real OpenAI-compatible server on 127.0.0.1 (tests/helpers/vlm_server.py),
and each of its rules:

- a run through it writes what a run in its own process writes (run.json, vlm/), and does not
  import litellm itself;
- its socket and folder are the user's alone; an unsafe folder is refused; a process of another
  user is refused by the peer check (SO_PEERCRED);
- each request carries its caller's key variables, and nothing of one request is left for the
  next (not in the planner's environment, its memory or its log); the trust rules hold;
- a client killed mid-request, a child killed mid-request, garbage on the socket: the planner
  goes on serving, or the run goes on in its own process;
- it exits after its idle timeout, when stopped, and a planner killed outright leaves nothing
  that stops the next one from starting;
- without it (`keymps run` with none up, or --no-warm-planner) nothing changes.

Starting a planner imports litellm (seconds), so most tests share one (module scope).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest
from helpers.fuzz_support import answer_text, task_copy
from helpers.vlm_server import Recorded, Reply, VlmServer

from keymps.planning.warm.client import PlannerUnavailable, WarmPlanner
from keymps.planning.warm.place import Place
from keymps.planning.warm.wire import PROTOCOL, WireError, receive, send

pytestmark = pytest.mark.slow

MODEL = "openai/test-vlm"
IMAGE = Path(__file__).resolve().parents[2] / "tasks" / "scenes" / "round_cake.png"
PROBE = (
    "import atexit, sys\n"
    "atexit.register(lambda: print('litellm imported:', 'litellm' in sys.modules, file=sys.stderr))\n"
    "from keymps.cli.app import main\n"
    "sys.argv[0] = 'keymps'\n"
    "main()\n"
)
"""`keymps` that says at its exit whether litellm was imported in its process."""


def _answer(request: Recorded) -> str:
    return answer_text("line", [[[130, 130], [130, 130]], [[100, 150], [100, 150]]], "two dots")


def _env(runtime: Path, **extra: str) -> dict[str, str]:
    """This process's environment without a planner mode or any provider key, and with its own
    folder for the planner."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k != "KEYMPS_WARM_PLANNER" and not k.endswith(("_API_KEY", "_API_TOKEN"))
    }
    env.update(XDG_RUNTIME_DIR=str(runtime), LITELLM_LOCAL_MODEL_COST_MAP="True", **extra)
    return env


def _keymps(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", PROBE, *args], env=env, capture_output=True, text=True, timeout=900
    )


def _run(
    env: dict[str, str], task: Path, out: Path, server: VlmServer, *more: str
) -> subprocess.CompletedProcess[str]:
    return _keymps(
        env, "run", str(task), "--model", MODEL, "--api-base", server.openai_base,
        "--no-cache", "--rerun", "off", "--out", str(out), *more,
    )  # fmt: skip


def _until(condition: Callable[[], Any], what: str, timeout_s: float = 120.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"not within {timeout_s:g} s: {what}")


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _children(pid: int) -> list[int]:
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            found += [int(c) for c in (task / "children").read_text().split()]
    return found


@dataclass
class Planner:
    env: dict[str, str]
    place: Place

    @property
    def client(self) -> WarmPlanner:
        return WarmPlanner(self.place)

    def status(self) -> dict[str, Any] | None:
        return self.client.status()

    @property
    def pid(self) -> int:
        status = self.status()
        assert status is not None, "the planner is not running"
        return int(status["pid"])

    def log(self) -> str:
        return self.place.log.read_text() if self.place.log.exists() else ""


@contextlib.contextmanager
def _runtime() -> Iterator[Path]:
    """A short private folder for XDG_RUNTIME_DIR (a Unix socket's path is at most 107 bytes);
    every planner started in it is ended afterwards."""
    folder = Path(tempfile.mkdtemp(prefix="kw-"))
    try:
        yield folder
    finally:
        planner = WarmPlanner(Place(folder / "keymps"))
        status = planner.status()
        if status is not None:
            planner.stop()
            with contextlib.suppress(ProcessLookupError):
                _until(lambda: not _alive(int(status["pid"])), "the planner to exit", 30)
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="module")
def planner() -> Iterator[Planner]:
    with _runtime() as folder:
        env = _env(folder)
        started = _keymps(env, "planner", "start")
        assert started.returncode == 0, started.stderr
        assert re.match(r"started: pid \d+, up \d+ s, 0 requests", started.stdout)
        planner = Planner(env, Place(folder / "keymps"))
        pid = planner.pid
        yield planner
        # it stops when told (the requests it is answering would finish first)
        stopped = _keymps(env, "planner", "stop")
        assert stopped.stdout.strip() == f"stopped (pid {pid})"
        _until(lambda: not _alive(pid), "the stop")
        assert not planner.place.socket.exists()
        assert _keymps(env, "planner", "stop").stdout.strip() == "not running"


def _comparable(folder: Path) -> dict[str, Any]:
    """run.json and the vlm/ records without what differs between any two runs: timings, the
    request's latency and the run folder's own path."""
    text = (folder / "run.json").read_text().replace(str(folder), "RUN")
    run = json.loads(text)
    run.pop("timings_s")
    run["vlm"].pop("latency_s")
    records = {}
    for path in sorted((folder / "vlm").glob("*.json")):
        record = json.loads(path.read_text().replace(str(folder), "RUN"))
        record.pop("latency_s")
        records[path.name] = record
    return {"run": run, "vlm": records, "crop": (folder / "vlm" / "crop.png").read_bytes()}


def test_a_run_through_the_planner_writes_what_a_run_in_its_own_process_writes(
    planner: Planner, tmp_path: Path
) -> None:
    task = task_copy(tmp_path / "task")
    served = planner.status()["requests"]  # type: ignore[index]
    with VlmServer(responder=_answer) as server:
        server.script(Reply.text_answer("no JSON at all"))  # a repair turn crosses too
        alone = _run({**planner.env, "KEYMPS_WARM_PLANNER": "0"}, task, tmp_path / "a", server)
        server.script(Reply.text_answer("no JSON at all"))
        warm = _run(planner.env, task, tmp_path / "b", server)
        bodies = [r.body for r in server.chat_requests]
        headers = [r.headers["authorization"] for r in server.chat_requests]
    assert alone.returncode == 0, alone.stderr
    assert warm.returncode == 0, warm.stderr
    assert _comparable(tmp_path / "a") == _comparable(tmp_path / "b")
    assert bodies[:2] == bodies[2:]  # the very same requests reached the VLM
    assert headers == ["Bearer no-key-needed"] * 4
    assert "litellm imported: True" in alone.stderr
    assert "litellm imported: False" in warm.stderr  # the point of it
    assert planner.status()["requests"] == served + 2  # type: ignore[index]
    assert "warning" not in warm.stderr


def test_without_it_a_run_is_as_before(planner: Planner, tmp_path: Path) -> None:
    """--no-warm-planner never touches a planner that is up; with none up, a run starts none."""
    task = task_copy(tmp_path / "task")
    served = planner.status()["requests"]  # type: ignore[index]
    with VlmServer(responder=_answer) as server:
        done = _run(planner.env, task, tmp_path / "off", server, "--no-warm-planner")
    assert done.returncode == 0, done.stderr
    assert "litellm imported: True" in done.stderr
    assert planner.status()["requests"] == served  # type: ignore[index]
    with _runtime() as empty, VlmServer(responder=_answer) as server:
        done = _run(_env(empty), task, tmp_path / "none", server)
        assert done.returncode == 0, done.stderr
        assert WarmPlanner(Place(empty / "keymps")).status() is None
        assert not (empty / "keymps").exists()


def test_the_socket_and_its_folder_are_the_users_alone(planner: Planner) -> None:
    import stat

    folder = planner.place.folder.lstat()
    assert stat.S_ISDIR(folder.st_mode) and stat.S_IMODE(folder.st_mode) == 0o700
    assert folder.st_uid == os.getuid()
    sock = planner.place.socket.lstat()
    assert stat.S_ISSOCK(sock.st_mode) and stat.S_IMODE(sock.st_mode) == 0o600
    for path in (planner.place.lock, planner.place.log):
        assert stat.S_IMODE(path.lstat().st_mode) == 0o600, path
    listening = Path("/proc/net/tcp").read_text() + Path("/proc/net/tcp6").read_text()
    inodes = _open_file_targets(planner.pid)
    tcp = {line.split()[9] for line in listening.splitlines()[1:] if line.split()[3] == "0A"}
    assert not {f"socket:[{inode}]" for inode in tcp} & inodes  # nothing listens on TCP


def _open_file_targets(pid: int) -> set[str]:
    """What the process's open descriptors point at, e.g. ``socket:[1234]``."""
    targets = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            targets.add(os.readlink(fd))
        except FileNotFoundError:  # closed between listing and reading: nothing open there
            continue
    return targets


@pytest.mark.skipif(os.getuid() != 0, reason="needs root: a process of another user that can "
                    "reach the socket (its folder is 0700) exists only with root's help")  # fmt: skip
def test_a_process_of_another_user_is_refused_by_the_peer_check(planner: Planner) -> None:
    """The process runs as user 65534 (its effective uid, which the kernel reports to the
    planner) and reaches the 0700 folder with a file-system uid of 0 (setfsuid): the folder's
    mode cannot stop it, the peer check must."""
    probe = (
        "import ctypes, os, socket, struct, sys\n"
        "os.setegid(65534)\n"
        "os.seteuid(65534)\n"
        "ctypes.CDLL(None, use_errno=True).setfsuid(0)\n"
        "s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)\n"
        "s.settimeout(30)\n"
        "s.connect(sys.argv[1])\n"
        'body = b\'{"kind": "hello", "protocol": %d}\' % int(sys.argv[2])\n'
        "try:\n"
        "    s.sendall(struct.pack('!I', len(body)) + body)\n"
        "    heard = s.recv(100)\n"
        "except (BrokenPipeError, ConnectionResetError):\n"
        "    heard = b''\n"
        "print(os.geteuid(), repr(heard))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe, str(planner.place.socket), str(PROTOCOL)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["65534", "b''"]  # connected, and closed without a word
    assert re.search(r"refused a connection from process \d+ of user 65534", planner.log())
    assert planner.status() is not None  # and the planner goes on


def test_garbage_on_the_socket_leaves_the_planner_serving(planner: Planner) -> None:
    def raw(data: bytes) -> bytes:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as connection:
            connection.settimeout(30)
            connection.connect(str(planner.place.socket))
            connection.sendall(data)
            with contextlib.suppress(ConnectionResetError):
                return connection.recv(1000)
            return b""

    pid = planner.pid
    assert raw(b"\xff\xff\xff\xff") == b""  # announces 4 GB
    assert raw(b"\x00\x00\x00\x05nope!") == b""
    assert raw(b"") == b""
    assert b"unknown request" in raw(_frame({"kind": "exec", "protocol": PROTOCOL}))
    assert b"protocol 99" in raw(_frame({"kind": "hello", "protocol": 99}))
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as connection:  # a plan, then silence
        connection.connect(str(planner.place.socket))
        send(connection, {"kind": "plan", "protocol": PROTOCOL})
        connection.sendall(b"\x00\x00\x10\x00{")
    assert planner.pid == pid


def _frame(message: dict[str, Any]) -> bytes:
    data = json.dumps(message).encode()
    return len(data).to_bytes(4, "big") + data


def _memory_holds(pid: int, needles: list[bytes]) -> set[bytes]:
    """Which needles are anywhere in the process's readable memory."""
    found: set[bytes] = set()
    with open(f"/proc/{pid}/maps") as maps, open(f"/proc/{pid}/mem", "rb", 0) as memory:
        for line in maps:
            fields = line.split()
            if "r" not in fields[1]:
                continue
            start, end = (int(v, 16) for v in fields[0].split("-"))
            try:
                memory.seek(start)
                chunk = memory.read(end - start)
            except (OSError, OverflowError, ValueError):
                continue
            found |= {needle for needle in needles if needle in chunk}
    return found


def test_each_request_carries_its_own_keys_and_leaves_none_behind(
    planner: Planner, tmp_path: Path
) -> None:
    canaries = {name: f"canary-{name}-{os.urandom(8).hex()}" for name in ("lab", "openai")}
    lab = task_copy(tmp_path / "lab", **{"model: openai/gpt-4o": f"model: {MODEL}\n  api_key_env: LAB_VLM_API_KEY"})  # fmt: skip
    plain = task_copy(tmp_path / "plain")
    with VlmServer(responder=_answer) as server:
        first = _run(
            {**planner.env, "LAB_VLM_API_KEY": canaries["lab"]}, lab, tmp_path / "1", server
        )
        second = _run({**planner.env, "OPENAI_API_KEY": canaries["openai"]}, lab, tmp_path / "2", server)  # fmt: skip
        third = _run({**planner.env, "OPENAI_API_KEY": canaries["openai"]}, plain, tmp_path / "3", server)  # fmt: skip
        fourth = _run(planner.env, plain, tmp_path / "4", server)
        heard = [r.headers["authorization"] for r in server.chat_requests]
    assert first.returncode == 0, first.stderr
    # the second caller has no $LAB_VLM_API_KEY: the first caller's key is not lent to it
    assert second.returncode == 1
    assert "planner.api_key_env names $LAB_VLM_API_KEY, which is not set" in second.stderr
    assert "litellm imported: False" in second.stderr
    assert third.returncode == 0 and fourth.returncode == 0, third.stderr + fourth.stderr
    assert heard == [
        f"Bearer {canaries['lab']}",
        f"Bearer {canaries['openai']}",
        "Bearer no-key-needed",  # a keyless caller gets no key of an earlier one
    ]
    needles = [value.encode() for value in canaries.values()]
    environ = Path(f"/proc/{planner.pid}/environ").read_bytes()
    assert not [n for n in needles if n in environ]
    assert not [n for n in needles if n in planner.log().encode()]
    try:
        kept = _memory_holds(planner.pid, needles)
    except PermissionError:
        pytest.skip("the planner's memory is not readable here (ptrace rules)")
    assert not kept, "a key outlived its request in the planner's memory"


def test_a_server_only_the_task_names_gets_no_key_through_the_planner(
    planner: Planner, tmp_path: Path
) -> None:
    canary = f"sk-canary-{os.urandom(8).hex()}"
    env = {**planner.env, "OPENAI_API_KEY": canary}
    with VlmServer(responder=_answer) as server:
        task = task_copy(
            tmp_path / "task",
            **{"model: openai/gpt-4o": f"model: {MODEL}\n  api_base: {server.openai_base}"},
        )
        runs = [
            _keymps({**env, "KEYMPS_WARM_PLANNER": mode}, "run", str(task), "--no-cache",
                    "--image", str(IMAGE), "--rerun", "off", "--out", str(tmp_path / mode))
            for mode in ("0", "use")
        ]  # fmt: skip
        heard = [r.headers["authorization"] for r in server.chat_requests]
    for done in runs:
        assert done.returncode == 0, done.stderr
        assert "is named only by the task file, so no API key is sent to it" in done.stderr
    assert "litellm imported: False" in runs[1].stderr
    assert heard == ["Bearer no-key-needed"] * 2


def test_a_redirect_to_another_server_is_not_followed_through_the_planner(
    planner: Planner, tmp_path: Path
) -> None:
    canary = f"sk-canary-{os.urandom(8).hex()}"
    env = {**planner.env, "OPENAI_API_KEY": canary, "KEYMPS_WARM_PLANNER": "use"}
    task = task_copy(tmp_path / "task")
    with VlmServer(responder=_answer) as own, VlmServer(responder=_answer) as other:
        own.script(Reply.redirect(307, f"{other.url}/v1/chat/completions"))
        done = _run(env, task, tmp_path / "run", own)
        heard = [r.headers.get("authorization") for r in own.chat_requests]
        elsewhere = len(other.requests)
    assert done.returncode != 0
    assert "litellm imported: False" in done.stderr, "asked through the planner"
    assert "redirected the request (HTTP 307)" in done.stderr, done.stderr
    assert "another server: not followed" in done.stderr and canary not in done.stderr
    assert heard == [f"Bearer {canary}"], "the user's own server got the key, once"
    assert elsewhere == 0
    assert not (tmp_path / "run" / "trajectory.csv").exists()


def test_a_client_killed_mid_request_leaves_the_planner_serving(
    planner: Planner, tmp_path: Path
) -> None:
    task = task_copy(tmp_path / "task")
    pid = planner.pid
    with VlmServer(responder=_answer) as server:
        server.script(Reply.text_answer(_answer(None), delay_s=300))  # type: ignore[arg-type]
        client = subprocess.Popen(
            [sys.executable, "-c", PROBE, "run", str(task), "--model", MODEL, "--api-base",
             server.openai_base, "--no-cache", "--rerun", "off", "--out", str(tmp_path / "killed")],
            env=planner.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            _until(lambda: server.chat_requests, "the request to reach the VLM", 600)
            assert _until(lambda: planner.status()["busy"], "its child")  # type: ignore[index]
        finally:
            client.kill()
            client.wait()
        # the child answering it ends with its client, long before the VLM would answer
        _until(lambda: planner.status()["busy"] == 0, "the child to end", 60)  # type: ignore[index]
        after = _run(planner.env, task, tmp_path / "after", server)
    assert after.returncode == 0, after.stderr
    assert "litellm imported: False" in after.stderr
    assert planner.pid == pid


def test_a_request_whose_answer_never_comes_is_asked_in_the_run_itself(
    planner: Planner, tmp_path: Path
) -> None:
    task = task_copy(tmp_path / "task")
    with VlmServer(responder=_answer) as server:
        server.script(Reply.text_answer(_answer(None), delay_s=300))  # type: ignore[arg-type]
        client = subprocess.Popen(
            [sys.executable, "-c", PROBE, "run", str(task), "--model", MODEL, "--api-base",
             server.openai_base, "--no-cache", "--rerun", "off", "--out", str(tmp_path / "run")],
            env=planner.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        _until(lambda: server.chat_requests, "the request to reach the VLM", 600)
        for child in _children(planner.pid):  # the planner's child dies without an answer
            os.kill(child, signal.SIGKILL)
        out, err = client.communicate(timeout=900)
        asked = len(server.chat_requests)
    assert client.returncode == 0, err
    assert "warning: the warm planner gave no answer" in err
    assert "planning in this process" in err
    assert "litellm imported: True" in err
    assert asked == 2
    assert json.loads((tmp_path / "run" / "run.json").read_text())["ok"] is True
    assert planner.status() is not None


def test_it_starts_on_demand_exits_when_idle_and_starts_after_a_kill(tmp_path: Path) -> None:
    task = task_copy(tmp_path / "task")
    with _runtime() as folder, VlmServer(responder=_answer) as server:
        env = _env(folder)
        place = Place(folder / "keymps")
        # started on demand by a run that asks for it
        done = _run({**env, "KEYMPS_WARM_PLANNER": "1"}, task, tmp_path / "first", server)
        assert done.returncode == 0, done.stderr
        status = WarmPlanner(place).status()
        assert status is not None and status["requests"] == 1
        assert "litellm imported: False" in done.stderr
        # killed outright: its socket stays behind, and nothing answers there
        os.kill(int(status["pid"]), signal.SIGKILL)
        _until(lambda: not _alive(int(status["pid"])), "the kill")
        assert place.socket.exists()
        assert _keymps(env, "planner", "status").returncode == 3
        done = _run(env, task, tmp_path / "second", server)  # none up: the run asks itself
        assert done.returncode == 0, done.stderr
        assert "litellm imported: True" in done.stderr and "warning" not in done.stderr
        # a new one starts in its place; a request longer than its idle timeout is answered,
        # and it exits once idle after it
        server.script(Reply.text_answer(_answer(None), delay_s=3))  # type: ignore[arg-type]
        pid, answer = _slow_request_to_a_new_planner(env, place, server)
        assert json.loads(answer.text)["rationale"] == "two dots"
        _until(lambda: not _alive(pid), "the idle exit", 120)
        assert re.search(rf"\[{pid}\] exits: idle for \d+ s", place.log.read_text())
        assert not place.socket.exists()
        assert not WarmPlanner(place).lock_held()


def _slow_request_to_a_new_planner(
    env: dict[str, str], place: Place, server: VlmServer
) -> tuple[int, Any]:
    """Start a planner with a 1 s idle timeout and ask it at once (again when it left before
    the request came: the test must not depend on this machine's speed)."""
    from keymps.default_plugins.litellm.warm_up import _warm_up_request

    request = replace(_warm_up_request(), model=MODEL, timeout_s=60.0)
    options = {"model": MODEL, "api_base": server.openai_base, "api_base_trusted": True}
    for _ in range(5):
        started = _keymps(env, "planner", "start", "--idle-timeout", "1")
        assert started.returncode == 0, started.stderr
        assert "exits after 1 s idle" in started.stdout
        pid = int(re.findall(r"^started: pid (\d+),", started.stdout)[0])
        with contextlib.suppress(PlannerUnavailable):
            return pid, WarmPlanner(place).plan(options, request)
    raise AssertionError("the planner never answered within its 1 s idle timeout")


@pytest.mark.parametrize("kind", ["mode 0755", "a link", "another user's"])
def test_an_unsafe_folder_is_refused_in_one_line(kind: str) -> None:
    if kind == "another user's" and os.getuid() != 0:
        pytest.skip("only root can give a folder to another user")
    with _runtime() as folder:
        target = folder / "keymps"
        if kind == "a link":
            (folder / "elsewhere").mkdir(mode=0o700)
            target.symlink_to(folder / "elsewhere")
        else:
            target.mkdir(mode=0o700)
            if kind == "mode 0755":
                target.chmod(0o755)
            else:
                os.chown(target, 65534, 65534)
        done = _keymps(_env(folder), "planner", "start")
        assert done.returncode == 1
        lines = done.stderr.strip().splitlines()
        assert lines[0].startswith(f"error: the warm planner's folder {target} ")
        assert "Traceback" not in done.stderr and len(lines) == 2  # (+ the probe's line)
        assert not list(target.glob("*.sock"))


def test_status_says_how_to_read_it(planner: Planner) -> None:
    done = _keymps(planner.env, "planner", "status", "--json")
    assert done.returncode == 0
    status = json.loads(done.stdout)
    assert status["running"] is True and status["pid"] == planner.pid
    assert status["socket"] == str(planner.place.socket)
    human = _keymps(planner.env, "planner", "status")
    assert human.stdout.startswith(f"running: pid {planner.pid}, up ")
    assert f"log {planner.place.log}" in human.stdout


def test_a_stranger_to_the_wire_gets_an_error_not_a_crash(planner: Planner) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as connection:
        connection.settimeout(60)
        connection.connect(str(planner.place.socket))
        send(connection, {"kind": "plan", "protocol": PROTOCOL})
        send(connection, {"options": {}, "request": {}, "environment": {}, "cwd": "/"})
        reply = receive(connection)
    assert set(reply) == {"failure"} and "KeyError" in reply["failure"]
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as connection:
        connection.connect(str(planner.place.socket))
        send(connection, {"kind": "plan", "protocol": PROTOCOL})
        connection.shutdown(socket.SHUT_WR)
        with pytest.raises(WireError):
            receive(connection)
    assert planner.status() is not None


CROP = re.compile(r"(\d+) x (\d+) pixels")


def _cuts(request: Recorded) -> str:
    """Three cuts across the middle of whatever crop the request shows (a valid cutting plan)."""
    width, height = (int(v) for v in CROP.findall(json.dumps(request.body["messages"]))[-1])
    pairs = [[[width * f, 0.3 * height], [width * f, 0.7 * height]] for f in (0.4, 0.5, 0.6)]
    return answer_text("straight", pairs, "three cuts")


def test_an_evaluation_asks_through_the_planner_and_imports_no_litellm(
    planner: Planner, tmp_path: Path
) -> None:
    served = planner.status()["requests"]  # type: ignore[index]
    with VlmServer(responder=_cuts) as server:
        runs = {
            mode: _keymps(
                planner.env, "eval", "cake_six", "--model", MODEL, "--api-base",
                server.openai_base, "--no-cache", "--repeats", "2", "--concurrency", "4",
                "--processes", "2", "--quiet", "--out", str(tmp_path / mode), *flags,
            )
            for mode, flags in (("warm", ()), ("alone", ("--no-warm-planner",)))
        }  # fmt: skip
        asked = len(server.chat_requests)
    for mode, done in runs.items():
        assert done.returncode == 0, done.stderr
        records = [json.loads(line) for line in (tmp_path / mode / "results.jsonl").open()]
        assert len(records) == 4 and all(r["ok"] for r in records), records
        assert {r["vlm_calls"] for r in records} == {1}
    assert asked == 8
    assert planner.status()["requests"] == served + 4  # type: ignore[index]
    assert "litellm imported: False" in runs["warm"].stderr
    assert "litellm imported: True" in runs["alone"].stderr
