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
3.44-3.56 to 3.05-3.19 ms (:func:`run_chunks`).

The kernel calls the walk through the address of its compiled code (:func:`_call_compiled`),
not by name: called by name, the walk's code is linked into the kernel's and optimised by LLVM
once more, which took 2.8-2.9 s for each walk on a cache that had the walk already; through its
address, the kernel compiles in 0.8-1.0 s, once for each signature of the walks' arguments (a
camera's rays with their one origin, rays with origins of their own, ...), and Numba's cache
keeps it.

Taken only where it is safe, else the pool runs the pass: a threading layer that takes parallel
kernels from several Python threads at once (``omp``, ``tbb``; ``workqueue`` aborts the process),
in the process that imported rayaccel (GNU OpenMP aborts a forked child that uses it after its
parent did), and for walks that return a count (their unusable rays), take an
:class:`.actions.Action` and no other tuple: Numba hands a ``prange`` body's tuples on as their
items, and refuses a tuple among them (the indexed layout's ``(vertices, faces)`` of a float64
mesh, :mod:`rayaccel.geometry.gather`), so such walks stay on the pool.
"""

from __future__ import annotations

import os

import numba
import numpy as np
from llvmlite import ir
from numba import prange, types
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
    """Set ``counter[0]`` to ``new`` if it still holds ``expected``, atomically; whether it did."""
    signature = types.boolean(counter, expected, new)

    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        exchanged = builder.cmpxchg(data, args[1], args[2], "acq_rel", "acquire")
        return builder.extract_value(exchanged, 1)

    return signature, codegen


@intrinsic
def _call_compiled(typingctx, address, first, end, tid, head, action_fields, tail):
    """The walk whose compiled code is at ``address`` on rays ``first`` to ``end - 1`` with scratch
    row ``tid``, its other arguments ``head``, then the :class:`.actions.Action` of the fields
    ``action_fields``, then ``tail``: called with Numba's calling convention, as Numba calls a
    compiled function, its answer the walk's int64. The walks raise nothing; the status of the
    call is not read."""
    action = types.NamedTuple(tuple(action_fields.types), Action)
    walk_args = (types.int64,) * 3 + tuple(head.types) + (action,) + tuple(tail.types)
    signature = types.int64(address, first, end, tid, head, action_fields, tail)

    def codegen(context, builder, sig, args):
        call_conv = context.call_conv
        function_type = call_conv.get_function_type(types.int64, walk_args)
        function = builder.inttoptr(args[0], function_type.as_pointer())
        values = [context.cast(builder, args[k], sig.args[k], types.int64) for k in (1, 2, 3)]
        values += [builder.extract_value(args[4], k) for k in range(len(head.types))]
        values.append(context.make_tuple(builder, action, [builder.extract_value(args[5], k)
                                                           for k in range(len(action_fields.types))]))
        values += [builder.extract_value(args[6], k) for k in range(len(tail.types))]
        answer_type = call_conv.get_return_type(types.int64).pointee
        answer = builder.alloca(answer_type)
        builder.store(ir.Constant(answer_type, None), answer)
        error = builder.alloca(function_type.args[1].pointee)
        builder.call(function, [answer, error, *call_conv._get_arg_packer(walk_args).as_arguments(builder, values)])
        return builder.load(answer)

    return signature, codegen


@inline_kernel
def _next_chunk(counter, n, chunk, align, threads):
    """The next chunk ``(first, end)`` of the ``n`` rays, taken from ``counter``: ``chunk`` rays, or,
    once fewer than :data:`_TAIL_CHUNKS` chunks a thread are left, half the rays left over the
    threads, rounded up to ``align`` and no fewer than :data:`_SHORTEST`; ``(n, n)`` when none is
    left."""
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
def _take_chunks(address, n, chunk, align, counter, threads, head, action_fields, tail):
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
            mine += _call_compiled(address, first, end, tid, head, action_fields, tail)
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


def _compiled_address(walk, args: tuple) -> int:
    """The address of ``walk``'s compiled code for ``args`` (after its ray range and thread row),
    compiled or loaded by a walk of no rays; 0 for a walk that does not return an int64."""
    key = (walk, tuple(_type_key(value) for value in args))
    address = _entries.get(key)
    if address is None:
        walk(0, 0, 0, *args)
        compiled = walk.overloads.get(tuple(walk.typeof_pyval(value) for value in (0, 0, 0, *args)))
        address = 0
        if compiled is not None and compiled.signature.return_type == types.int64:
            address = compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)
        _entries[key] = address
    return address


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
    0.96-0.99 / 0.975-0.98. Incoherent rays lose the pool's parts of a thread's own
    (:func:`rayaccel._jit.share_among_threads`, 1.6-3.6 % of their work) and gain its hand-overs."""
    positions = [k for k, value in enumerate(args) if isinstance(value, Action)]
    if threads < 2 or len(positions) != 1 or any(type(value) is tuple for value in args) or not _threads_usable():
        return None
    address = _compiled_address(walk, args)
    if not address:
        return None
    k = positions[0]
    counter = np.zeros(1, dtype=np.int64)
    return int(_take_chunks(address, n_rays, chunk, align, counter, threads, args[:k], tuple(args[k]),
                            args[k + 1:]))
