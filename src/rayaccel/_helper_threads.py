"""The helper threads that run a pass's chunks beside the calling thread, kept off its CPU.

:func:`rayaccel._jit.share_among_threads` and :func:`rayaccel._jit.on_threads` run one share of
the work on the calling thread and the others on a pool of helper threads, which sleep between
passes. Linux chooses the CPU of a thread it wakes, and it often chose the caller's own, which was
busy with the caller's share: the two threads then took turns on one CPU while the other stood
idle, until the scheduler's balancing moved one of them, a millisecond or more later or not within
the pass at all. A pass's threads then read the CPU each sat on (``sched_getcpu``) at the start and
end of every chunk: on 9 of 12 calls both had run on the same CPU, and those took 5.6-7.4 ms
against 3.7-4.2 (forest-small-chair, 1024^2 camera rays, any hit, two threads, each call after a
pause of 50 ms and one call untimed, as the benchmark times them; Intel Xeon with two vCPUs,
2026-12-07); each thread's own CPU time was the same, 2.8-3.9 ms, in both kinds of call.

So before it wakes the helpers, the caller lets them run on every CPU it may use except the one it
runs on (``os.sched_setaffinity`` on the helpers' thread ids), only when that CPU is another than
at the last pass: the wake-up cannot put a helper beside the caller, and the scheduler keeps its
choice among the other CPUs. Where the platform has neither call (not Linux), or the caller may use
one CPU only, the helpers run wherever the system puts them.
"""

from __future__ import annotations

import ctypes
import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor

__all__ = ["HelperThreads"]

_START_TIMEOUT = 10.0


def _cpu_reader():
    """``sched_getcpu`` of the C library, or None where there is none (or no way to set a
    thread's CPUs)."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    try:
        reader = ctypes.CDLL(None).sched_getcpu
    except (OSError, AttributeError):
        return None
    reader.restype = ctypes.c_int
    reader.argtypes = []
    return reader


class HelperThreads:
    """``size`` helper threads, all started at once so that each one's thread id is known before
    the first pass wakes it; :meth:`submit` hands one a share after :meth:`keep_off_caller` has
    moved them off the calling thread's CPU."""

    def __init__(self, size: int):
        self._executor = ThreadPoolExecutor(size, thread_name_prefix="rayaccel")
        self._current_cpu = _cpu_reader()
        self._thread_ids = self._start(size) if self._current_cpu is not None else []
        self._kept_off = -1
        self._lock = threading.Lock()

    def _start(self, size: int) -> list[int]:
        """Start every helper (each waits at a barrier until all run, so that the pool makes
        ``size`` threads) and return their thread ids; none if they did not all start in time."""
        barrier = threading.Barrier(size)

        def thread_id(_):
            barrier.wait(_START_TIMEOUT)
            return threading.get_native_id()

        try:
            return list(self._executor.map(thread_id, range(size)))
        except threading.BrokenBarrierError:
            return []

    def keep_off_caller(self) -> None:
        """Let the helpers run on the calling thread's CPUs but the one it runs on now."""
        if not self._thread_ids:
            return
        cpu = self._current_cpu()
        if cpu == self._kept_off or cpu < 0:
            return
        others = os.sched_getaffinity(0) - {cpu}
        if not others:
            return
        with self._lock:
            try:
                for thread_id in self._thread_ids:
                    os.sched_setaffinity(thread_id, others)
            except OSError:
                self._thread_ids = []
                return
            self._kept_off = cpu

    def submit(self, work, row) -> Future:
        return self._executor.submit(work, row)
