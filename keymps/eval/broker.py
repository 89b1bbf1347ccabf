"""`keymps eval`'s VLM calls: one asyncio event loop, litellm's async API, --concurrency at most.

Each eval run's planning session hands the calls of a backend that offers `acomplete` to
`dispatch(backend, request)` (keymps.run.RunOptions.dispatch): `VlmBroker.complete` (from any
thread of this process) or a `BrokerClient` (from a worker process, through a pair of queues)
waits while the loop awaits `backend.acomplete(request)` under an asyncio.Semaphore(concurrency).
The backend knows nothing of the broker. A call waiting for the
server or backing off on a rate limit (keymps.default_plugins.litellm.retry) costs no thread and no CPU; the runs'
CPU work goes on meanwhile in their threads and worker processes.

The loop runs in one daemon thread per process, started on first use and kept for the
process's life (litellm keeps its HTTP clients per event loop).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import queue
import threading
from concurrent.futures import Future
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.planning.backend_choice import AUTO_VLM

if TYPE_CHECKING:
    from keymps.eval.turn import CpuTurn
    from keymps.planning.warm.dispatch import WarmDispatch
    from keymps.types import BackendAnswer, PlanRequest

BROKERED_BACKEND = AUTO_VLM
"""The planner backend whose calls a broker makes (other backends call out themselves)."""
_LOOP: asyncio.AbstractEventLoop | None = None
_LOOP_LOCK = threading.Lock()
STOPPED = "the evaluation was stopped before the VLM answered"


def event_loop() -> asyncio.AbstractEventLoop:
    """This process's broker loop, running in its own daemon thread."""
    global _LOOP
    with _LOOP_LOCK:
        if _LOOP is None or _LOOP.is_closed():
            loop = asyncio.new_event_loop()
            threading.Thread(target=loop.run_forever, name="keymps-vlm-loop", daemon=True).start()
            _LOOP = loop
        return _LOOP


def _waiting(turn: CpuTurn | None) -> contextlib.AbstractContextManager[None]:
    """While a call waits for its answer, the next run of this process computes."""
    return turn.given_up() if turn is not None else contextlib.nullcontext()


def _portable(request: PlanRequest) -> PlanRequest:
    """The request without its pixel arrays (the messages carry the image): cheap to send."""
    return replace(request, crop=np.zeros((0, 0, 3), np.uint8), crop_mask=None)


class VlmBroker:
    """Makes VLM calls on the event loop, at most `concurrency` at once."""

    def __init__(
        self,
        concurrency: int,
        warm_up: bool = False,
        turn: CpuTurn | None = None,
        via: WarmDispatch | None = None,
    ):
        self.turn = turn
        """Given up while a caller of `complete` waits for its answer (keymps.eval.turn)."""
        self.via = via
        """The warm planner, when the calls go there (keymps.planning.warm): this process then
        never imports litellm."""
        self.concurrency = max(1, concurrency)
        self._semaphore = asyncio.Semaphore(self.concurrency)
        self._pending: set[Future[Any]] = set()
        self._asking: dict[str, asyncio.Future[BackendAnswer]] = {}
        """Calls out now, by share key (only the loop's thread reads or writes it)."""
        self._lock = threading.Lock()
        self._closed = False
        if warm_up:  # import litellm (seconds) while the first runs render and detect
            from keymps.default_plugins.litellm.backend import import_litellm

            self.loop.call_soon_threadsafe(import_litellm)

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        """The loop's thread starts with the first call: offline runs never start it (and
        their worker processes can be forked from a process without threads)."""
        return event_loop()

    async def _call(self, backend: Any, request: PlanRequest) -> BackendAnswer:
        """One call, or the answer of the identical call already out (same share key): runs
        that ask the same at the same time (keymps and vlm-keypoint on one scene) pay once."""
        key = request.share_key
        if key is not None and key in self._asking:
            answer = await asyncio.shield(self._asking[key])
            return replace(answer, shared=True, cost_usd=0.0, retries=())
        call = asyncio.ensure_future(self._ask(backend, request))
        if key is not None:
            self._asking[key] = call
            call.add_done_callback(lambda _: self._asking.pop(key, None))
        return await call

    async def _ask(self, backend: Any, request: PlanRequest) -> BackendAnswer:
        async with self._semaphore:
            if self.via is not None:
                return await self.via.acall(backend, request)
            answer: BackendAnswer = await backend.acomplete(request)
            return answer

    def submit(self, backend: Any, request: PlanRequest) -> Future[BackendAnswer]:
        """Schedule one call; its future ends with the answer or the call's exception."""
        with self._lock:
            if self._closed:
                raise KeympsError("the evaluation is stopping: VLM call not made")
            future = asyncio.run_coroutine_threadsafe(self._call(backend, request), self.loop)
            self._pending.add(future)
        future.add_done_callback(self._forget)
        return future

    def _forget(self, future: Future[Any]) -> None:
        with self._lock:
            self._pending.discard(future)

    def complete(self, backend: Any, request: PlanRequest) -> BackendAnswer:
        """The answer to one call made on the loop (this thread waits): a run's `dispatch`."""
        future = self.submit(backend, request)
        try:
            with _waiting(self.turn):
                return future.result()
        except (asyncio.CancelledError, concurrent.futures.CancelledError):
            raise KeympsError(STOPPED) from None

    def serve(self, requests: Any, replies: list[Any], stop: threading.Event) -> threading.Thread:
        """Answer worker processes' calls: (worker, id, backend, request) from `requests`,
        (id, "ok", answer) or (id, "error" | "failure", message) to replies[worker], until
        `stop` is set. (Not stopped by a sentinel put on `requests`: a worker ended while it
        was writing to that queue would keep its lock, and the put would wait forever.)"""

        def reply(worker: int, call_id: int, future: Future[BackendAnswer]) -> None:
            try:
                message: tuple[Any, ...] = (call_id, "ok", future.result())
            except KeympsError as error:
                message = (call_id, "error", str(error))
            except (asyncio.CancelledError, concurrent.futures.CancelledError):
                message = (call_id, "error", STOPPED)
            except Exception as error:  # a bug in litellm or keymps: the run records it
                message = (call_id, "failure", f"{type(error).__name__}: {error}")
            with contextlib.suppress(Exception):  # the worker may be gone
                replies[worker].put(message)

        def read() -> None:
            while not stop.is_set():
                try:
                    item = requests.get(timeout=0.1)
                except queue.Empty:
                    continue
                except (EOFError, OSError, ValueError):  # the queue was closed
                    return
                worker, call_id, backend, request = item
                try:
                    future = self.submit(backend, request)
                except KeympsError as error:
                    with contextlib.suppress(Exception):
                        replies[worker].put((call_id, "error", str(error)))
                    continue
                future.add_done_callback(
                    lambda done, w=worker, i=call_id: reply(w, i, done)  # type: ignore[misc]
                )

        thread = threading.Thread(target=read, name="keymps-vlm-requests", daemon=True)
        thread.start()
        return thread

    def close(self) -> None:
        """Cancel the calls still waiting (an interrupted evaluation stops at once)."""
        with self._lock:
            self._closed = True
            pending = list(self._pending)
        for future in pending:
            future.cancel()


class BrokerClient:
    """A worker process's side: send each call to the broker, wait for its answer."""

    def __init__(
        self, worker: int, requests: Any, replies: Any, turn: CpuTurn | None = None
    ) -> None:
        self.worker = worker
        self.turn = turn
        self.requests = requests
        self.replies = replies
        self._ids = itertools.count()
        self._waiting: dict[int, Future[tuple[str, Any]]] = {}
        self._lock = threading.Lock()
        threading.Thread(target=self._read, name="keymps-vlm-replies", daemon=True).start()

    def _read(self) -> None:
        while True:
            try:
                call_id, status, value = self.replies.get()
            except (EOFError, OSError, ValueError):
                return
            with self._lock:
                future = self._waiting.pop(call_id, None)
            if future is not None:
                future.set_result((status, value))

    def complete(self, backend: Any, request: PlanRequest) -> BackendAnswer:
        """Send one call to the parent's broker and wait: a worker's runs' `dispatch`."""
        future: Future[tuple[str, Any]] = Future()
        call_id = next(self._ids)
        with self._lock:
            self._waiting[call_id] = future
        self.requests.put((self.worker, call_id, backend, _portable(request)))
        with _waiting(self.turn):
            status, value = future.result()
        if status == "ok":
            answer: BackendAnswer = value
            return answer
        if status == "error":
            raise KeympsError(value)
        raise RuntimeError(value)
