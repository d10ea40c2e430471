"""What a walk does with the primitives it meets: the leaf action every structure's ray walk shares.

Each structure owns one ray walk (a DDA, a stack traversal); what happens at a
leaf or cell is :func:`visit_prim`, which branches on the ``mode`` of the
:class:`Action` it is given (one NamedTuple type for every mode, so each walk
compiles once, and the branch, the same for every primitive of a batch, is
predicted):

- ``NEAREST`` keeps the closest hit (equal distances to the lower primitive
  index), or stops at the first one for any-hit queries;
- ``COUNT`` counts every crossing in ``[t_min, t_max]``;
- ``WINDING`` sums the crossings signed by the side the ray leaves through (+1
  out of a triangle's front, -1 out of its back), in half units: 2 per crossing,
  1 for a crossing at ``t = 0`` exactly (a ray starting on the surface), so that
  the sum is twice the winding number about the ray's origin of a closed mesh;
- ``LIST`` writes every crossing into the ray's slots of flat arrays, kept
  sorted by ``(t, prim)``; once the slots are full it keeps the nearest and
  lowers the walk's search bound to the farthest kept, as a closest-hit walk
  lowers it to its best hit.

A walk carries ``(best_t, best_prim, best_u, best_v)``: its search bound and the
hit that set it (``best_prim < 0`` while the bound is the interval's end), and
prunes whatever lies beyond ``best_t``. Counting and listing test primitives
with the crossing test (:func:`rayaccel.geometry.primitive.cross_prim`: each
crossing of a shared edge or vertex given to one triangle, both crossings of a
sphere); a primitive met twice (referenced from several cells) must be skipped
by the walk's mailbox, since these modes would count it again.

Every walk that takes an action is a :func:`rayaccel._jit.chunk_kernel` (a serial loop over
a chunk of rays), so the writes into the action's arrays are inlined: inlined into a
``prange`` loop, a store into an array field of a tuple argument is dropped (Numba 0.68 loses
it). Each write takes its array from the action in the statement that stores into it, after
the value is computed: an array taken from the tuple and used in another block (passed on to
a function that branches, or indexed on the left of a conditional expression) keeps a
reference that Numba counts with atomic instructions on every ray. ``perf`` found those
counts in 12 % of the samples of the four-wide walk on incoherent rays when the closest hit
was written by a called kernel; without them, one thread, forest-small-chair, bvh-binned:
primary closest +7 %, any hit +51 %, incoherent +11 / +1 %, shadow +11 / +8 % (the full
dragon: -7 to +11 %, within the noise of the run).

Choosing the action at compile time was tried twice. By its type, through
``numba.extending.overload``: the overload, called rather than inlined, cost up to half of
the kd-tree's closest-hit speed. By passing the mode to the walk on its own and making it a
literal with ``numba.literally``, so that dead-branch pruning drops the other modes: the
four-wide walk's first closest-hit call then compiled for 7.2 s with an integer mode before
asking for the literal, 25.5 s with it (21.9 s for the whole walk before), and the integer
attempt came back at the next call from Python (7.9 s for the first ``occluded``). The way
kept: a thin kernel passes the constant ``NEAREST`` to the walk, inlined at the IR level, which
hands it to :func:`visit_prim_in_mode` and :func:`finish_ray_in_mode`; Numba's dead-branch
pruning, which runs after that inlining, drops the other modes before typing. The eight-wide
walk's closest-hit kernel compiles in 5.4 s against 9.8 s for the walk of every mode
(bunny, empty cache, CPU).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba.extending import overload

from .._jit import inline_kernel, unsigned
from ..geometry.primitive import cross_prim, intersect_prim
from ..rays import result_row

__all__ = ["NEAREST", "COUNT", "LIST", "WINDING", "Action", "nearest_hit", "hit_flags", "hit_count", "hit_list",
           "hit_slots", "signed_crossings", "is_closer", "store_hit", "visit_prim", "visit_prim_in_mode", "finish_ray",
           "finish_ray_in_mode", "finish_walked_ray", "intersect_references"]

NEAREST = 0
COUNT = 1
LIST = 2
WINDING = 3


class Action(NamedTuple):
    """What a walk does with the primitives it meets, and where it writes (per output row ``r``).

    ``mode``: NEAREST, COUNT, LIST or WINDING. NEAREST: ``t``, ``prim``, ``u``, ``v`` (n,), the
    best hit of row ``r`` (:func:`finish_ray` writes every row), and ``geom`` (n,) int64, when
    not empty, 0 where row ``r`` hit and -1 where it missed (``Hits.geom`` of a plain mesh or
    sphere set); or, when ``hit`` (n,) bool is not empty, only whether row ``r`` hit there
    (:func:`hit_flags`). COUNT: ``count`` (n,) int64, crossings of row
    ``r`` (starting at 0); WINDING: signed crossings there, in half units. LIST: row ``r``
    fills ``t, prim, u, v[offsets[r]:offsets[r + 1]]``, ``count[r]`` (starting at 0) of them
    so far; or, when ``offsets`` holds one number ``size``, the ``size`` slots ``r, r + n, r +
    2n, ...`` (:func:`hit_slots`). Arrays a mode does not use are empty.
    """

    mode: int
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    count: np.ndarray
    offsets: np.ndarray
    geom: np.ndarray
    hit: np.ndarray


_NO_FLOATS = np.zeros(0)
_NO_INTS = np.zeros(0, dtype=np.int64)
_NO_FLAGS = np.zeros(0, dtype=np.bool_)


def nearest_hit(t, prim, u, v, geom=_NO_INTS) -> Action:
    """The closest-hit (or any-hit) action writing into ``t``, ``prim``, ``u``, ``v`` (n,), or into
    ``prim`` only when the three others are empty, and into ``geom`` (n,) when given: written by
    the walk's threads as each ray ends rather than by ``np.minimum(prim, 0)`` after the walk,
    forest camera rays' closest hit ran 1.04 and 1.08 times as fast (two runs of processes
    alternating with the commit before, 2**20 rays, two threads), incoherent rays' 0.95 and 1.03."""
    return Action(NEAREST, t, prim, u, v, _NO_INTS, _NO_INTS, geom, _NO_FLAGS)


def hit_flags(hit) -> Action:
    """The any-hit action writing only whether each row hit into ``hit`` (n,) bool, for
    ``occluded``: one byte a ray where the primitive took eight, and no pass over the
    primitives afterwards to compare them with 0. Against the primitive compared afterwards,
    processes alternating with the commit before, two threads: forest-small-chair camera rays
    1.26, shadow rays 1.02; full dragon camera rays 1.12, shadow rays 1.19. :func:`finish_ray`
    tests ``hit`` beside the other outputs, each in its own ``if``: nesting the others under
    its ``else`` slowed the closest-hit walk (forest camera rays 0.78-0.93, one thread)."""
    return Action(NEAREST, _NO_FLOATS, _NO_INTS, _NO_FLOATS, _NO_FLOATS, _NO_INTS, _NO_INTS, _NO_INTS, hit)


def hit_count(count) -> Action:
    """The counting action adding each row's crossings into ``count`` (n,) int64 zeros."""
    return Action(COUNT, _NO_FLOATS, _NO_INTS, _NO_FLOATS, _NO_FLOATS, count, _NO_INTS, _NO_INTS, _NO_FLAGS)


def signed_crossings(count) -> Action:
    """The action adding each row's signed crossings, in half units, into ``count`` (n,) int64
    zeros."""
    return Action(WINDING, _NO_FLOATS, _NO_INTS, _NO_FLOATS, _NO_FLOATS, count, _NO_INTS, _NO_INTS, _NO_FLAGS)


def hit_list(offsets, fill, t, prim, u, v) -> Action:
    """The listing action: row ``r`` fills ``t, prim, u, v[offsets[r]:offsets[r + 1]]``, ``fill`` (n,)
    int64 zeros counting how many so far."""
    return Action(LIST, t, prim, u, v, fill, offsets, _NO_INTS, _NO_FLAGS)


def hit_slots(size, fill, t, prim, u, v) -> Action:
    """The listing action with ``size`` slots for each of the n rows, slot ``j`` of row ``r`` at
    ``j * n + r`` in ``t, prim, u, v`` (n * size,): the rows' first slots lie side by side, so
    that rows with few hits, most of them in most batches, leave the later slots untouched."""
    return Action(LIST, t, prim, u, v, fill, np.array([size], dtype=np.int64), _NO_INTS, _NO_FLAGS)


@inline_kernel
def _slots(action, row):
    """``(first, capacity, stride)``: where row ``row``'s list starts, its length, and the step
    from one of its slots to the next."""
    if action.offsets.shape[0] == 1:
        return row, action.offsets[0], action.count.shape[0]
    first = action.offsets[row]
    return first, action.offsets[row + 1] - first, 1


@inline_kernel
def is_closer(t, prim, best_t, best_prim):
    """Whether a hit ``(t, prim)`` replaces the best so far. Equal distances go to
    the lower primitive index, so every structure reports the same primitive as
    brute force even where a ray meets a shared edge or vertex."""
    if t == np.inf:
        return False
    return best_prim < 0 or t < best_t or (t == best_t and prim < best_prim)


@inline_kernel
def store_hit(i, t, prim, u, v, out_t, out_prim, out_u, out_v):
    """Write ray ``i``'s best hit into the output arrays (left as a miss when ``prim < 0``)."""
    if prim >= 0:
        out_t[i] = t
        out_prim[i] = prim
        out_u[i] = u
        out_v[i] = v


@inline_kernel
def _insert(action, row, t, prim, u, v):
    """Put the crossing ``(t, prim)`` into row ``row``'s sorted slots, dropping the farthest when they
    are full (or the crossing itself, when it is the farthest); returns whether they are full."""
    first, capacity, stride = _slots(action, row)
    filled = action.count[row]
    if capacity == 0:
        return False
    if filled == capacity:
        last = first + (capacity - 1) * stride
        if not (t < action.t[last] or (t == action.t[last] and prim < action.prim[last])):
            return True
        j = capacity - 1
    else:
        j = filled
        action.count[row] = filled + 1
    while j > 0:
        before, slot = first + (j - 1) * stride, first + j * stride
        if not (action.t[before] > t or (action.t[before] == t and action.prim[before] > prim)):
            break
        action.t[slot] = action.t[before]
        action.prim[slot] = action.prim[before]
        action.u[slot] = action.u[before]
        action.v[slot] = action.v[before]
        j -= 1
    slot = first + j * stride
    action.t[slot] = t
    action.prim[slot] = prim
    action.u[slot] = u
    action.v[slot] = v
    return filled + 1 >= capacity


@inline_kernel
def visit_prim(action, row, kind, geom, k, prims, entry, ray, t_min, best_t, best_prim, best_u, best_v, any_hit):
    """Test the primitive in row ``k`` of ``geom`` for the ray of output row ``row`` and apply the
    action; returns ``(best_t, best_prim, best_u, best_v, stop)``, ``stop`` when the walk can end
    at once (an any-hit query that found one). The primitive's index is ``prims[entry]``."""
    return visit_prim_in_mode(action.mode, action, row, kind, geom, k, prims, entry, ray, t_min, best_t, best_prim,
                              best_u, best_v, any_hit)


@inline_kernel
def visit_prim_in_mode(mode, action, row, kind, geom, k, prims, entry, ray, t_min, best_t, best_prim, best_u, best_v,
                       any_hit):
    """:func:`visit_prim` with the action's mode given apart: a walk that passes a constant
    (``NEAREST``) has the other modes' code pruned before Numba types it, so that the
    closest-hit kernel compiles none of the crossing tests, lists and winding counts.

    A closest-hit or any-hit walk reads the primitive's index only for a hit: read before every
    test, it cost a cache miss on most tests of an incoherent walk (in-process A/B, one thread,
    2**18 incoherent rays, speed after over before: full dragon 1.03 closest / 1.04 any hit,
    dragon-203k 1.02 / 1.05, forest-small-chair 1.01 / 1.01). Reading it lazily in the crossing
    modes too (inside :func:`_cross_prim_in_mode`) lost the lists' writes (Numba 0.68: an
    overload inlined within an overload inlined at typing). Brute force passes ``arange(n)``:
    choosing ``entry`` itself by an overload on ``prims`` being ``None`` made a test worker's
    compilation of the interleaved walk grow to 10-23 GB (Numba's inliner, after the
    worker's earlier compilations)."""
    if mode == NEAREST:
        t, u, v = intersect_prim(kind, geom, k, ray, t_min, best_t)
        if t == np.inf:
            return best_t, best_prim, best_u, best_v, False
        prim = prims[entry]
        if is_closer(t, prim, best_t, best_prim):
            return t, prim, u, v, any_hit
        return best_t, best_prim, best_u, best_v, False
    return _cross_prim_in_mode(mode, action, row, kind, geom, k, prims[entry], ray, t_min, best_t, best_prim,
                               best_u, best_v)


def _cross_prim_in_mode(mode, action, row, kind, geom, k, prim, ray, t_min, best_t, best_prim, best_u, best_v):
    """The crossing modes' part of :func:`visit_prim_in_mode` (counting, winding, lists). Its
    own overload, inlined when Numba types it, not a function inlined at its IR level: a walk
    whose constant mode prunes the call before typing then never copies this code, which
    inlined at the IR level was copied into every closest-hit walk before the pruning (the
    first ``intersect`` of ``bvh-binned`` on an empty cache: 8.5 -> 5.4-6.3 s of CPU, two
    runs). A plain kernel called per primitive would compile less still, but counted and
    listed at 0.39-0.58 of the speed of the inlined code."""
    n, t_first, t_second, u, v, side = cross_prim(kind, geom, k, ray, t_min, best_t)
    if n == 0:
        return best_t, best_prim, best_u, best_v, False
    if mode == COUNT:
        action.count[row] += n
        return best_t, best_prim, best_u, best_v, False
    if mode == WINDING:
        half_turns = side if t_first == 0.0 else 2 * side
        action.count[row] += half_turns
        return best_t, best_prim, best_u, best_v, False
    full = _insert(action, row, t_first, prim, u, v)
    if n == 2:
        full = _insert(action, row, t_second, prim, u, v)
    if full:
        first, capacity, stride = _slots(action, row)
        last = first + (capacity - 1) * stride
        return action.t[last], action.prim[last], best_u, best_v, False
    return best_t, best_prim, best_u, best_v, False


@overload(_cross_prim_in_mode, inline="always")
def _cross_prim_in_mode_overload(mode, action, row, kind, geom, k, prim, ray, t_min, best_t, best_prim, best_u,
                                 best_v):
    return _cross_prim_in_mode


@inline_kernel
def finish_ray(action, row, best_t, best_prim, best_u, best_v):
    """Write what the walk kept for the ray of output row ``row``: the closest hit, or a miss
    (``t = inf``, ``prim = -1``, ``u = v = NaN``; the other modes write as they go). Every ray
    of a closest-hit walk ends here, so its output arrays need no filling beforehand. An action
    whose ``hit`` is not empty takes whether the ray hit only (:func:`hit_flags`), one whose
    ``t`` is empty the primitive only."""
    finish_ray_in_mode(action.mode, action, row, best_t, best_prim, best_u, best_v)


@inline_kernel
def finish_ray_in_mode(mode, action, row, best_t, best_prim, best_u, best_v):
    """:func:`finish_ray` with the action's mode given apart (see :func:`visit_prim_in_mode`). The
    row indexes unsigned (:data:`rayaccel._jit.unsigned`), without Numba's wrap-around of negative
    indices."""
    if mode == NEAREST:
        r = unsigned(row)
        if action.hit.shape[0] > 0:
            action.hit[r] = best_prim >= 0
        if action.prim.shape[0] > 0:
            action.prim[r] = best_prim
        if action.geom.shape[0] > 0:
            action.geom[r] = min(best_prim, 0)
        if action.t.shape[0] > 0:
            hit = best_prim >= 0
            t = best_t if hit else np.inf
            u = best_u if hit else np.nan
            v = best_v if hit else np.nan
            action.t[r] = t
            action.u[r] = u
            action.v[r] = v


@inline_kernel
def finish_walked_ray(mode, action, work, row, best_t, best_prim, best_u, best_v, n_nodes, n_tests, n_leaves):
    """:func:`finish_ray_in_mode`, then the ray's work counters (nodes, tests, leaves) when the walk
    counts (``work`` not None), for a walk that keeps them apart from its answer."""
    finish_ray_in_mode(mode, action, row, best_t, best_prim, best_u, best_v)
    if work is not None:
        work[row, 0] = n_nodes
        work[row, 1] = n_tests
        work[row, 3] = n_leaves


@inline_kernel
def finish_misses_in_mode(mode, action, hit_slot, first, end):
    """:func:`finish_ray_in_mode` for the rays ``first`` to ``end - 1`` of a batch, each of which
    missed: a fill of each output's rows ``first`` to ``end - 1`` when the rays are in their rows
    (an empty ``hit_slot``), else a row at a time."""
    if mode == NEAREST:
        if hit_slot.shape[0] == 0:
            if action.hit.shape[0] > 0:
                action.hit[first:end] = False
            if action.geom.shape[0] > 0:
                action.geom[first:end] = -1
            if action.prim.shape[0] > 0:
                action.prim[first:end] = -1
            if action.t.shape[0] > 0:
                action.t[first:end] = np.inf
                action.u[first:end] = np.nan
                action.v[first:end] = np.nan
            return
        for i in range(first, end):
            finish_ray_in_mode(mode, action, result_row(hit_slot, i), np.inf, -1, 0.0, 0.0)


@inline_kernel
def intersect_references(mode, action, row, first, end, refs, mailbox, tid, stamp, kind, geom, in_leaf_order, ray,
                         t_min, best_t, best_prim, best_u, best_v, n_tests, n_skips, any_hit):
    """Visit the primitives ``refs[first:end]`` (a cell's or a leaf's references) with the
    action, in ``mode`` (the action's own, or a constant that prunes the others' code, see
    :func:`visit_prim_in_mode`), skipping those already stamped in the mailbox, when there is
    one (an empty array or ``None`` otherwise; ``None`` leaves the mailbox test out of the
    compiled code), and stamping the others. With ``in_leaf_order`` the
    geometry is stored in reference order (row ``k`` is primitive ``refs[k]``), otherwise it
    is the scene's, row ``refs[k]``. Returns the walk's ``(best_t, best_prim, best_u,
    best_v)`` and the counters ``(tests, skips)``, updated."""
    for k in range(first, end):
        prim = refs[k]
        if mailbox is not None and mailbox.shape[0] > 0:
            if mailbox[tid, prim] == stamp:
                n_skips += 1
                continue
            mailbox[tid, prim] = stamp
        n_tests += 1
        best_t, best_prim, best_u, best_v, stop = visit_prim_in_mode(mode, action, row, kind, geom,
                                                                     k if in_leaf_order else prim, refs, k, ray,
                                                                     t_min, best_t, best_prim, best_u, best_v,
                                                                     any_hit)
        if stop:
            break
    return best_t, best_prim, best_u, best_v, n_tests, n_skips
