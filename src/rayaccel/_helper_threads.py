"""The helper threads that run a pass's chunks beside the calling thread, each on a CPU of its own.

:func:`rayaccel._jit.share_among_threads` and :func:`rayaccel._jit.on_threads` run one share of
the work on the calling thread and the others on a pool of helper threads, which sleep between
passes. Linux chooses the CPU of a thread it wakes, and it often chose the caller's own, which was
busy with the caller's share: the two threads then took turns on one CPU while the other stood
idle, until the scheduler's balancing moved one of them, a millisecond or more later or not within
the pass at all. A pass's threads then read the CPU each sat on (``sched_getcpu``) at the start and
end of every chunk: on 10 of 12 calls both had run on the same CPU, and those took 5.6-7.4 ms
against 3.8 and 4.2 (forest-small-chair, 1024^2 camera rays, any hit, two threads, each call after a
pause of 50 ms and one call untimed, as the benchmark times them; Intel Xeon with two vCPUs,
2026-12-07); each thread's own CPU time was the same, 2.8-3.9 ms, in both kinds of call.

So for each pass the caller is pinned to the CPU it runs on, and before it wakes the helpers they
are let run on every other CPU the caller may use (``os.sched_setaffinity`` on their thread ids,
only when the caller's CPU or CPUs changed since the last pass); the caller gets its CPUs back when
the pass ends. Helpers kept off the caller's CPU alone were not enough: the caller, waiting for the
GIL while a helper dispatched its next chunk, was woken onto the helper's CPU in turn. Settled calls
of forest-small-chair queries on two threads, counting those whose two threads met on a CPU: 10 of
120 with the helpers alone kept off (camera and shadow rays, 2 to 4 of 20), none with the caller
pinned too. Times (medians of 16 calls in 4 rounds alternating the three ways in one process, free
/ helpers kept off / caller pinned too): shadow rays any hit 11.11 / 7.48 / 7.48 ms, closest 9.33 /
8.73 / 8.53, camera rays any hit 4.95 / 4.46 / 4.34, closest 12.10 / 11.86 / 12.17, 2^18
incoherent rays 0.99-1.01. A pass begun while another runs (queries on several Python threads)
leaves the placement as it is. Where the platform has neither call (not Linux), or the caller may
use one CPU only, the threads run wherever the system puts them.
"""

from __future__ import annotations

import collections
import ctypes
import os
import statistics
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor

__all__ = ["HelperThreads"]

_START_TIMEOUT = 10.0
_WAKES_KEPT = 15
"""Latest helper start latencies :meth:`HelperThreads.wake_seconds` takes the median of."""
_FIRST_WAKES = 5
"""Empty tasks the pool hands its helpers when it starts, to measure their start latency before
any pass does."""


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


def _nothing(_row) -> None:
    """An empty task."""


class HelperThreads:
    """``size`` helper threads, all started at once so that each one's thread id is known before
    the first pass wakes it; :meth:`submit` hands one a share between :meth:`begin_pass`, which
    keeps the caller and the helpers on different CPUs, and :meth:`end_pass`."""

    def __init__(self, size: int):
        self._executor = ThreadPoolExecutor(size, thread_name_prefix="rayaccel")
        self._current_cpu = _cpu_reader()
        self._thread_ids = self._start(size) if self._current_cpu is not None else []
        self._helpers_on = None
        self._passes = 0
        self._lock = threading.Lock()
        self._wakes = collections.deque(maxlen=_WAKES_KEPT)
        for _ in range(_FIRST_WAKES):
            self.submit(_nothing, 0).result()

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

    def begin_pass(self):
        """Keep the calling thread and the helpers apart for one pass: the caller pinned to the
        CPU it runs on, the helpers let run on its other CPUs. Returns what :meth:`end_pass` needs
        to give the caller its CPUs back; None where nothing was changed: placement unavailable,
        a caller with one CPU, or another pass already running (on another Python thread), whose
        placement stands."""
        with self._lock:
            self._passes += 1
            if self._passes > 1 or not self._thread_ids:
                return None
        cpu = self._current_cpu()
        try:
            caller_cpus = os.sched_getaffinity(0)
            others = caller_cpus - {cpu}
            if cpu < 0 or not others:
                return None
            if (cpu, others) != self._helpers_on:
                for thread_id in self._thread_ids:
                    os.sched_setaffinity(thread_id, others)
                self._helpers_on = cpu, others
            os.sched_setaffinity(0, {cpu})
        except OSError:
            self._thread_ids = []
            return None
        return caller_cpus

    def end_pass(self, caller_cpus) -> None:
        """Undo :meth:`begin_pass`: the caller's CPUs back as they were."""
        with self._lock:
            self._passes -= 1
        if caller_cpus is not None:
            os.sched_setaffinity(0, caller_cpus)

    def submit(self, work, row) -> Future:
        """``work(row)`` on a helper, the time it took the helper to begin it kept for
        :meth:`wake_seconds`."""
        return self._executor.submit(self._begin, time.perf_counter(), work, row)

    def _begin(self, submitted: float, work, row):
        self._wakes.append(time.perf_counter() - submitted)
        return work(row)

    def wake_seconds(self) -> float:
        """The median time from :meth:`submit` to a helper beginning its work, over the latest
        :data:`_WAKES_KEPT` submissions: the latency of waking a sleeping thread, which a pass pays
        about twice (the helper's start, then the caller's when the helper ends last)."""
        return statistics.median(self._wakes)
