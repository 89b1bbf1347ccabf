"""A fake UR controller for the tests; no arm moves. It speaks, on a 127.0.0.x address:

- RTDE (port 30004), protocol version 2 from Universal Robots' RTDE guide: protocol version,
  controller version, output recipes streamed at their frequency, input recipes and the
  client's data packages;
- the dashboard server (29999): the few lines ur_rtde asks (PolyscopeVersion, running, stop);
- the script port (30003, and 30001/30002): the URScript ur_rtde's control interface uploads.

The "control script" runs here as the controller would run ur_rtde 1.6's: it reads the command
in input_int_register_0 (with its arguments in the double registers) and answers through
output_int_register_0 (1 ready, 2 done). The "arm" follows moveJ and servoJ. Like a UR
controller's RTDE watchdog (rtde_set_watchdog, action "stop"), once setWatchdog(f) has been
called the program stops when input_int_register_0 is not updated for 1/f s: the arm stops
following and the trip is counted. What happened is counted in shared memory (ArmState), so a
test in another process can wait for it: servoJ commands, servoStop, stopScript, watchdog
updates and trips, control clients that disconnected.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import re
import socket
import struct
import threading
import time
from typing import Any

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORTS = (30001, 30002, 30003)
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
    "external_force_torque": "VECTOR6D",  # an input of ur_rtde's last recipe
}
REGISTER = re.compile(r"^(input|output)_(int|double)_register_(\d+)$")
FORMATS = {"DOUBLE": ">d", "VECTOR6D": ">6d", "INT32": ">i", "UINT32": ">I"}

# ur_rtde 1.6's command numbers (RTDE::RobotCommand::Type) and control-script states
NO_CMD, MOVEJ, SERVOJ, SERVO_STOP, WATCHDOG, SET_WATCHDOG, STOP_SCRIPT = 0, 1, 11, 16, 24, 35, 255
REALTIME = {6, 9, 10, 11, 24, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71}
"""Commands the script processes without the done/clear handshake (servoJ, the watchdog kick)."""
READY, DONE = 1, 2


class ArmState:
    """What the fake arm reports and what was done to it; shared with the server process."""

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
        self.program_running = context.Value("i", 0)
        self.servo_commands = context.Value("i", 0)
        self.servo_stops = context.Value("i", 0)
        self.script_stops = context.Value("i", 0)
        self.control_disconnects = context.Value("i", 0)
        """Control clients (RTDE connections with input recipes) that closed their connection."""
        self.watchdog_hz = context.Value("d", 0.0)
        """The frequency setWatchdog asked for; 0 while no watchdog is set (a program stop
        removes it, as on a UR controller)."""
        self.watchdog_updates = context.Value("i", 0)
        """Updates of input_int_register_0 (what the watchdog watches) since it was set."""
        self.watchdog_trips = context.Value("i", 0)

    def counts(self) -> dict[str, float]:
        """Everything counted, for an assertion's message."""
        names = ("program_running", "servo_commands", "servo_stops", "script_stops")
        names += ("control_disconnects", "watchdog_hz", "watchdog_updates", "watchdog_trips")
        return {name: getattr(self, name).value for name in names}


def _bump(counter: Any, by: int = 1) -> None:
    with counter.get_lock():
        counter.value += by


class ControlScript:
    """ur_rtde's control script as the controller runs it (one per controller)."""

    def __init__(self, state: ArmState):
        self.state = state
        self.lock = threading.Lock()
        self.out_int = [0] * 48
        self.out_double = [0.0] * 48
        self.last_update = time.monotonic()

    def uploaded(self) -> None:
        with self.lock:
            self.state.program_running.value = 1
            self.state.watchdog_hz.value = 0.0
            self.out_int[0] = READY

    def stop(self) -> None:
        """The program ends (stopScript, the dashboard's stop, a watchdog trip)."""
        self.state.program_running.value = 0
        self.state.watchdog_hz.value = 0.0
        self.out_int[0] = 0

    def package(self, ints: dict[int, int], doubles: dict[int, float]) -> None:
        """One data package of a control client: the registers it sets, then the command."""
        with self.lock:
            if 0 not in ints:
                return
            self.last_update = time.monotonic()
            if self.state.watchdog_hz.value > 0:
                _bump(self.state.watchdog_updates)
            if not self.state.program_running.value:
                return
            command = ints[0]
            if command == NO_CMD:
                if self.out_int[0] == DONE:
                    self.out_int[0] = READY
                return
            if command in REALTIME:
                self._realtime(command, doubles)
            elif self.out_int[0] == READY:
                self._command(command, doubles)

    def _realtime(self, command: int, doubles: dict[int, float]) -> None:
        if command == SERVOJ:
            _bump(self.state.servo_commands)
            self.state.q[:] = [doubles[i] for i in range(6)]

    def _command(self, command: int, doubles: dict[int, float]) -> None:
        if command == MOVEJ:
            self.state.q[:] = [doubles[i] for i in range(6)]
        elif command == SERVO_STOP:
            _bump(self.state.servo_stops)
        elif command == SET_WATCHDOG:
            self.state.watchdog_updates.value = 0
            self.state.watchdog_hz.value = doubles[0]
        elif command == STOP_SCRIPT:
            _bump(self.state.script_stops)
            self.stop()
            return
        self.out_int[0] = DONE

    def watch(self) -> None:
        """The RTDE watchdog: stop the program when the watched input is not updated in time."""
        while True:
            time.sleep(0.002)
            with self.lock:
                frequency = self.state.watchdog_hz.value
                late = time.monotonic() - self.last_update
                if frequency > 0 and self.state.program_running.value and late > 1 / frequency:
                    _bump(self.state.watchdog_trips)
                    self.stop()

    def robot_status_bits(self) -> int:
        return 0b1 | (0b10 if self.state.program_running.value else 0)  # power on, running

    def safety_status_bits(self) -> int:
        return 1 << (self.state.safety_mode.value - 1)  # NORMAL bit 0, PROTECTIVE_STOP bit 2 ...


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


def _type(name: str) -> str:
    register = REGISTER.match(name)
    if register:
        return "INT32" if register.group(2) == "int" else "DOUBLE"
    return TYPES.get(name, "NOT_FOUND")


def _value(name: str, state: ArmState, script: ControlScript, clock: float) -> Any:
    register = REGISTER.match(name)
    if register:
        index = int(register.group(3))
        return script.out_int[index] if register.group(2) == "int" else script.out_double[index]
    return {
        "timestamp": clock,
        "actual_q": list(state.q),
        "actual_qd": [0.0] * 6,
        "target_q": list(state.q),
        "robot_mode": state.robot_mode.value,
        "safety_mode": state.safety_mode.value,
        "runtime_state": 2 if state.program_running.value else 1,  # PLAYING or STOPPED
        "robot_status_bits": script.robot_status_bits(),
        "safety_status_bits": script.safety_status_bits(),
        "speed_scaling": 1.0,
    }[name]


def _values(names: list[str], state: ArmState, script: ControlScript, clock: list[float]) -> bytes:
    packed = b""
    for name in names:
        value = _value(name, state, script, clock[0])
        packed += struct.pack(
            FORMATS[_type(name)], *(value if isinstance(value, list) else [value])
        )
    return packed


class _Client:
    """One RTDE connection: its output recipe, its input recipes, its stream."""

    def __init__(self, connection: socket.socket, state: ArmState, script: ControlScript):
        self.connection, self.state, self.script = connection, state, script
        self.lock = threading.Lock()
        self.streaming = threading.Event()
        self.names: list[str] = []
        self.inputs: dict[int, list[str]] = {}
        self.frequency = 125.0

    def stream(self) -> None:
        started, clock = time.monotonic(), [0.0]
        while True:
            self.streaming.wait()
            if self.state.drop.value:
                with contextlib.suppress(OSError):
                    self.connection.shutdown(socket.SHUT_RDWR)
                return
            if not self.state.frozen.value:
                clock[0] = time.monotonic() - started
            try:
                payload = bytes([1]) + _values(self.names, self.state, self.script, clock)
                _send(self.connection, self.lock, "U", payload)
            except OSError:
                return
            time.sleep(1.0 / self.frequency)

    def serve(self) -> None:
        threading.Thread(target=self.stream, daemon=True).start()
        while True:
            size, kind = struct.unpack(">HB", _read_exactly(self.connection, 3))
            self.handle(chr(kind), _read_exactly(self.connection, size - 3))

    def handle(self, kind: str, payload: bytes) -> None:
        reply = {
            "V": lambda: bytes([1]),  # protocol version accepted
            "v": lambda: struct.pack(">IIII", 3, 15, 7, 0),  # a CB3 on software 3.15
            "O": lambda: self.output_recipe(payload),
            "I": lambda: self.input_recipe(payload),
            "S": lambda: self.start(True),
            "P": lambda: self.start(False),
        }.get(kind)
        if reply is not None:
            _send(self.connection, self.lock, kind, reply())
        elif kind == "U":
            self.data(payload)

    def output_recipe(self, payload: bytes) -> bytes:
        self.frequency = struct.unpack(">d", payload[:8])[0]
        self.names[:] = [n for n in payload[8:].decode().split(",") if n]
        _bump(self.state.recipes)
        return bytes([1]) + ",".join(_type(n) for n in self.names).encode()

    def input_recipe(self, payload: bytes) -> bytes:
        names = [n for n in payload.decode().split(",") if n]
        recipe = len(self.inputs) + 1
        self.inputs[recipe] = names
        return bytes([recipe]) + ",".join(_type(n) for n in names).encode()

    def start(self, streaming: bool) -> bytes:
        (self.streaming.set if streaming else self.streaming.clear)()
        return bytes([1])

    def data(self, payload: bytes) -> None:
        names = self.inputs.get(payload[0], [])
        ints: dict[int, int] = {}
        doubles: dict[int, float] = {}
        offset = 1
        for name in names:
            register = REGISTER.match(name)
            kind = _type(name)
            (value,) = struct.unpack_from(FORMATS[kind], payload, offset)
            offset += struct.calcsize(FORMATS[kind])
            if register and register.group(2) == "int":
                ints[int(register.group(3))] = value
            elif register:
                doubles[int(register.group(3))] = value
        self.script.package(ints, doubles)


def _dashboard(connection: socket.socket, script: ControlScript) -> None:
    connection.sendall(b"Connected: Universal Robots Dashboard Server\n")
    for line in connection.makefile("rb"):
        asked = line.decode().strip()
        if asked == "PolyscopeVersion":
            answer = "URSoftware 3.15.7.106331 (Jun 08 2023)"
        elif asked == "running":
            answer = f"Program running: {'true' if script.state.program_running.value else 'false'}"
        elif asked == "stop":
            with script.lock:
                script.stop()
            answer = "Stopped"
        elif asked == "is in remote control":
            answer = "true"
        else:
            answer = f"could not understand: '{asked}'"
        connection.sendall(answer.encode() + b"\n")


def _script_port(connection: socket.socket, script: ControlScript) -> None:
    text = b""
    while chunk := connection.recv(65536):
        text += chunk
        if b"def rtde_control" in text and text.rstrip().endswith(b"end"):
            script.uploaded()
            text = b""


def _listen(host: str, port: int, serve: Any) -> socket.socket:
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind((host, port))
    server.listen()

    def accept() -> None:
        while True:
            connection, _ = server.accept()
            connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

            def run(c: socket.socket = connection) -> None:
                try:
                    serve(c)
                except (ConnectionError, OSError):
                    pass
                finally:
                    c.close()

            threading.Thread(target=run, daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    return server


def serve(host: str, state: ArmState, ready: Any) -> None:
    """Be the controller at `host` until the process is terminated."""
    script = ControlScript(state)

    def rtde(connection: socket.socket) -> None:
        _bump(state.connections)
        client = _Client(connection, state, script)
        try:
            client.serve()
        finally:
            if client.inputs:
                _bump(state.control_disconnects)

    _listen(host, RTDE_PORT, rtde)
    _listen(host, DASHBOARD_PORT, lambda c: _dashboard(c, script))
    for port in SCRIPT_PORTS:
        _listen(host, port, lambda c: _script_port(c, script))
    ready.set()
    script.watch()


def start(host: str, state: ArmState) -> multiprocessing.process.BaseProcess:
    """The fake controller in its own process, listening when this returns."""
    context = multiprocessing.get_context("spawn")
    ready = context.Event()
    process = context.Process(target=serve, args=(host, state, ready), daemon=True)
    process.start()
    if not ready.wait(10):
        process.terminate()
        raise RuntimeError(f"the fake UR controller did not start on {host}")
    return process
