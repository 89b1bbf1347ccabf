"""Bounds on work, not on the wall clock: a test of "no hang" or "linear, not quadratic" must not
fail because other processes keep the cores busy.

`Budget` measures the CPU seconds this process spends (every thread of it) and, only as a guard
against a real hang (a blocked read, a loop that sleeps), the wall seconds, with a bound loose
enough that no load makes it fail: HANG_FACTOR times the CPU bound, plus HANG_FLOOR_S.
"""

from __future__ import annotations

import resource
import time

HANG_FACTOR = 20
HANG_FLOOR_S = 60.0


class Budget:
    """Started when made; `check` asserts the work since then stayed within its bound."""

    def __init__(self, children: bool = False) -> None:
        self.children = children
        self.cpu_started = self._cpu()
        self.wall_started = time.perf_counter()

    def _cpu(self) -> float:
        if self.children:  # work done in child processes that have ended
            usage = resource.getrusage(resource.RUSAGE_CHILDREN)
            return usage.ru_utime + usage.ru_stime
        return time.process_time()

    def check(self, cpu_s: float, what: str = "") -> None:
        """Assert at most `cpu_s` CPU seconds were spent, and that no hang happened."""
        cpu = self._cpu() - self.cpu_started
        wall = time.perf_counter() - self.wall_started
        label = f"{what}: " if what else ""
        assert cpu < cpu_s, f"{label}{cpu:.2f} s of CPU, more than the bound of {cpu_s} s"
        hang = HANG_FACTOR * cpu_s + HANG_FLOOR_S
        assert wall < hang, f"{label}still running after {wall:.0f} s of wall time (a hang)"
