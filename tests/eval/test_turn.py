"""keymps.eval.turn: one run computes at a time in a process, and none while it waits."""

from __future__ import annotations

import threading
import time

from keymps.eval.turn import CpuTurn


def test_a_run_waiting_for_the_vlm_lets_the_next_run_compute() -> None:
    turn = CpuTurn()
    events: list[str] = []
    answer = threading.Event()

    def first() -> None:
        events.append("first computes")
        with turn.given_up():
            answer.wait(timeout=10)
        events.append("first goes on")

    def second() -> None:
        events.append("second computes")
        answer.set()  # the VLM answers while the second run has the turn
        time.sleep(0.05)
        events.append("second done")

    one = threading.Thread(target=turn.run, args=(first,))
    one.start()
    while not events:
        time.sleep(0.001)
    two = threading.Thread(target=turn.run, args=(second,))
    two.start()
    one.join(timeout=10)
    two.join(timeout=10)
    # the first run takes its turn back only when the second gives it up (here: when done)
    assert events == ["first computes", "second computes", "second done", "first goes on"]


def test_runs_never_compute_at_the_same_time() -> None:
    turn = CpuTurn()
    state = {"now": 0, "peak": 0}
    lock = threading.Lock()

    def work() -> int:
        with lock:
            state["now"] += 1
            state["peak"] = max(state["peak"], state["now"])
        time.sleep(0.01)
        with lock:
            state["now"] -= 1
        with turn.given_up():  # waiting: others may compute meanwhile
            time.sleep(0.01)
        return 1

    threads = [threading.Thread(target=turn.run, args=(work,)) for _ in range(6)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=10)
    assert state["peak"] == 1


def test_giving_up_a_turn_one_does_not_hold_changes_nothing() -> None:
    turn = CpuTurn()
    with turn.given_up():  # `keymps run`, or a thread outside any eval: no turn to give up
        pass
    assert turn.run(lambda value: value + 1, 41) == 42
    assert turn.run(lambda: "free again") == "free again"  # the turn was released after use


def test_an_inactive_turn_lets_runs_compute_together() -> None:
    """For plugin backends, which wait inside their own calls: no turn is ever waited for."""
    turn = CpuTurn(active=False)
    both_inside = threading.Barrier(2, timeout=5)
    threads = [threading.Thread(target=turn.run, args=(both_inside.wait,)) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=10)
    assert not both_inside.broken  # both threads were inside run() at the same time
