"""Event lists of the kd-tree builder: encoding and sorting.

An event (Wald & Havran 2006) marks where a primitive's box starts or ends on
one axis, or where a box that is flat on that axis lies (*planar*). It is
stored as a position (float64) and a code ``prim << 2 | type``; the lists of
one node hold each axis's events in turn, sorted by position and, at equal
positions, by type: ends, then planars, then starts, which is the order the
sweep needs to count primitives left of, on and right of a plane.
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel

__all__ = ["END", "PLANAR", "START", "order_ties", "root_events", "event_before", "sort_events"]

END = 0
PLANAR = 1
START = 2


@kernel
def order_ties(pos, code, scratch):
    """Reorder runs of equal positions by event type (end, planar, start) in linear time;
    ``pos`` must already be sorted. ``scratch`` is an int64 array at least as long."""
    n = pos.shape[0]
    i = 0
    while i < n:
        j = i + 1
        while j < n and pos[j] == pos[i]:
            j += 1
        if j - i > 1:
            m = 0
            for kind in (END, PLANAR, START):
                for k in range(i, j):
                    if code[k] & 3 == kind:
                        scratch[m] = code[k]
                        m += 1
            code[i:j] = scratch[:j - i]
        i = j


def root_events(lo: np.ndarray, hi: np.ndarray, executor=None):
    """The sorted events of all primitives, axis by axis: ``(pos, code, span)`` with
    ``code = prim << 2 | type`` and axis ``a``'s events at ``span[a, 0]:span[a, 1]``.
    The three axes sort concurrently when ``executor`` is given."""
    prims = np.arange(len(lo), dtype=np.int64)

    def one_axis(axis):
        flat = lo[:, axis] == hi[:, axis]
        solid = ~flat
        pos = np.concatenate((hi[solid, axis], lo[flat, axis], lo[solid, axis]))
        code = np.concatenate((prims[solid] << 2 | END, prims[flat] << 2 | PLANAR, prims[solid] << 2 | START))
        order = np.argsort(pos)
        pos, code = pos[order], code[order]
        order_ties(pos, code, np.empty(len(code), dtype=np.int64))
        return pos, code

    per_axis = list(executor.map(one_axis, range(3)) if executor else map(one_axis, range(3)))
    lengths = np.array([len(p) for p, _ in per_axis], dtype=np.int64)
    span = np.stack((np.cumsum(lengths) - lengths, np.cumsum(lengths)), axis=1)
    return np.concatenate([p for p, _ in per_axis]), np.concatenate([c for _, c in per_axis]), span


@kernel
def event_before(pos_a, code_a, pos_b, code_b):
    return pos_a < pos_b or (pos_a == pos_b and code_a & 3 < code_b & 3)


@kernel
def sort_events(pos, code, n):
    """Sort ``pos[:n]``, ``code[:n]`` in place by position, then type."""
    if n <= 32:
        for k in range(1, n):
            p = pos[k]
            c = code[k]
            j = k
            while j > 0 and event_before(p, c, pos[j - 1], code[j - 1]):
                pos[j] = pos[j - 1]
                code[j] = code[j - 1]
                j -= 1
            pos[j] = p
            code[j] = c
        return
    order = np.argsort(pos[:n])
    sorted_pos = pos[:n][order]
    sorted_code = code[:n][order]
    pos[:n] = sorted_pos
    code[:n] = sorted_code
    order_ties(pos[:n], code[:n], np.empty(n, dtype=np.int64))
