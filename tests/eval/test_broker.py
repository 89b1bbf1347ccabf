"""`keymps eval`'s VLM calls through litellm's async API against a real local server (127.0.0.1):
bounded by --concurrency, backing off on rate limits, and an interruption that keeps every
finished run."""

from __future__ import annotations

import asyncio
import email.utils
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from helpers.vlm_server import Recorded, Reply, VlmServer

from keymps.cli.app import cli
from keymps.eval.runner import read_results

SIX = '{"keyword": "straight", "pairs": [[[10, 10], [90, 90]]], "rationale": "r"}'


@pytest.fixture(autouse=True)
def _isolated(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)


def _request(model: str = "openai/test-vlm") -> Any:
    from keymps.planning.answer import answer_schema
    from keymps.types import PlanRequest

    return PlanRequest(
        instruction="cut it",
        crop=np.zeros((100, 100, 3), np.uint8),
        crop_mask=None,
        metres_per_px=(0.0005, 0.0005),
        primitives={"straight": "a straight cut"},
        object_height=0.05,
        max_pairs=8,
        messages=[{"role": "user", "content": "crop 100 x 100 pixels"}],
        schema=answer_schema("combined", ["straight"], 8),
        model=model,
    )


def _backend(server: VlmServer, **extra: Any) -> Any:
    from keymps.default_plugins.litellm.backend import LitellmBackend, LitellmOptions

    options = LitellmOptions(model="openai/test-vlm", api_base=server.openai_base, **extra)
    return LitellmBackend(options)


class InFlight:
    """Counts the calls being answered at once (`now`, `peak`).

    With `gather`, the first calls wait (30 s at most in all) until that many are in flight
    together: a machine too loaded to start the next run within a call's delay then cannot
    hide the concurrency the product reaches; a product that never reaches it costs the wait.
    """

    def __init__(self, delay_s: float, gather: int = 0) -> None:
        self.delay_s, self.gather = delay_s, gather
        self.now = self.peak = 0
        self._changed = threading.Condition()
        self._gather_until: float | None = None

    def call(self) -> None:
        with self._changed:
            self.now += 1
            self.peak = max(self.peak, self.now)
            self._changed.notify_all()
            if self._gather_until is None:
                self._gather_until = time.monotonic() + 30
            left = self._gather_until - time.monotonic()
            self._changed.wait_for(lambda: self.peak >= self.gather, timeout=max(0.0, left))
        time.sleep(self.delay_s)
        with self._changed:
            self.now -= 1

    def answer(self, request: Recorded) -> str:
        """A VlmServer responder: counted, then the six-piece answer."""
        self.call()
        return SIX


def test_the_broker_keeps_exactly_concurrency_calls_in_flight() -> None:
    """Twenty calls submitted at once, concurrency 4: the server sees 4 at a time, never 5."""
    from keymps.eval.broker import VlmBroker

    calls = InFlight(0.3, gather=4)
    with VlmServer(responder=calls.answer) as server:
        broker = VlmBroker(4)
        started = time.perf_counter()
        futures = [broker.submit(_backend(server), _request()) for _ in range(20)]
        answers = [f.result(timeout=60) for f in futures]
        elapsed = time.perf_counter() - started
        broker.close()
    assert calls.peak == 4
    assert all(a.text == SIX and a.prompt_tokens == 321 for a in answers)
    assert elapsed >= 5 * 0.3  # 20 calls, 4 at a time


def test_the_thread_serving_workers_stops_even_if_a_dead_worker_kept_the_queue_lock() -> None:
    """A worker ended (Ctrl-C) while its queue feeder was writing keeps the requests queue's
    write lock: stopping the serving thread must not need a put on that queue."""
    import multiprocessing

    from keymps.eval.broker import VlmBroker

    requests, replies = multiprocessing.Queue(), [multiprocessing.Queue()]
    requests._wlock.acquire()  # what the ended worker left behind (private, on purpose)
    stop = threading.Event()
    broker = VlmBroker(1)
    serving = broker.serve(requests, replies, stop)
    stop.set()
    serving.join(timeout=5)
    assert not serving.is_alive()
    broker.close()


def test_identical_requests_out_at_once_share_one_call() -> None:
    """keymps and vlm-keypoint ask the same for one scene: when both are out at once, the
    server answers once and the second run gets that answer as shared (no cost of its own)."""
    from dataclasses import replace

    from keymps.eval.broker import VlmBroker

    calls = InFlight(0.3)
    with VlmServer(responder=calls.answer) as server:
        broker = VlmBroker(4)
        same = replace(_request(), share_key="scene-1")
        other = replace(_request(), share_key="scene-2")
        futures = [broker.submit(_backend(server), r) for r in (same, same, other, _request())]
        answers = [f.result(timeout=60) for f in futures]
        asked = len(server.chat_requests)
        broker.close()
    assert asked == 3  # scene-1 once, scene-2 once, and the request that shares nothing
    assert [a.shared for a in answers] == [False, True, False, False]
    assert answers[1].text == answers[0].text and answers[1].cost_usd == 0.0


def test_rate_limits_back_off_exponentially_with_jitter() -> None:
    """Three 429s without Retry-After: waits of 1, 2 and 4 x the backoff, each stretched by up
    to 50 % at random, then the answer; every wait is noted for the run's vlm/ records."""

    with VlmServer() as server:
        server.script(*[Reply.error(429)] * 3, Reply.text_answer(SIX))
        backend = _backend(server, backoff_s=0.1)
        answer = asyncio.run(backend.acomplete(_request()))
        arrivals = [r.at for r in server.chat_requests]
    assert answer.text == SIX and len(arrivals) == 4
    assert len(answer.retries) == 3 and all("retried after" in n for n in answer.retries)
    waits = [float(re.search(r"retried after ([0-9.e-]+) s", n)[1]) for n in answer.retries]
    gaps = np.diff(arrivals)
    for wait, gap, base in zip(waits, gaps, (0.1, 0.2, 0.4), strict=True):
        assert base <= wait <= 1.5 * base + 0.001, (waits, base)  # the wait keymps chose
        assert gap >= wait - 0.005, (gaps, waits)  # and took (a loaded machine only adds)


def test_retry_after_is_honoured_in_seconds_and_as_a_date() -> None:

    with VlmServer() as server:
        backend = _backend(server, backoff_s=0.01)
        # a first call pays litellm's lazy imports (seconds), which would eat the date's lead
        server.script(Reply.text_answer(SIX))
        asyncio.run(backend.acomplete(_request()))
        clock_offset = time.time() - time.monotonic()
        date = email.utils.formatdate(time.time() + 2, usegmt=True)  # whole seconds: 1-2 s ahead
        server.script(
            Reply.error(429, retry_after=0.5),
            Reply("error", status=429, headers={"Retry-After": date}, text="slow down"),
            Reply.text_answer(SIX),
        )
        answer = asyncio.run(backend.acomplete(_request()))
        arrivals = [r.at for r in server.chat_requests[1:]]
    assert answer.text == SIX
    assert 0.5 <= arrivals[1] - arrivals[0] < 1.0
    # the third try comes no earlier than the date (50 ms for the clocks) and not much later
    date_monotonic = email.utils.parsedate_to_datetime(date).timestamp() - clock_offset
    assert date_monotonic - 0.05 <= arrivals[2] < date_monotonic + 0.5


def _eval(*args: str) -> Any:
    return CliRunner().invoke(cli, ["eval", *args, "--quiet"], catch_exceptions=False)


@pytest.mark.parametrize("processes", ["1", "2"])
def test_eval_reaches_but_never_exceeds_its_concurrency(tmp_path: Path, processes: str) -> None:
    calls = InFlight(0.5, gather=3)
    out = tmp_path / "c3"

    def six_wedges(request: Recorded) -> str:
        calls.call()
        return _six_wedges(request)

    with VlmServer(responder=six_wedges) as server:
        result = _eval(
            "cake_six", "--case", "round", "--repeats", "16", "--concurrency", "3",
            "--processes", processes, "--model", "openai/test-vlm",
            "--api-base", server.openai_base, "--out", str(out),
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        asked = len(server.chat_requests)
    records = read_results(out / "results.jsonl")
    assert len(records) == 16 and asked == 16
    assert all(r["ok"] and r["success"] and not r["cached"] for r in records), records
    assert calls.peak == 3


@pytest.mark.parametrize(("processes", "concurrency"), [("1", "1"), ("2", "2")])
def test_the_next_runs_are_prepared_while_the_vlm_answers(
    tmp_path: Path, processes: str, concurrency: str
) -> None:
    """While the first calls are out, more runs than --concurrency have started (their scenes,
    prompts ...), so a slot that frees up is used at once; the calls stay within --concurrency."""
    out = tmp_path / "ahead"
    runs = out / "runs" / "keymps" / "round"
    started: list[int] = []
    calls = InFlight(0.0)

    def answer(request: Recorded) -> str:
        if not started:  # the first call waits until the runs beyond it show up (10 s at most)
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and len(list(runs.glob("r*"))) <= int(concurrency):
                time.sleep(0.01)
            started.append(len(list(runs.glob("r*"))))
        calls.call()
        return _six_wedges(request)

    with VlmServer(responder=answer) as server:
        result = _eval(
            "cake_six", "--case", "round", "--repeats", "8", "--concurrency", concurrency,
            "--processes", processes, "--model", "openai/test-vlm",
            "--api-base", server.openai_base, "--out", str(out),
        )  # fmt: skip
        assert result.exit_code == 0, result.output
    records = read_results(out / "results.jsonl")
    assert len(records) == 8 and all(r["ok"] and r["success"] for r in records), records
    assert started[0] > int(concurrency)
    assert calls.peak <= int(concurrency)


def test_a_plugin_backend_keeps_its_calls_concurrent_and_within_concurrency(
    tmp_path: Path, keymps_plugins: Any
) -> None:
    """A plugin backend calls out itself, in the run's thread (no broker): --concurrency runs
    are in flight, their calls overlap, and no run ahead makes a call beyond the bound."""
    import math

    from keymps.plugin.hookspecs import hookimpl
    from keymps.types import BackendAnswer

    calls = InFlight(0.3, gather=3)  # a synchronous HTTP call, say

    class Blocking:
        name, cacheable = "blocking", False

        def complete(self, request: Any) -> BackendAnswer:
            calls.call()
            width, height = request.crop_size_px
            cx, cy, r = width / 2, height / 2, min(width, height) / 2 - 1
            pairs = [
                [
                    [cx - r * math.cos(a), cy - r * math.sin(a)],
                    [cx + r * math.cos(a), cy + r * math.sin(a)],
                ]
                for a in (math.radians(90 + 60 * k) for k in range(3))
            ]
            return BackendAnswer(
                text=json.dumps({"keyword": "straight", "pairs": pairs, "rationale": "six"})
            )

    class Plugin:
        @hookimpl
        def register_vlm_backends(self, register: Any) -> None:
            register("blocking", lambda options: Blocking())

    keymps_plugins.register(Plugin(), name="blocking-plugin")
    out = tmp_path / "plugin"
    result = _eval(
        "cake_six", "--case", "round", "--repeats", "9", "--concurrency", "3",
        "--processes", "1", "--backend", "blocking", "--out", str(out),
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    records = read_results(out / "results.jsonl")
    assert len(records) == 9 and all(r["ok"] and r["success"] for r in records), records
    assert calls.peak == 3


def _six_wedges(request: Recorded) -> str:
    import math
    import re

    text = json.dumps(request.body["messages"][1]["content"][0])
    width, height = (int(v) for v in re.findall(r"(\d+) x (\d+) pixels", text)[-1])
    cx, cy, r = width / 2, height / 2, min(width, height) / 2 - 1
    pairs = []
    for k in range(3):
        a = math.radians(90 + 60 * k)
        dx, dy = r * math.cos(a), r * math.sin(a)
        pairs.append([[cx - dx, cy - dy], [cx + dx, cy + dy]])
    return json.dumps({"keyword": "straight", "pairs": pairs, "rationale": "six"})


def test_eval_waits_out_a_rate_limit_then_records_the_run(tmp_path: Path) -> None:
    out = tmp_path / "limited"
    with VlmServer(responder=_six_wedges) as server:
        server.script(Reply.error(429, retry_after=0.4))
        result = _eval(
            "cake_six", "--case", "round", "--repeats", "1", "--model", "openai/test-vlm",
            "--api-base", server.openai_base, "--out", str(out),
        )  # fmt: skip
        arrivals = [r.at for r in server.chat_requests]
    assert result.exit_code == 0, result.output
    (record,) = read_results(out / "results.jsonl")
    assert record["ok"] and record["success"], record
    assert len(arrivals) == 2 and arrivals[1] - arrivals[0] >= 0.4
    (call,) = [json.loads(p.read_text()) for p in (out / record["folder"] / "vlm").glob("01-*")]
    assert len(call["retries"]) == 1 and "retried after 0.4 s" in call["retries"][0]


def test_eval_records_exhausted_retries_as_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "exhausted"
    secret = "sk-test-0123456789abcdef"
    monkeypatch.setenv("OPENAI_API_KEY", secret)
    with VlmServer() as server:
        server.script(*[Reply.error(429, retry_after=0.05, message=f"no, {secret}")] * 8)
        result = _eval(
            "cake_six", "--case", "round", "--repeats", "2", "--concurrency", "2",
            "--model", "openai/test-vlm", "--api-base", server.openai_base, "--out", str(out),
        )  # fmt: skip
        asked = len(server.chat_requests)
    assert result.exit_code == 0, result.output  # a failed run never stops the suite
    records = read_results(out / "results.jsonl")
    assert len(records) == 2 and asked == 8  # 1 try + 3 retries each
    for record in records:
        assert not record["ok"]
        assert "failed after 4 tries" in record["error"] and "429" in record["error"]
        assert "\n" not in record["error"] and "Traceback" not in record["error"]
    written = "".join(p.read_text() for p in out.rglob("*") if p.suffix in (".json", ".jsonl"))
    assert secret not in written + result.output and "[redacted]" in written
    assert "Traceback" not in result.output


@pytest.mark.parametrize(
    ("finished", "signum", "to_group"),
    [(1, signal.SIGINT, True), (12, signal.SIGINT, True), (6, signal.SIGTERM, False)],
    ids=["Ctrl-C after 1", "Ctrl-C after 12", "SIGTERM to the main process after 6"],
)
def test_stopping_an_offline_eval_is_one_line(
    finished: int, signum: int, to_group: bool, tmp_path: Path
) -> None:
    """Ctrl-C to the process group (a terminal's) or SIGTERM to the main process (a service
    manager's) once `finished` runs are recorded. The offline suite runs in this process too:
    its run in flight ended after the queues had closed and printed `ValueError: Queue ... is
    closed` (6 of 6 Ctrl-Cs); SIGTERM killed the suite with no word."""
    out = tmp_path / "offline"
    command = ["eval", "cutting_sim", "--backend", "offline", "--repeats", "3"]
    process = subprocess.Popen(
        [sys.executable, "-c", "from keymps.cli.app import main; main()", *command]
        + ["--processes", "2", "--quiet", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        text=True,
    )
    deadline = time.monotonic() + 120
    while len(read_results(out / "results.jsonl")) < finished and process.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    if to_group:
        os.killpg(process.pid, signum)
    else:
        os.kill(process.pid, signum)
    _, stderr = process.communicate(timeout=60)
    if process.returncode == 0:
        pytest.skip("the suite ended before the signal")
    assert process.returncode == 128 + signum, stderr
    assert "Traceback" not in stderr and "is closed" not in stderr, stderr
    assert stderr.strip().splitlines()[-1].startswith("interrupted: "), stderr


def test_ctrl_c_keeps_every_finished_run_and_a_rerun_does_the_rest(tmp_path: Path) -> None:
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) in the middle of a suite:
    it stops within seconds with one line, results.jsonl holds whole records only, and the
    same command again runs exactly the runs that are missing."""
    out = tmp_path / "interrupted"
    with VlmServer(responder=lambda r: (time.sleep(0.4), _six_wedges(r))[1]) as server:
        command = [
            sys.executable, "-c", "from keymps.cli import main; main()", "eval", "cake_six",
            "--case", "round",
            "--repeats", "24", "--concurrency", "2", "--processes", "2", "--quiet", "--no-cache",
            "--model", "openai/test-vlm", "--api-base", server.openai_base, "--out", str(out),
        ]  # fmt: skip
        process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True
        )
        results = out / "results.jsonl"
        deadline = time.monotonic() + 120
        while len(read_results(results)) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        os.killpg(process.pid, signal.SIGINT)
        stopped = time.monotonic()
        try:
            _, stderr = process.communicate(timeout=30)
        except subprocess.TimeoutExpired:  # say where it hung: before or after its last line
            os.killpg(process.pid, signal.SIGKILL)
            _, stderr = process.communicate()
            pytest.fail(f"keymps eval still running 30 s after Ctrl-C; stderr: {stderr.decode()}")
        assert time.monotonic() - stopped < 10
        assert process.returncode == 130, stderr.decode()
        assert "interrupted:" in stderr.decode() and "Traceback" not in stderr.decode()
        lines = results.read_text().splitlines()
        kept = [json.loads(line) for line in lines]  # every line a whole record
        assert 3 <= len(kept) < 24 and len({r["repeat"] for r in kept}) == len(kept)
        asked_before = len(server.chat_requests)
        rerun = subprocess.run(command, capture_output=True, timeout=300)
        assert rerun.returncode == 0, rerun.stderr.decode()
        asked_again = len(server.chat_requests) - asked_before
    records = read_results(results)
    assert sorted(r["repeat"] for r in records) == list(range(24))  # none twice, none lost
    assert asked_again == 24 - len(kept)
