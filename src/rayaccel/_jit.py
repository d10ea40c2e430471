"""The one Numba policy of rayaccel.

Every kernel is compiled through :func:`kernel` (serial), :func:`inline_kernel`
(inlined into callers at Numba's IR level) or :func:`parallel_kernel`
(``prange`` over rays), all cached on disk so that only the first run on a
machine pays for compilation. The cache is Numba's, stamped with the sources of
the kernel's file and of every package module that file imports
(:mod:`rayaccel._cache_key`): editing a callee in another file recompiles its
callers.

Numerics
--------
``fastmath`` stays off. Its ``nnan``/``ninf`` flags would let LLVM assume that
no value is infinite, and traversal relies on comparisons with ``inf`` (misses,
``t_max = inf``, the reciprocal of a zero direction component). Its
``contract`` flag would fuse ``a*b - c*d`` into an FMA, which breaks the exact
antisymmetry of the edge functions that makes the triangle test watertight.
``error_model="numpy"`` lets a division by zero produce ``inf`` instead of
raising, which the slab and DDA set-up rely on.

Indexing
--------
Numba wraps negative indices around, as Python does, so every ``a[i]`` with a
signed ``i`` costs a few instructions more; indexing with :data:`unsigned`
``(i)`` skips them where ``i >= 0`` is certain. In loops that do little else
(the kd-tree builder's event loops) this measured up to 2x. Only the index is
cast: arithmetic stays signed, as mixing unsigned and signed integers gives
floats in Numba.
"""

from __future__ import annotations

import contextlib
import copy
import math
import os
import threading
import time
from concurrent.futures import wait

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import analysis, cgutils, ir_utils, sigutils
from numba.core import ir as numba_ir
from numba.core.compiler import Compiler
from numba.core.compiler_lock import global_compiler_lock
from numba.core.dispatcher import Dispatcher
from numba.core.typed_passes import ParforFusionPass, ParforPass
from numba.core.typing import templates
from numba.extending import intrinsic
from numba.parfors import parfor

from ._cache_key import KernelCache
from ._helper_threads import HelperThreads

__all__ = ["kernel", "inline_kernel", "chunk_kernel", "parallel_kernel", "chunk_count", "on_threads",
           "share_among_threads", "helper_wake_seconds", "set_threads", "thread_count", "max_threads", "thread_id",
           "thread_rows", "lent_rows", "prefetch", "emit_prefetch", "unsigned"]

_COMMON = dict(nogil=True, error_model="numpy", fastmath=False)

unsigned = np.uint64


def _same_scope(scope, memo):
    return scope


@contextlib.contextmanager
def _scopes_shared_by_copies():
    """Numba inlines a function at its IR level (``inline="always"``) by deep-copying the
    function's IR block by block, and every block's copy copies the function's whole variable
    scope again, which the inlining then only reads (to rename its variables into the
    caller's scope): the copies cost blocks x variables. Within this context, held under
    Numba's compiler lock so that no other compilation sees it, a copied block shares the
    original scope instead. Measured, first ``intersect`` of bvh-binned on an empty cache:
    13.9 -> 5.3 s of CPU, the deep copies having been 80 % of a profile of it. Numba
    versions whose scopes copy themselves are left alone."""
    with global_compiler_lock:
        if "__deepcopy__" in vars(numba_ir.Scope):
            yield
            return
        numba_ir.Scope.__deepcopy__ = _same_scope
        try:
            yield
        finally:
            del numba_ir.Scope.__deepcopy__


_INLINE_SIGNATURES = {}
"""The signature :func:`_typed_once` gave each (template, typing context, argument types)."""


def _typed_once(generic):
    """``generic`` (the typing of an overload's call) remembering, for rayaccel's own overloads
    inlined at every call (``inline="always"``), the signature it gave each argument types.

    Numba's type inference re-evaluates every call of a function at each of its rounds, and
    for such an overload each evaluation runs the untyped passes and the type inference of the
    overload's whole implementation again, though the same argument types give the same
    signature (and Numba keeps, per signature, the one typed copy that it later inlines at
    every call). ``actions._cross_prim_in_mode``, the crossing modes' visit of a primitive,
    was typed 15 times for its two calls in the grid-BVH's walk of every mode (18.4 s of CPU,
    2 distinct argument types). Other overloads, a user's among them, are typed as Numba
    types them."""

    def generic_typed_once(self, args, kws):
        if not (self._inline.is_always_inline and self._overload_func.__module__.startswith(__package__ + ".")):
            return generic(self, args, kws)
        key = type(self), self.context, tuple(args), tuple(kws.items())
        signature = _INLINE_SIGNATURES.get(key)
        if signature is None:
            signature = generic(self, args, kws)
            if signature is not None:
                _INLINE_SIGNATURES[key] = signature
        return signature

    return generic_typed_once


@contextlib.contextmanager
def _inline_overloads_typed_once():
    """Within this context, held under Numba's compiler lock, rayaccel's always-inlined
    overloads are typed once per argument types (:func:`_typed_once`). Numba versions without
    the overload template's ``generic`` are left alone."""
    with global_compiler_lock:
        generic = vars(templates._OverloadFunctionTemplate).get("generic")
        if generic is None:
            yield
            return
        templates._OverloadFunctionTemplate.generic = _typed_once(generic)
        try:
            yield
        finally:
            templates._OverloadFunctionTemplate.generic = generic


def _is_variable_name(name) -> bool:
    """Whether ``name`` is a variable's name or a tuple of them (a copy ``lhs = rhs``)."""
    return type(name) is str or (type(name) is tuple and all(type(part) is str for part in name))


class _FlatCopiesOfNameSets:
    """Numba's ``copy`` module as ``numba.core.ir_utils`` sees it inside
    :func:`_name_sets_copied_flat`: ``deepcopy`` of a dict whose values are sets of variable
    names (strings, or tuples of them) copies the sets, whose members are immutable; anything
    else is deep-copied as before."""

    copy = staticmethod(copy.copy)

    @staticmethod
    def deepcopy(value, memo=None):
        if type(value) is dict and all(type(names) is set and all(map(_is_variable_name, names))
                                       for names in value.values()):
            return {key: set(names) for key, names in value.items()}
        return copy.deepcopy(value, memo)


@contextlib.contextmanager
def _name_sets_copied_flat():
    """Numba's copy propagation (``ir_utils.copy_propagate``, run by the parallel pipeline of
    every :func:`chunk_kernel`) iterates to a fixed point and deep-copies, at every iteration,
    the copies known at each block's end: sets of pairs of variable names, which a deep copy
    walks member by member. Within this context, held under Numba's compiler lock, the sets
    are copied flat (:class:`_FlatCopiesOfNameSets`): the grid-BVH's walk of every mode, first
    ``count`` on the bunny, empty cache, CPU, 39.6 and 37.9 -> 34.9 and 32.2 s (overloads typed
    once in both; measured with a first version of the flat copy that did not check the sets'
    members). Numba versions whose ``ir_utils`` does not use the ``copy`` module are left
    alone."""
    with global_compiler_lock:
        if getattr(ir_utils, "copy", None) is not copy:
            yield
            return
        ir_utils.copy = _FlatCopiesOfNameSets
        try:
            yield
        finally:
            ir_utils.copy = copy


def _live_map_by_bits(cfg, blocks, var_use_map, var_def_map):
    """``numba.core.analysis.compute_live_map``, the variables live at each block's entry, found
    by the same two fixed points (definitions reaching each block, then liveness pushed back to
    the predecessors) with each block's set of names held as the bits of one integer, so that
    a union or an intersection is one operation on integers instead of one per name. Numba's
    sets grow towards every variable of a kernel whose inlined callees give it thousands, and
    their unions took 4.4 s of the 55 s that the grid-BVH's walk of every mode compiled in
    (cProfile, 2026-11-28)."""
    names = []
    index_of = {}

    def bits(variables):
        value = 0
        for name in variables:
            index = index_of.get(name)
            if index is None:
                index = index_of[name] = len(names)
                names.append(name)
            value |= 1 << index
        return value

    def named(value):
        return {names[index] for index, bit in enumerate(reversed(bin(value))) if bit == "1"}

    topo_order = cfg.topo_order()
    used = {offset: bits(variables) for offset, variables in var_use_map.items()}
    defined = {offset: bits(variables) for offset, variables in var_def_map.items()}
    reaching = dict.fromkeys(topo_order, 0)
    grew = True
    while grew:
        grew = False
        for offset in topo_order:
            value = reaching[offset] | defined[offset] | used[offset]
            reaching[offset] = value
            for successor, _ in cfg.successors(offset):
                before = reaching.get(successor, 0)
                if before | value != before:
                    reaching[successor] = before | value
                    grew = True
    live = {offset: used[offset] for offset in blocks}
    grew = True
    while grew:
        grew = False
        for offset in reversed(topo_order):
            for predecessor, _ in cfg.predecessors(offset):
                merged = live[predecessor] | (live[offset] & reaching.get(predecessor, 0) & ~defined[predecessor])
                if merged != live[predecessor]:
                    live[predecessor] = merged
                    grew = True
    return {offset: named(value) for offset, value in live.items()}


@contextlib.contextmanager
def _live_maps_by_bits():
    """Within this context, held under Numba's compiler lock, the liveness that Numba's passes
    compute (in ``analysis``, ``ir_utils`` and ``parfors.parfor``) comes from
    :func:`_live_map_by_bits`, which finds the same sets. Numba versions whose modules do not
    all use the function are left alone."""
    modules = (analysis, ir_utils, parfor)
    with global_compiler_lock:
        original = analysis.compute_live_map
        if any(getattr(module, "compute_live_map", None) is not original for module in modules):
            yield
            return
        for module in modules:
            module.compute_live_map = _live_map_by_bits
        try:
            yield
        finally:
            for module in modules:
                module.compute_live_map = original


@contextlib.contextmanager
def _compile_shortcuts():
    """The four shortcuts under which rayaccel's kernels compile (:func:`_scopes_shared_by_copies`,
    :func:`_inline_overloads_typed_once`, :func:`_name_sets_copied_flat`, :func:`_live_maps_by_bits`);
    each compiles the same code as Numba would without it (the grid-BVH's walk of every mode
    assembles to the same 5,651 lines with and without the second and third, the 114 functions of
    :class:`_NoParforSearch`'s first comparison to the same 331,959 lines with and without the
    fourth), and none is in force outside rayaccel's compilations. The second and third, against the
    first alone, first use on an empty cache (bunny, CPU, medians of three pairs of processes,
    2026-11-28): bvh-binned ``intersect`` 6.57 -> 5.88 s, ``count`` 14.86 -> 10.80 s,
    ``intersect_all`` after it 16.76 -> 11.93 s; grid-bvh ``count`` 55.9 -> 37.6 s. The fourth, later
    that day: grid-bvh's first ``intersect`` and ``count`` 35.7-40.6 -> 28.2-32.6 s (three pairs of
    processes)."""
    with (_scopes_shared_by_copies(), _inline_overloads_typed_once(), _name_sets_copied_flat(),
          _live_maps_by_bits()):
        yield


def _without_literals(signature):
    """``signature`` (a tuple of argument types, or a full signature) with every literal type
    replaced by its plain type: ``Literal[int](0)`` by ``int64``.

    A kernel called from another with a constant argument, or with a variable whose first
    value is a constant, was compiled twice: Numba's type inference resolves the call while the
    argument's type is still the literal, compiles that specialization, and compiles again once
    the variable's later values make it ``int64``. None of the kernels it happened to is
    written to gain from a literal (the walks choose their modes through functions inlined at
    the IR level, see :mod:`rayaccel.structures.actions`). The literal call still types against
    the plain specialization, into which a literal converts. First use on an empty cache (one
    process each, CPU time, five runs each, 2026-11-27): the kd-tree's first build (bunny)
    26.9 -> 21.8 s in the median (131 -> 125 specializations; single runs 23.7-28.2 against
    19.2-27.0 s), the default build level (7.5-9.3 s against 7.8-8.8, three runs)."""
    args, return_type = sigutils.normalize_signature(signature)
    plain = tuple(types.unliteral(arg) for arg in args)
    return plain if return_type is None else return_type(*plain)


def _cached(dispatcher):
    """Cache ``dispatcher`` on disk under a stamp of its file and every file it imports
    (:mod:`rayaccel._cache_key`), so that an edited callee in another file recompiles it,
    and compile it under :func:`_compile_shortcuts` for plain argument types only
    (:func:`_without_literals`)."""
    if isinstance(dispatcher, Dispatcher):
        dispatcher._cache = KernelCache(dispatcher.py_func)
        compile_signature = dispatcher.compile

        def compile_with_shortcuts(signature):
            with _compile_shortcuts():
                return compile_signature(_without_literals(signature))

        dispatcher.compile = compile_with_shortcuts
    return dispatcher


def kernel(func):
    """Compile ``func`` as a serial, cached, GIL-free Numba kernel."""
    return _cached(numba.njit(**_COMMON)(func))


def inline_kernel(func):
    """Compile ``func`` like :func:`kernel` but inline it into its callers at Numba's IR level.

    For the small tests on the hottest paths (volume entry, primitive
    dispatch): LLVM does not always inline across Numba functions, and a
    call that passes tuples through memory at every node costs more than the
    test itself (measured: 2-3x the BVH traversal time).
    """
    return _cached(numba.njit(inline="always", **_COMMON)(func))


class _NoParforSearch(Compiler):
    """Numba's parallel pipeline without the two passes that look for loops and array
    expressions to run in parallel and fuse them (``ParforPass``, ``ParforFusionPass``), for
    kernels that have none. The passes kept, the copy propagation and dead code removal of the
    parfor pre-lowering among them, compile the same machine code: with and without the two
    passes, building each of eight methods (``bvh-binned``, ``grid-bvh``, ``kdtree``, ``grid``,
    ``hgrid``, ``octree``, ``none``, two-wide ``bvh-sah``) over the bunny and 300 spheres and
    running ``intersect``, ``occluded``, ``count`` and ``intersect_all`` on camera and random
    rays, with shadow rays and the interleaved walk for ``bvh-binned``, compiled 114 functions
    in 331,959 lines of assembly, and forcing the lane packets and the BVH's and kd-tree's
    interleaved walks, 53 functions in 122,778 lines, every chunk kernel of the package among
    them: none different once symbol, label and constant names are set aside (2026-11-28).
    Their array analysis and the fusion pass's two rounds of simplification cost compile time
    that the pre-lowering's round repeats: that set took 419 s of CPU against 484 s (one
    process each, side by side on an empty cache), the grid-BVH's first ``intersect`` and
    ``count`` (bunny, four processes each, the two passes skipped by a patch of Numba for
    functions without ``prange``) 38.3-43.2 s (median 39.5) against 42.0-54.9 s (median 46.2)."""

    def define_pipelines(self):
        pipelines = super().define_pipelines()
        for pipeline in pipelines:
            pipeline.passes = [(stage, name) for stage, name in pipeline.passes
                               if stage not in (ParforPass, ParforFusionPass)]
            pipeline.finalize()
        return pipelines


def chunk_kernel(func):
    """Compile ``func``, a serial loop over a chunk of items that :func:`on_threads` or
    :func:`share_among_threads` runs on threads, through Numba's parallel pipeline although
    it has no ``prange`` loop, less the passes that would look for one (:class:`_NoParforSearch`).

    For the ray walks: the parallel pipeline's passes make a walk's code faster than the serial
    pipeline does (the four-wide BVH walk on one thread: 3.2 against 6.1 million camera rays
    per second on the full dragon as a plain serial kernel, as fast as its ``prange`` version
    here), while lowering a ``prange`` loop into a threaded function costs as much compile time
    again (the first ``intersect`` on the bunny with an empty cache: 38.0 s of CPU as a
    ``prange`` kernel, 17.1 s as this). Without the search for one, Numba has no cause to warn
    that it found nothing to run in parallel. Where the serial code loses: the kd-tree's walk as
    a serial kernel has, in its LLVM IR, 9 atomic reference-count increments and as many
    decrements around every leaf it visits, for the array arguments of the functions inlined
    at Numba's IR level; the four-wide walk compiled here has none inside its loop (checked
    in its machine code). The parallel pipeline's copy propagation, which removes the
    variables inlining makes for arguments, is the likely reason (not confirmed).
    """
    return _cached(numba.njit(parallel=True, pipeline_class=_NoParforSearch, **_COMMON)(func))


def parallel_kernel(func):
    """Compile ``func`` as a cached kernel whose ``prange`` loops run on all threads."""
    return _cached(numba.njit(parallel=True, **_COMMON)(func))


_pool = {}


def _thread_pool() -> HelperThreads:
    """One pool of ``max_threads()`` helper threads per process, made on first use (a forked
    child gets its own: the parent's threads do not exist in it)."""
    pid = os.getpid()
    if pid not in _pool:
        _pool.clear()
        _pool[pid] = HelperThreads(max_threads())
    return _pool[pid]


_GUIDED_SHARE = 0.5
"""The part of the items left, divided among the threads, that a chunk of
:func:`share_among_threads` takes once that is less than the chunk it was given."""
_TAIL_CHUNKS = 2
"""Chunks a thread, left of :func:`share_among_threads`'s items in all, from which its chunks may
shrink."""


def chunk_count(n: int, min_chunk: int = 16384) -> int:
    """How many chunks :func:`on_threads` splits ``n`` items into: one per thread, with at
    least ``min_chunk`` items each (one chunk at least)."""
    return max(1, min(thread_count(), n // min_chunk))


def on_threads(run, n: int, min_chunk: int = 16384) -> list:
    """``[run(first, end, c) for each chunk c]`` over chunks ``c = 0, 1, ...`` of ``n`` items,
    one chunk per thread (``thread_count()``) and at least ``min_chunk`` items per chunk, the
    chunks run side by side: the first on the calling thread, the others on the threads of a
    pool kept for the process.

    For a pass whose serial kernel releases the GIL (every kernel here does), without
    compiling a parallel kernel, which costs several times a serial one on first use (a
    parallel pass over primitive boxes 3.6 s, its serial kernel 0.4 s, measured on an empty
    cache). Not always as fast: Numba compiles a ``prange`` body with its arrays marked as
    not aliasing each other where it can prove so, a serial kernel without; the grid's
    insertion passes, which write cells through computed indices, measured 38 ms against
    22 ms (counting pass) and 21 against 15 ms (row sort) on the full dragon, so they stay
    ``prange`` kernels. The primitive boxes (6.8 against 6.9 ms on the dragon, one thread),
    the ray checks and the reference count measured as fast as their ``prange`` versions;
    the gather and the centroids inside BVH builds that measured faster as a whole.
    """
    n_chunks = chunk_count(n, min_chunk)
    if n_chunks == 1:
        return [run(0, n, 0)]
    return _with_helpers(lambda c: run(c * n // n_chunks, (c + 1) * n // n_chunks, c), n_chunks)


def share_among_threads(run, n: int, chunk: int, align: int = 1, shortest_seconds: float = 0.0) -> None:
    """``run(first, end, row)`` over chunks of the ``n`` items, run by ``chunk_count(n, chunk)``
    threads, ``row`` the running thread's number (below that count, for per-thread scratch
    rows). Each thread owns a contiguous part of the items, one part a thread, and takes chunks
    from its front; a thread whose part is done takes them from the back of the part with most
    items left. Chunks are ``chunk`` items long (or what is left of a part) until fewer than
    :data:`_TAIL_CHUNKS` chunks a thread are left in all, then :data:`_GUIDED_SHARE` of the items left
    divided among the threads, but no fewer than the last chunk's pace gets through in
    ``shortest_seconds``; every chunk starts at a multiple of ``align`` (``chunk`` is one).

    For passes whose work per item varies along the items, such as the rays of a camera,
    whose lower half may hold the whole model: split in one chunk per thread, one thread
    idles while the other finishes (camera rays on the full dragon, one thread: 0.066 s for
    the upper half of the image, 0.092 s for the lower). The calling thread is one of the
    threads (:func:`_with_helpers`); after an error no thread takes another chunk. Before, the
    pool ran one task per chunk while the caller waited for each task's future in turn; against
    that, two threads, medians of 11 calls (forest) and 7 (full dragon) alternating in one
    process, the time the two threads stood between chunks fell from 2.36 to 0.69 ms for the
    forest's camera rays, any hit (the call took 13-18 ms), 2.21 to 0.85 for their closest hit,
    9.59 to 5.06 for incoherent rays, any hit, and on the dragon from 2.12 to 0.62 (camera rays,
    any hit) and 16.3 to 6.0 ms (incoherent); the first chunk began 0.2-0.5 ms sooner.

    Parts of their own, because two cores reading the same nodes pay for it: two Python threads
    each walking 2^19 of the forest's incoherent rays through one tree took 94.6 ms a call, the
    same through two copies of the tree 81.1 ms, one thread alone 81.0-83.3 (2026-12-08, Intel
    host, two vCPUs); where chunks went to the threads in turn, the two walked neighbouring
    rays, which a sorted batch (:func:`rayaccel.ray_order.coherent_batch`) sends through the same
    nodes. Against that, 2^20 incoherent rays on two threads, closest hit, medians of 9 calls,
    processes alternating, three pairs: the forest's threads busy 194.5-198.9 ms in all against
    201.7-202.1 (calls of 99.0-101.1 ms against 102.6-103.5), the full dragon's 371.3-381.8
    against 383.1-385.7 (calls 187.6-192.5 against 198.5-198.6); camera and shadow rays, settled
    calls, the time over the time before: forest 0.91-1.11 (six pairs, the noise of that hour), full
    dragon 0.98-1.04 (two).

    The last chunks shrink with the items left, as in guided self-scheduling (Polychronopoulos &
    Kuck, "Guided Self-Scheduling: A Practical Scheduling Scheme for Parallel Supercomputers", IEEE
    Trans. Computers 36(12), 1987), so that the threads end together: the full dragon's
    incoherent rays, in 32 chunks of 11 ms, had one thread end 8-10 ms before the other (calls of
    191-194 ms); with the last ones shrinking, 0.2 ms. Only the last: guided self-scheduling
    throughout gave a quarter of a camera's rays to one chunk, taken where the sky gives way to the
    model, which held its thread for 8 ms while the other ended at 7 ms (forest, 1024^2 camera
    rays, closest hit; the call 10.2-10.6 ms against 9.0). And none shorter than
    ``shortest_seconds``: chunks down to 1,024 camera rays, a few microseconds each, had the
    threads wait on each other's hand-over of the GIL (any hit 3.7-3.8 ms against 3.4-3.5)."""
    threads = chunk_count(n, chunk)
    if threads == 1:
        run(0, n, 0)
        return
    fronts = [row * n // threads // align * align for row in range(threads)]
    backs = fronts[1:] + [n]
    lock = threading.Lock()
    pace = [0.0]
    failed = []

    def next_chunk(row):
        with lock:
            left = sum(back - front for front, back in zip(fronts, backs))
            if left == 0 or failed:
                return None
            size = chunk
            if left < _TAIL_CHUNKS * threads * chunk:
                shortest = shortest_seconds / pace[0] if pace[0] > 0.0 else chunk
                guided = -(-int(max(_GUIDED_SHARE * left / threads, shortest)) // align) * align
                size = min(chunk, max(align, guided))
            if fronts[row] < backs[row]:
                first, end = fronts[row], min(fronts[row] + size, backs[row])
                fronts[row] = end
                return first, end
            victim = max(range(threads), key=lambda k: backs[k] - fronts[k])
            end = backs[victim]
            first = max(fronts[victim], -(-(end - size) // align) * align)
            backs[victim] = first
            return first, end

    def take_chunks(row):
        while (span := next_chunk(row)) is not None:
            start = time.perf_counter()
            try:
                run(*span, row)
            except BaseException:
                failed.append(row)
                raise
            pace[0] = (time.perf_counter() - start) / (span[1] - span[0])

    _with_helpers(take_chunks, threads)


def _with_helpers(work, threads: int) -> list:
    """``[work(0), ..., work(threads - 1)]``, ``work(0)`` on the calling thread while the pool's
    threads run the others, the caller and they kept on different CPUs for the pass
    (:mod:`rayaccel._helper_threads`); every call has ended when this returns, or raises the first
    error."""
    pool = _thread_pool()
    caller_cpus = pool.begin_pass()
    helpers = []
    try:
        for row in range(1, threads):
            helpers.append(pool.submit(work, row))
        mine = work(0)
    finally:
        wait(helpers)
        pool.end_pass(caller_cpus)
    return [mine] + [helper.result() for helper in helpers]


def helper_wake_seconds() -> float:
    """How long a sleeping helper of the pool takes to begin the work handed to it, as this
    machine's recent passes measured it (:meth:`.HelperThreads.wake_seconds`)."""
    return _thread_pool().wake_seconds()


def set_threads(n: int) -> None:
    """Use ``n`` threads in parallel kernels (at most ``numba.config.NUMBA_NUM_THREADS``)."""
    numba.set_num_threads(int(n))


def thread_count() -> int:
    """Threads that parallel kernels use now."""
    return numba.get_num_threads()


def max_threads() -> int:
    """The most threads parallel kernels can use in this process (``NUMBA_NUM_THREADS``)."""
    return numba.config.NUMBA_NUM_THREADS


thread_id = numba.get_thread_id


_ROW_ALIGNMENT = 128


def thread_rows(shape, dtype=np.float64) -> np.ndarray:
    """Uninitialised per-thread scratch of ``shape`` (threads first) whose rows each start on a
    128-byte boundary, the second axis lengthened as needed: two threads writing their own rows
    never write into one cache line, nor into the pair of lines the adjacent-line prefetcher
    fetches together. ``np.empty`` aligns to 16 bytes only, so the two rows of the eight-wide
    BVH walk's child entry distances (32 bytes each, written at every node) could share a line.
    No speed-up was measured from this alone (the two-thread timings of this machine vary more
    than false sharing on one line would explain); it removes the hazard, not a measured cost."""
    dtype = np.dtype(dtype)
    rows, width, *inner = shape
    item_bytes = dtype.itemsize * math.prod(inner)
    step = _ROW_ALIGNMENT // math.gcd(item_bytes, _ROW_ALIGNMENT)
    width = -(-width // step) * step
    size = rows * width * item_bytes
    raw = np.empty(size + _ROW_ALIGNMENT, dtype=np.uint8)
    offset = (-raw.ctypes.data) % _ROW_ALIGNMENT
    return raw[offset:offset + size].view(dtype).reshape(rows, width, *inner)


_returned_rows = {}


class lent_rows:  # noqa: N801  (used as a function in ``with`` statements)
    """The per-thread scratch ``make(*key)`` makes (a tuple of :func:`thread_rows`), lent for the
    ``with`` block: one that an earlier block with the same ``make`` and ``key`` gave back, or
    made anew when every one is lent out (blocks running on several Python threads at once, or
    within each other), given back when the block ends. Its contents are what the last borrower
    left, as uninitialised as a fresh :func:`thread_rows`. A query's scratch arrays, made afresh,
    were among the Python work between a call's start and its first chunk, which slows with the
    caches cold after a walk: eight ``thread_rows`` calls took 0.09-0.10 ms of a 5.2 ms query
    (forest camera rays, any hit, two threads), 3 us each in a loop. A class rather than a
    generator made into a context manager: 0.5 against 1.2 us a block (a loop of empty blocks),
    of a one-ray query's 19 us at the time."""

    __slots__ = ("_make", "_key", "_returned", "_scratch")

    def __init__(self, make, *key):
        self._make, self._key = make, key

    def __enter__(self):
        returned = self._returned = _returned_rows.setdefault((self._make, *self._key), [])
        try:
            self._scratch = returned.pop()
        except IndexError:
            self._scratch = self._make(*self._key)
        return self._scratch

    def __exit__(self, *error):
        self._returned.append(self._scratch)
        return False


@intrinsic
def prefetch(typingctx, array, row, column):
    """Ask the CPU to start loading the cache line of ``array[row, column]`` (a 2-D array; of
    ``array[row]`` for a 1-D one, ``column`` unused) without waiting for it (LLVM's
    ``llvm.prefetch``, read, high locality): for memory a traversal will read a few steps
    later, such as the nodes it pushes on its stack."""
    signature = types.void(array, row, column)

    def codegen(context, builder, sig, args):
        array_type = sig.args[0]
        view = context.make_array(array_type)(context, builder, args[0])
        row_index = context.cast(builder, args[1], sig.args[1], types.intp)
        column_index = context.cast(builder, args[2], sig.args[2], types.intp)
        emit_prefetch(builder, cgutils.get_item_pointer(context, builder, array_type, view,
                                                        [row_index, column_index][:array_type.ndim]))
        return context.get_dummy_value()

    return signature, codegen


def emit_prefetch(builder, pointer) -> None:
    """The IR of :func:`prefetch` of the cache line at ``pointer`` (for intrinsics that compute
    the address themselves)."""
    byte_pointer = builder.bitcast(pointer, ir.IntType(8).as_pointer())
    int32 = ir.IntType(32)
    function_type = ir.FunctionType(ir.VoidType(), [byte_pointer.type, int32, int32, int32])
    function = cgutils.get_or_insert_function(builder.module, function_type, "llvm.prefetch.p0")
    builder.call(function, [byte_pointer, int32(0), int32(3), int32(1)])
