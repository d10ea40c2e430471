"""A walk's chunks run on Numba's own threads, each thread taking its next chunk itself.

:func:`rayaccel._jit.share_among_threads` hands a walk's chunks to Python threads, the calling
thread and a pool's helpers, which sleep between passes and take the GIL between chunks. On a
two-vCPU virtual machine a query of short rays pays for that about a tenth of its time
(forest-small-chair, 1024^2 camera rays, any hit, two threads, calls of 3.2-3.3 ms, 2026-12-08):
waking the helper 0.06-0.08 ms, its first chunk 0.04 ms after the caller's, 0.08 ms a thread
between chunks, 0.065 ms until the caller sees the helper end. :func:`run_chunks` runs such a
pass in a Numba parallel kernel instead (:func:`_take_chunks`): its ``prange`` gives each thread
one loop that takes the next chunk from a counter the threads share, advanced by an atomic
compare-and-exchange, the last chunks shrinking as in guided self-scheduling (Polychronopoulos &
Kuck, IEEE Trans. Computers 36(12), 1987), and calls the walk on it, with no Python in between
(the threads are Numba's threading layer's, OpenMP's or TBB's). That query's calls went from
3.44-3.56 to 3.05-3.19 ms (:func:`run_chunks`). The threads do not take parts of the rays of
their own first, as the pool's do: in this kernel that measured no better (time over time with
one counter, two pairs of processes: full dragon incoherent rays 1.05-1.06 / 1.02-1.04, forest camera,
shadow and incoherent rays 0.94-1.09). Nor can Ctrl-C stop a batch before it ends, as it could
between the pool's chunks.

The kernel calls the walk through the address of its compiled code (:func:`_call_compiled`),
not by name: called by name, the walk's code is linked into the kernel's and optimised by LLVM
once more, which took 2.8-2.9 s for each walk on a cache that had the walk already; through its
address, the kernel compiles in 0.8-1.0 s, once for each signature of the walks' arguments (a
camera's rays with their one origin, rays with origins of their own, ...), and Numba's cache
keeps it.

Taken only where it is safe, else the pool runs the pass: a threading layer that takes parallel
kernels from several Python threads at once (``omp``, ``tbb``; ``workqueue`` aborts the process),
in the process that imported rayaccel (GNU OpenMP aborts a forked child that uses it after its
parent did), for walks that return a count (their unusable rays) or nothing, and whose
arguments hold tuples one level deep at most (:func:`_flattened`).
"""

from __future__ import annotations

import os

import numba
import numpy as np
from llvmlite import ir
from numba import prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from .._jit import inline_kernel, parallel_kernel
from .actions import Action

__all__ = ["run_chunks"]

_SAFE_LAYERS = ("omp", "tbb")
_IMPORTED_BY = os.getpid()
_TAIL_CHUNKS = 2
"""Chunks a thread, of the rays left in all, below which the chunks shrink (as in
:func:`rayaccel._jit.share_among_threads`)."""
_SHORTEST = 64
"""Fewest rays (rounded up to the walk's alignment) of a shrinking chunk."""
_ACTION_MARK = np.int16
"""The dtype of :func:`_flattened`'s marker for an :class:`.actions.Action` (Numba's ``int16``)."""
_LEAF = np.empty(0, dtype=np.int8)


@intrinsic
def _counter_value(typingctx, counter):
    """``counter[0]``, read with an atomic load (acquire)."""
    signature = types.int64(counter)

    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        return builder.load_atomic(data, "acquire", 8)

    return signature, codegen


@intrinsic
def _advance_counter(typingctx, counter, expected, new):
    """Set ``counter[0]`` to ``new`` if it still holds ``expected``, atomically (compare-and-exchange);
    whether it did."""
    signature = types.boolean(counter, expected, new)

    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        exchanged = builder.cmpxchg(data, args[1], args[2], "acq_rel", "acquire")
        return builder.extract_value(exchanged, 1)

    return signature, codegen


@intrinsic
def _call_compiled(typingctx, address, first, end, tid, leaves, layout):
    """The walk whose compiled code is at ``address`` on rays ``first`` to ``end - 1`` with scratch
    row ``tid``, its other arguments rebuilt from ``leaves`` as ``layout`` says
    (:func:`_flattened`): called with Numba's calling convention, as Numba calls a compiled
    function; what the walk returns, or 0 for a walk that returns nothing. The walks raise
    nothing; the status of the call is not read."""
    returns = types.int64 if layout.types[0].ndim == 1 else types.none
    walk_args = [types.int64] * 3
    groups = []
    taken = 0
    for marker in layout.types[1:]:
        count = 1 if marker.ndim == 1 else marker.ndim - 2
        items = tuple(leaves.types[taken:taken + count])
        if marker.ndim == 1:
            walk_args.append(items[0])
        elif marker.dtype == types.int16:
            walk_args.append(types.NamedTuple(items, Action))
        else:
            walk_args.append(types.Tuple(items))
        groups.append((marker.ndim > 1, taken, count))
        taken += count
    signature = types.int64(address, first, end, tid, leaves, layout)

    def codegen(context, builder, sig, args):
        call_conv = context.call_conv
        function_type = call_conv.get_function_type(returns, walk_args)
        function = builder.inttoptr(args[0], function_type.as_pointer())
        values = [context.cast(builder, args[k], sig.args[k], types.int64) for k in (1, 2, 3)]
        for (grouped, first_leaf, count), walk_arg in zip(groups, walk_args[3:]):
            items = [builder.extract_value(args[4], k) for k in range(first_leaf, first_leaf + count)]
            values.append(context.make_tuple(builder, walk_arg, items) if grouped else items[0])
        answer_type = call_conv.get_return_type(returns).pointee
        answer = cgutils.alloca_once(builder, answer_type)
        builder.store(ir.Constant(answer_type, None), answer)
        error = cgutils.alloca_once(builder, function_type.args[1].pointee)
        builder.call(function, [answer, error, *call_conv._get_arg_packer(walk_args).as_arguments(builder, values)])
        if returns == types.none:
            return ir.Constant(ir.IntType(64), 0)
        return builder.load(answer)

    return signature, codegen


@inline_kernel
def _next_chunk(counter, n, chunk, align, threads):
    """The next chunk ``(first, end)`` of the ``n`` rays, taken from ``counter`` by a
    compare-and-exchange: ``chunk`` rays, or, once fewer than :data:`_TAIL_CHUNKS` chunks a thread
    are left, half the rays left over the threads, rounded up to ``align`` and no fewer than
    :data:`_SHORTEST`; ``(n, n)`` when none is left."""
    shortest = -(-_SHORTEST // align) * align
    while True:
        first = _counter_value(counter)
        if first >= n:
            return n, n
        left = n - first
        size = chunk
        if left < _TAIL_CHUNKS * threads * chunk:
            size = min(chunk, max(shortest, -(-(left // (2 * threads)) // align) * align))
        end = min(first + size, n)
        if _advance_counter(counter, first, end):
            return first, end


@parallel_kernel
def _take_chunks(address, n, chunk, align, counter, threads, leaves, layout):
    """Every chunk of the ``n`` rays walked (:func:`_call_compiled`) by ``threads`` threads, each
    taking chunks (:func:`_next_chunk`) until none is left, with its own scratch row; the total of
    what the walk returned (summed a thread first: Numba's ``prange`` drops a sum taken inside the
    ``while`` loop, and returned 0)."""
    found = 0
    for _ in prange(threads):
        tid = numba.get_thread_id()
        mine = 0
        while True:
            first, end = _next_chunk(counter, n, chunk, align, threads)
            if first >= n:
                break
            mine += _call_compiled(address, first, end, tid, leaves, layout)
        found += mine
    return found


@parallel_kernel
def _start_threads(out):
    """A parallel kernel of no work, whose first run has Numba choose its threading layer."""
    for k in prange(out.shape[0]):
        out[k] = k


_entries = {}


def _type_key(value):
    """What Numba's type of a walk's argument depends on, cheaper to read than the type."""
    if isinstance(value, np.ndarray):
        flags = value.flags
        return value.dtype.str, value.ndim, flags.c_contiguous, flags.f_contiguous, flags.writeable, flags.aligned
    if isinstance(value, tuple):
        return (type(value), *(_type_key(item) for item in value))
    if isinstance(value, bool) or value is None:
        return type(value)
    if isinstance(value, int):
        return int, -(2 ** 63) <= value < 2 ** 63
    if isinstance(value, (float, np.generic)):
        return type(value)
    return numba.typeof(value)


def _marker(dtype, ndim: int) -> np.ndarray:
    """An empty array whose type tells :func:`_call_compiled` how to rebuild an argument."""
    return np.empty((0,) * ndim, dtype=dtype)


def _flattened(args: tuple) -> tuple[tuple, tuple] | None:
    """``args`` as a flat tuple of their items, and the layout that rebuilds them, one empty array
    an argument (:func:`_marker`): of one dimension for an argument given as it is, of ``2 + k``
    for a tuple of ``k`` items (of dtype :data:`_ACTION_MARK` for an :class:`.actions.Action`).
    Numba hands a ``prange`` body's tuples on as their items and refuses a tuple among them (the
    indexed layout's ``(vertices, faces)`` of a float64 mesh, :mod:`rayaccel.geometry.gather`), so
    the tuples go in flat. None for a deeper tuple or another kind of named tuple."""
    leaves, layout = [], []
    for value in args:
        if not isinstance(value, tuple):
            leaves.append(value)
            layout.append(_LEAF)
            continue
        if type(value) not in (tuple, Action) or any(isinstance(item, tuple) for item in value):
            return None
        leaves.extend(value)
        layout.append(_marker(_ACTION_MARK if type(value) is Action else np.int8, 2 + len(value)))
    return tuple(leaves), tuple(layout)


def _compiled_address(walk, args: tuple) -> tuple[int, np.ndarray]:
    """The address of ``walk``'s compiled code for ``args`` (after its ray range and thread row),
    compiled or loaded by a walk of no rays, and the first marker of :func:`_call_compiled`'s
    layout, which tells whether the walk returns an int64 or nothing; address 0 for a walk that
    returns something else."""
    key = (walk, tuple(_type_key(value) for value in args))
    entry = _entries.get(key)
    if entry is None:
        walk(0, 0, 0, *args)
        compiled = walk.overloads.get(tuple(walk.typeof_pyval(value) for value in (0, 0, 0, *args)))
        returns = compiled.signature.return_type if compiled is not None else None
        address = 0
        if returns in (types.int64, types.none):
            address = compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)
        entry = _entries[key] = address, _marker(np.uint8, 1 if returns == types.int64 else 2)
    return entry


def _threads_usable() -> bool:
    """Whether this process may run :func:`_take_chunks`: not a forked child of the one that
    imported rayaccel, with a threading layer safe from several Python threads."""
    if os.getpid() != _IMPORTED_BY:
        return False
    try:
        layer = numba.threading_layer()
    except ValueError:
        _start_threads(np.zeros(1, dtype=np.int64))
        layer = numba.threading_layer()
    return layer in _SAFE_LAYERS


def run_chunks(walk, n_rays: int, chunk: int, align: int, threads: int, args: tuple) -> int | None:
    """Walk rays 0 to ``n_rays - 1`` with ``walk`` (a :func:`rayaccel._jit.chunk_kernel` taking
    ``(ray_first, ray_end, tid, *args)``) on ``threads`` of Numba's threads in chunks of ``chunk``
    rays, a multiple of ``align``, the last ones shrinking (:func:`_next_chunk`); returns the total
    of what the walk returned, or None, having walked nothing, where this way is not taken (see
    the module docstring), for the caller to share the chunks among Python threads.

    Against the pool (:func:`rayaccel._jit.share_among_threads`), the same answers, time over time
    before, two threads, settled calls, medians of 9 (forest) and 7 (full dragon) in each process,
    processes alternating with the code before, three pairs and two, closest / any hit (2026-12-08,
    Intel host, two vCPUs): forest-small-chair's 1024^2 camera rays 0.92-0.97 / 0.86-0.92, its
    145,931 shadow rays 0.905-0.96 / 0.92-0.98, 2^20 incoherent rays 0.94-1.03 / 0.97-0.98; the
    full dragon's camera rays 0.95 / 0.93-0.98, shadow rays 0.97-0.985 / 0.96-1.00, incoherent
    0.96-0.99 / 0.975-0.98 (``bvh-binned``, the float32 lanes layout). In one process, this way and
    the pool in turn, medians of 10 (forest) and 8 (dragon) settled calls a way, forest camera rays
    0.955-0.968 / 0.885-0.987, shadow rays 0.910-0.930 / 0.927-0.938, incoherent 0.994-1.000 /
    0.982-1.033 over ``bvh-binned`` (both layouts), ``kdtree`` and ``grid-bvh``; the full dragon's
    0.968-0.994 / 0.947-0.990, 0.963-0.987 / 0.968-0.988 and 1.000-1.008 / 0.964-0.991."""
    if threads < 2 or not _threads_usable():
        return None
    flat = _flattened(args)
    if flat is None:
        return None
    address, returns = _compiled_address(walk, args)
    if not address:
        return None
    leaves, layout = flat
    counter = np.zeros(1, dtype=np.int64)
    return int(_take_chunks(address, n_rays, chunk, align, counter, threads, leaves, (returns, *layout)))
