"""Reusable per-thread mailboxes for the grid traversals.

A mailbox (Amanatides & Woo 1987) remembers, per primitive, the last ray
that tested it, so that a primitive referenced by several cells is tested
once per ray. Here a mailbox is an int32 array (threads, n_prims) of ray
stamps; ray ``i`` of a call stamps ``base + i``, so a mailbox needs no clearing
as long as every call gets a fresh range of stamps. When the stamps would pass
``2**31 - 1`` they start again from 0 in a new generation, and each mailbox is
cleared once, the next time it is lent (int64 stamps, which never run out,
cost twice the memory: 16 bytes a triangle on two threads).
"""

from __future__ import annotations

import contextlib
import threading

import numba
import numpy as np

__all__ = ["MailboxPool", "MAX_STAMP"]

MAX_STAMP = 2**31 - 1
"""The largest stamp an int32 mailbox holds."""


class MailboxPool:
    """Mailboxes for one structure, allocated on first use and lent to one query at a time,
    so concurrent queries from several Python threads never share one."""

    def __init__(self, n_prims: int, enabled: bool = True):
        self.n_prims = n_prims
        self.enabled = enabled
        self._lock = threading.Lock()
        self._free = []
        self._next_stamp = 0
        self._generation = 0

    @property
    def nbytes(self) -> int:
        """Memory of one mailbox, which every query reads: a stamp per primitive and thread."""
        return numba.config.NUMBA_NUM_THREADS * self.n_prims * 4 if self.enabled else 0

    def __getstate__(self) -> dict:
        """Pickle the pool's settings only: the lock cannot travel, and the mailboxes are scratch space."""
        return {"n_prims": self.n_prims, "enabled": self.enabled}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["n_prims"], state["enabled"])

    @contextlib.contextmanager
    def lend(self, n_rays: int):
        """Yield ``(mailbox, base)``: a mailbox no other call is using (empty when
        mailboxing is off) and the first of ``n_rays`` fresh stamps."""
        if not self.enabled:
            yield np.zeros((0, 0), dtype=np.int32), 0
            return
        if n_rays > MAX_STAMP:
            raise ValueError(f"{n_rays} rays in one call, more than the {MAX_STAMP} a mailbox stamps: "
                             "split the batch")
        with self._lock:
            if self._next_stamp + n_rays > MAX_STAMP:
                self._generation += 1
                self._next_stamp = 0
            mailbox, generation = self._free.pop() if self._free else (None, None)
            base = self._next_stamp
            self._next_stamp += n_rays
            current = self._generation
        if mailbox is None:
            mailbox = np.full((numba.config.NUMBA_NUM_THREADS, self.n_prims), -1, dtype=np.int32)
        elif generation != current:
            mailbox.fill(-1)
        try:
            yield mailbox, base
        finally:
            with self._lock:
                self._free.append((mailbox, current))
