"""A fake UR controller's RTDE output stream (port 30004) for the tests; no arm moves.

It speaks the RTDE protocol version 2 from Universal Robots' RTDE guide: protocol version
request, controller version, output recipe setup, start/pause, and data packages streamed at
the recipe's frequency. The joint positions and the robot and safety modes come from shared
memory, so a test can change what the "arm" reports while a client is connected.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import socket
import struct
import threading
import time
from typing import Any

RTDE_PORT = 30004
TYPES = {
    "timestamp": "DOUBLE",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "target_q": "VECTOR6D",
    "robot_mode": "INT32",
    "safety_mode": "INT32",
    "runtime_state": "UINT32",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "speed_scaling": "DOUBLE",
}
FORMATS = {"DOUBLE": ">d", "VECTOR6D": ">6d", "INT32": ">i", "UINT32": ">I"}


class ArmState:
    """What the fake arm reports; shared between the test and the server process."""

    def __init__(self, q: list[float]):
        context = multiprocessing.get_context("spawn")
        self.q = context.Array("d", q)
        self.robot_mode = context.Value("i", 7)  # RUNNING
        self.safety_mode = context.Value("i", 1)  # NORMAL
        self.connections = context.Value("i", 0)
        self.recipes = context.Value("i", 0)
        self.frozen = context.Value("i", 0)
        """1: the data packages keep coming with the same timestamp (a controller that hangs)."""
        self.drop = context.Value("i", 0)
        """1: every client connection is closed (the cable pulled)."""


def _read_exactly(connection: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = connection.recv(size - len(data))
        if not chunk:
            raise ConnectionError("client closed")
        data += chunk
    return data


def _send(connection: socket.socket, lock: threading.Lock, kind: str, payload: bytes) -> None:
    with lock:
        connection.sendall(struct.pack(">HB", len(payload) + 3, ord(kind)) + payload)


def _values(names: list[str], state: ArmState, started: float, clock: list[float]) -> bytes:
    if not state.frozen.value:
        clock[0] = time.monotonic() - started
    values: dict[str, Any] = {
        "timestamp": clock[0],
        "actual_q": list(state.q),
        "actual_qd": [0.0] * 6,
        "target_q": list(state.q),
        "robot_mode": state.robot_mode.value,
        "safety_mode": state.safety_mode.value,
        "runtime_state": 1,
        "robot_status_bits": 0b11,
        "safety_status_bits": 1,
        "speed_scaling": 1.0,
    }
    packed = b""
    for name in names:
        value = values[name]
        packed += struct.pack(
            FORMATS[TYPES[name]], *(value if isinstance(value, list) else [value])
        )
    return packed


def _serve_client(connection: socket.socket, state: ArmState) -> None:
    lock = threading.Lock()
    streaming = threading.Event()
    names: list[str] = []
    frequency = 125.0
    started = time.monotonic()
    clock = [0.0]

    def stream() -> None:
        while True:
            streaming.wait()
            if state.drop.value:
                with contextlib.suppress(OSError):
                    connection.shutdown(socket.SHUT_RDWR)
                return
            try:
                _send(connection, lock, "U", bytes([1]) + _values(names, state, started, clock))
            except OSError:
                return
            time.sleep(1.0 / frequency)

    threading.Thread(target=stream, daemon=True).start()
    while True:
        size, kind = struct.unpack(">HB", _read_exactly(connection, 3))
        payload = _read_exactly(connection, size - 3)
        if kind == ord("V"):  # request protocol version
            _send(connection, lock, "V", bytes([1]))
        elif kind == ord("v"):  # controller version: a CB3 on software 3.15
            _send(connection, lock, "v", struct.pack(">IIII", 3, 15, 7, 0))
        elif kind == ord("O"):  # output recipe: frequency, then comma-separated names
            frequency = struct.unpack(">d", payload[:8])[0]
            names[:] = [n for n in payload[8:].decode().split(",") if n]
            types = [TYPES.get(n, "NOT_FOUND") for n in names]
            with state.recipes.get_lock():
                state.recipes.value += 1
            _send(connection, lock, "O", bytes([1]) + ",".join(types).encode())
        elif kind == ord("I"):  # input recipes are not offered by this fake
            _send(connection, lock, "I", bytes([0]) + b"NOT_FOUND")
        elif kind == ord("S"):
            streaming.set()
            _send(connection, lock, "S", bytes([1]))
        elif kind == ord("P"):
            streaming.clear()
            _send(connection, lock, "P", bytes([1]))


def serve(host: str, state: ArmState, ready: Any) -> None:
    """Accept RTDE clients on host:30004 until the process is terminated."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind((host, RTDE_PORT))
    server.listen()
    ready.set()
    while True:
        connection, _ = server.accept()
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with state.connections.get_lock():
            state.connections.value += 1

        def run(c: socket.socket = connection) -> None:
            try:
                _serve_client(c, state)
            except (ConnectionError, OSError):
                pass
            finally:
                c.close()

        threading.Thread(target=run, daemon=True).start()


def start(host: str, state: ArmState) -> multiprocessing.process.BaseProcess:
    """The fake controller in its own process, listening when this returns."""
    context = multiprocessing.get_context("spawn")
    ready = context.Event()
    process = context.Process(target=serve, args=(host, state, ready), daemon=True)
    process.start()
    if not ready.wait(10):
        process.terminate()
        raise RuntimeError(f"the fake RTDE server did not start on {host}:{RTDE_PORT}")
    return process
