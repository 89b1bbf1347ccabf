"""Runs eval jobs in worker processes, several jobs in flight in each.

A run's own work (rendering the scene, detection, the prompt, parsing the answer, grounding,
scoring, writing its files) is about 40 ms of Python CPU, and in one process the GIL runs it one
run at a time. Worker processes each have their own GIL. A run's VLM call does not happen in the
worker: it goes to the parent's event loop (keymps.eval.broker), which makes it with litellm's
async API, at most `concurrency` at once; the worker's thread waits for the answer.

With the litellm backend each process keeps RUNS_AHEAD more runs in flight than its share of
the VLM calls: while its calls are out, it prepares the next runs, so that a VLM slot that frees
up never waits for keymps' own work. Within a process one run computes at a time
(keymps.eval.turn) and gives its turn up while it waits for the VLM. (A plugin backend makes its
calls itself, in the run's thread: its runs in flight are the calls allowed at once, and they
share the core as threads do.) A worker takes a job only when one of its threads is free.

Offline runs fork their workers from this process before it starts any thread (fork_here):
they start at once with what it has imported and import the rest as their first run needs it,
at the same time as this process. Otherwise workers are forked from a fork server that has
imported keymps, OpenCV, NumPy and Pinocchio once (keymps.eval.preload): starting one costs
milliseconds, not the second of those imports, and no worker inherits the parent's threads or
open connections. Each worker runs with the parent's environment as it is when the suite starts
(KEYMPS_CACHE_DIR ...) and ignores Ctrl-C: the parent stops, then ends them. Records come back
to the parent, which alone writes results.jsonl.

As in any multiprocessing program, a script that runs a suite with processes > 1 needs the
`if __name__ == "__main__":` guard: the fork server's workers import the script's main module.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import multiprocessing
import os
import queue
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from keymps.errors import KeympsError
from keymps.planning.backend_choice import AUTO_VLM, NO_SERVER

if TYPE_CHECKING:
    from keymps.eval.broker import VlmBroker
    from keymps.eval.runner import EvalOptions, Job
    from keymps.eval.suites import Suite
    from keymps.eval.turn import CpuTurn
    from keymps.planning.warm.dispatch import WarmDispatch

RUNS_AHEAD = 2
"""Runs each process prepares beyond its share of the VLM calls in flight."""
MIN_JOBS_PER_PROCESS = 8
"""Below this many jobs per worker, starting workers costs more than it saves."""
MIN_OFFLINE_JOBS_PER_PROCESS = 4
"""The same without a VLM: this process computes runs while the workers start (about 1 s), so
a worker pays off sooner."""
POLL_S = 0.5


OFFLINE_BACKENDS = NO_SERVER
"""Planner backends that never call a VLM: `concurrency` does not bound their runs."""


def available_cores() -> int:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, cores or 1)


def default_processes(concurrency: int, jobs: int, backend: str | None = None) -> int:
    """Worker processes for `jobs` runs at `concurrency`: one per core (every core for an
    offline backend, whatever the concurrency); 1 means in-process."""
    cores = available_cores()
    offline = backend in OFFLINE_BACKENDS
    processes = cores if offline else min(cores, concurrency)
    per_process = MIN_OFFLINE_JOBS_PER_PROCESS if offline else MIN_JOBS_PER_PROCESS
    while processes > 1 and jobs < per_process * processes:
        processes -= 1
    return max(1, processes)


def runs_in_flight(concurrency: int, processes: int, backend: str) -> int:
    """Runs started at once: the VLM calls allowed at once, and RUNS_AHEAD per process when the
    calls go through the broker (which alone keeps them to `concurrency`)."""
    from keymps.eval.broker import BROKERED_BACKEND

    if backend in OFFLINE_BACKENDS:  # nothing to wait for: one run computing per process
        return max(1, concurrency, processes)
    ahead = RUNS_AHEAD * max(1, processes) if backend == BROKERED_BACKEND else 0
    return max(1, concurrency) + ahead


def threads_per_process(runs: int, processes: int) -> list[int]:
    """Split `runs` in flight over the workers (the first ones take the remainder)."""
    base, extra = divmod(runs, processes)
    return [base + (1 if i < extra else 0) for i in range(processes) if base or i < extra]


@dataclass(frozen=True)
class JobRunner:
    """How a worker runs one job and describes a failed one (keymps.eval.runner's functions,
    passed in so that this module does not import the runner that imports it)."""

    run: Callable[..., dict[str, Any]]
    record: Callable[..., dict[str, Any]]


def _worker(
    suite: Suite,
    options: EvalOptions,
    backend: str,
    threads: int,
    environment: dict[str, str],
    jobs: Any,
    results: Any,
    vlm: tuple[int, Any, Any],
    job_runner: JobRunner,
) -> None:
    """A worker process: take a job whenever a thread is free, send each record back; its VLM
    calls go to the parent's broker (keymps.eval.broker)."""
    import signal

    # Ctrl-C and a closed terminal's SIGHUP reach the whole process group: the parent alone
    # stops, then ends its workers (SIGTERM, which ends a worker at once, not the parent's
    # orderly stop a forked worker would inherit)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    os.environ.clear()
    os.environ.update(environment)
    from keymps.eval.broker import BROKERED_BACKEND, BrokerClient
    from keymps.eval.turn import CpuTurn

    turn = CpuTurn(active=backend == BROKERED_BACKEND)
    client = BrokerClient(*vlm, turn=turn)
    _take_jobs(suite, options, backend, threads, jobs, results, job_runner, turn, client.complete)


def _take_jobs(
    suite: Suite,
    options: EvalOptions,
    backend: str,
    threads: int,
    jobs: Any,
    results: Any,
    job_runner: JobRunner,
    turn: CpuTurn,
    dispatch: Any,
    stop: threading.Event | None = None,
) -> None:
    """Take a job whenever one of `threads` is free until the queue's end (None) or `stop`."""
    free = threading.Semaphore(threads)

    def send(job: Job, future: Future[dict[str, Any]]) -> None:
        try:
            record = future.result()
        except BaseException as error:  # the runner records failures; this is a last resort
            record = {
                **job_runner.record(suite, job, options, backend),
                "ok": False,
                "error": f"internal error {type(error).__name__}: {error}",
            }
        # stopped (Ctrl-C) and the queue closed: the run is not in results.jsonl, so the next
        # `keymps eval` does it again
        with contextlib.suppress(ValueError, OSError):
            results.put((job, record))
        free.release()

    with ThreadPoolExecutor(max_workers=threads) as pool:
        while True:
            free.acquire()
            if stop is not None and stop.is_set():
                break
            try:
                job = jobs.get()
            except (EOFError, OSError, ValueError):  # the parent is gone: nothing left to do
                break
            if job is None:
                break
            future = pool.submit(turn.run, job_runner.run, suite, job, options, backend, dispatch)
            future.add_done_callback(functools.partial(send, job))


def run_in_processes(
    suite: Suite,
    jobs: Sequence[Job],
    options: EvalOptions,
    backend: str,
    processes: int,
    on_record: Callable[[Job, dict[str, Any]], None],
    broker: VlmBroker,
    job_runner: JobRunner,
) -> None:
    """Run `jobs` in `processes` processes; call on_record in this process as each one ends.

    With an offline backend this process is one of them: it takes jobs from the same queue as
    its workers from the start, so no core waits for the workers to start. With a VLM this
    process makes the calls (keymps.eval.broker) and every run is a worker's."""
    from keymps.eval.turn import CpuTurn
    from keymps.perception.board_model import lab_tables_ready

    lab_tables_ready()  # a forked worker inherits the tables, and no thread of their build
    forking = fork_here(backend)
    context: Any = multiprocessing.get_context("fork") if forking else fork_server(backend)
    shares = threads_per_process(runs_in_flight(options.concurrency, processes, backend), processes)
    here = shares.pop(0) if backend in OFFLINE_BACKENDS and len(shares) > 1 else 0
    channels = _Channels.open(context, len(shares))
    workers = _workers(context, channels, shares, suite, options, backend, job_runner)
    # before this process has any other thread (a queue's feeder included)
    unfreeze_after = forking and _fork(workers)
    for job in [*jobs, *[None] * (len(shares) + (1 if here else 0))]:
        channels.jobs.put(job)
    stop_serving, stop_computing = threading.Event(), threading.Event()
    serving = broker.serve(channels.vlm_requests, channels.vlm_replies, stop_serving)
    # Process.start() waits until the fork server has imported everything: start them aside
    starting = threading.Thread(target=_start, args=(workers,), name="keymps-eval-start")
    computing = threading.Thread(
        target=_take_jobs,
        args=(
            suite, options, backend, here, channels.jobs, channels.results, job_runner,
            CpuTurn(active=False), None, stop_computing,
        ),
        name="keymps-eval-here",
        daemon=True,
    )  # fmt: skip
    finished = False
    try:
        starting.start()
        if here:
            computing.start()
        _collect(channels.results, workers, len(jobs), on_record)
        finished = True
    finally:
        if unfreeze_after:
            gc.unfreeze()  # this process's collector as it was (a caller's process goes on)
        stop_computing.set()
        starting.join()  # a worker still starting reads the end of the queue and leaves
        _end_workers(workers, patient=finished)
        broker.close()
        stop_serving.set()
        serving.join(timeout=5)
        channels.close()


@dataclass(frozen=True)
class _Channels:
    """The queues between this process and its workers."""

    jobs: Any
    results: Any
    vlm_requests: Any
    vlm_replies: list[Any]
    """One per worker: the broker's answers to that worker's calls."""

    @classmethod
    def open(cls, context: Any, workers: int) -> _Channels:
        replies = [context.Queue() for _ in range(workers)]
        return cls(context.Queue(), context.Queue(), context.Queue(), replies)

    def close(self) -> None:
        """Close every queue without waiting for what was never read."""
        for channel in (self.jobs, self.results, self.vlm_requests, *self.vlm_replies):
            # The workers are gone: what this process still has to send (jobs never taken,
            # replies to ended runs) is dropped instead of waited for, which could be forever
            # (a full pipe nobody reads, or a lock held by a worker ended mid-write).
            channel.cancel_join_thread()
            channel.close()


def _workers(
    context: Any,
    channels: _Channels,
    shares: list[int],
    suite: Suite,
    options: EvalOptions,
    backend: str,
    job_runner: JobRunner,
) -> list[Any]:
    """The worker processes (not started), one per share of the runs in flight."""
    environment = dict(os.environ)
    return [
        context.Process(
            target=_worker,
            args=(
                suite, options, backend, threads, environment, channels.jobs, channels.results,
                (index, channels.vlm_requests, channels.vlm_replies[index]), job_runner,
            ),
            name=f"keymps-eval-{index}",
            daemon=True,
        )
        for index, threads in enumerate(shares)
    ]  # fmt: skip


def _fork(workers: list[Any]) -> bool:
    """Fork the workers from this process; True when this call froze its garbage collector (and
    the caller unfreezes it: else who froze first unfreezes)."""
    unfreeze = gc.get_freeze_count() == 0
    # Python's recipe for a fork without exec: what this process made so far is never
    # scanned by a worker's garbage collector, so its pages stay shared, not copied
    gc.freeze()
    for worker in workers:
        worker.start()
    return unfreeze


def _start(workers: list[Any]) -> None:
    """Start the workers not started yet."""
    for worker in workers:
        if worker.pid is None:
            worker.start()


def _collect(
    results: Any,
    workers: list[Any],
    count: int,
    on_record: Callable[[Job, dict[str, Any]], None],
) -> None:
    """Hand `count` records to `on_record` as they come; a worker that died stops it."""
    received = 0
    while received < count:
        try:
            job, record = results.get(timeout=POLL_S)
        except queue.Empty:
            _check_alive(workers)
            continue
        on_record(job, record)
        received += 1


def _end_workers(workers: list[Any], patient: bool) -> None:
    """Join the started workers (5 s each when `patient`, else none), terminating the rest."""
    for worker in workers:
        if worker.pid is None:  # never started
            continue
        worker.join(timeout=5 if patient else 0)
        if worker.is_alive():
            worker.terminate()
            worker.join(timeout=5)


def fork_server(backend: str) -> Any:
    """The multiprocessing context whose fork server starts the workers of runs that wait for
    a VLM: it imports keymps.eval.preload once (and the litellm backend's module, which its
    runs build: 0.15 s), and each worker starts from there."""
    from keymps.eval.broker import BROKERED_BACKEND

    context = multiprocessing.get_context("forkserver")
    preload = ["keymps.eval.preload"]
    if backend == BROKERED_BACKEND:
        preload.append("keymps.default_plugins.litellm.backend")
    context.set_forkserver_preload(preload)
    return context


def start_fork_server(backend: str) -> None:
    """Start the fork server now (its imports, a second or more, then run on the other core
    while this process reads the suite and imports litellm); a later start of a worker finds
    it running. Offline runs fork their workers from this process instead (fork_here)."""
    from multiprocessing import forkserver

    if backend in OFFLINE_BACKENDS:
        return
    fork_server(backend)
    forkserver.ensure_running()


_UNDER_WAY: dict[str, WarmDispatch | None] = {}
"""Backends whose start-up this process has begun, and the warm planner their calls go to."""


def get_going(
    backend: str,
    model: str | None,
    api_base: str | None,
    concurrency: int,
    processes: int | None,
    warm_planner: str = "off",
) -> WarmDispatch | None:
    """A VLM evaluation's slow starts, begun before the suite is read (once per process):
    the warm planner's use when one is up (or `warm_planner` is start), else litellm's import
    and first-call set-up (on a thread of this process, whose broker makes every call); and
    the fork server of the worker processes unless every run stays in this process
    (--processes 1, or one VLM call at a time). Returns at once: the warm planner's dispatch
    for the broker, or None. Offline runs need none of it."""
    from keymps.planning.planner import prepare_backend_in_background
    from keymps.planning.warm.dispatch import warm_dispatch

    if backend in OFFLINE_BACKENDS:
        return None
    if backend in _UNDER_WAY:
        return _UNDER_WAY[backend]
    warm = warm_dispatch(warm_planner) if backend == AUTO_VLM else None
    if warm is None:
        prepare_backend_in_background(backend, {"model": model, "api_base": api_base})
    if processes != 1 and concurrency > 1:
        start_fork_server(backend)
    _UNDER_WAY[backend] = warm
    return warm


def fork_here(backend: str) -> bool:
    """Offline runs fork their workers from this process while it has no other thread: each
    starts with what this process has imported (Python, NumPy, pydantic, the suite) instead of
    a fork server importing it all again, about 0.3-0.5 s later. Runs that wait for a VLM, a
    process with threads (a progress bar's) and other systems than Linux (macOS' libraries are
    not safe to fork) go through a fork server: nothing of this process's threads, locks or
    connections is copied into the workers."""
    return (
        backend in OFFLINE_BACKENDS
        and threading.active_count() == 1
        and sys.platform.startswith("linux")
    )


def _check_alive(workers: Sequence[Any]) -> None:
    for worker in workers:
        if worker.exitcode not in (None, 0):
            raise KeympsError(
                f"eval worker process {worker.name} died (exit code {worker.exitcode}); every "
                "finished run is in results.jsonl: run the same command again to resume"
            )
