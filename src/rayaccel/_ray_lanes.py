"""How kernels read a batch's rays: eight rays' coordinates in vector lanes, for the LLVM
intrinsics that handle rays side by side, and one ray's origin (:func:`origin_at`).

A C-contiguous (n, 3) ray array holds eight consecutive rays in 24 consecutive
numbers: three vector loads fetch them, and two shuffles put each axis of the
eight rays into one vector, one lane a ray. A batch's one shared origin (a (3,) array,
:func:`rayaccel.rays.prepare_rays` with ``shared_origin``) is read as three numbers, each
copied into every lane. The packet walks
(:mod:`rayaccel.structures.bvh.packet_slab`) and the walks' ray check
(:func:`rayaccel._validate.unusable_rays`) read rays this way; a loop over the
rays instead compiles to gathers, one per coordinate of eight rays.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["LANES", "rays_readable", "load_eight", "splat", "shared_by_lanes", "rays_by_axis", "origin_at"]

LANES = 8
"""Rays read at once, one per vector lane."""


def rays_readable(*arrays) -> bool:
    """Whether ray arrays (Numba types) are ones :func:`rays_by_axis` reads: C-contiguous float64 or
    float32, (n, 3) or a shared origin's (3,)."""
    return all(isinstance(a, types.Array) and a.layout == "C" and a.ndim in (1, 2)
               and a.dtype in (types.float64, types.float32) for a in arrays)


def load_eight(builder, array_type, pointer, count=LANES):
    """``count`` (eight unless given) consecutive numbers of a float64 or float32 array from
    ``pointer`` as a vector of float64 (float32 widened exactly, as :func:`rayaccel.rays.ray_at`
    widens them)."""
    doubles = ir.VectorType(ir.DoubleType(), count)
    if array_type.dtype == types.float64:
        return builder.load(builder.bitcast(pointer, doubles.as_pointer()), align=8)
    floats = ir.VectorType(ir.FloatType(), count)
    return builder.fpext(builder.load(builder.bitcast(pointer, floats.as_pointer()), align=4), doubles)


def splat(builder, value, vector_type):
    """The IR of a vector of ``vector_type`` with ``value`` in every lane."""
    vector = ir.Constant(vector_type, ir.Undefined)
    for lane in range(vector_type.count):
        vector = builder.insert_element(vector, value, ir.IntType(32)(lane))
    return vector


def shared_by_lanes(builder, array_type, pointer):
    """The float64 or float32 number at ``pointer`` as a vector of :data:`LANES` float64, each
    lane a copy (float32 widened exactly)."""
    value = builder.load(pointer)
    if array_type.dtype == types.float32:
        value = builder.fpext(value, ir.DoubleType())
    return splat(builder, value, ir.VectorType(ir.DoubleType(), LANES))


def rays_by_axis(context, builder, array_type, array, row, second=None):
    """The :data:`LANES` rows from ``row`` (an intp value) of an (n, 3) ray array that
    :func:`rays_readable` accepts, as three vectors of eight float64, x, y and z, one lane a ray:
    three loads of eight numbers, shuffled from rows to lanes. Given ``second`` (an intp value),
    lanes 4-7 take the four rows from ``second`` instead (a packet of two image rows,
    :mod:`rayaccel.ray_tiles`): each four rows' twelve numbers loaded as eight and four, then
    shuffled alike. A (3,) array, one origin for every ray, gives its x, y and z in every lane."""
    intp = context.get_value_type(types.intp)
    data = context.make_array(array_type)(context, builder, array).data
    if array_type.ndim == 1:
        return [shared_by_lanes(builder, array_type, builder.gep(data, [ir.Constant(intp, axis)]))
                for axis in range(3)]
    to_lanes = [[3 * lane + axis for lane in range(LANES)] for axis in range(3)]
    sixteen = ir.Constant(ir.VectorType(ir.IntType(32), 2 * LANES), list(range(2 * LANES)))
    if second is None:
        start = builder.gep(data, [builder.mul(row, ir.Constant(intp, 3))])
        parts = [load_eight(builder, array_type, builder.gep(start, [ir.Constant(intp, LANES * k)])) for k in range(3)]
        low = builder.shuffle_vector(parts[0], parts[1], sixteen)
        high = builder.shuffle_vector(parts[2], parts[2], sixteen)
    else:
        half = LANES // 2
        halves = []
        for first in (row, second):
            start = builder.gep(data, [builder.mul(first, ir.Constant(intp, 3))])
            four = load_eight(builder, array_type, builder.gep(start, [ir.Constant(intp, LANES)]), half)
            widened = builder.shuffle_vector(four, four, ir.Constant(ir.VectorType(ir.IntType(32), LANES),
                                                                     list(range(half)) + [half] * half))
            halves.append(builder.shuffle_vector(load_eight(builder, array_type, start), widened, sixteen))
        low, high = halves
        numbers = 3 * half
        to_lanes = [[k if k < numbers else k - numbers + 2 * LANES for k in lanes] for lanes in to_lanes]
    return [builder.shuffle_vector(low, high, ir.Constant(ir.VectorType(ir.IntType(32), LANES), lanes))
            for lanes in to_lanes]


@intrinsic
def origin_at(typingctx, origins, i):
    """Ray ``i``'s origin as three float64 numbers (inside kernels): row ``i`` of (n, 3)
    ``origins``, or the one origin of a (3,) array every ray shares
    (:class:`rayaccel.rays.RayBatch`), float32 widened exactly: three loads, as Numba's indexing
    makes them, picked by the array's type when the kernel is typed. Written as an ``overload``
    inlined at Numba's IR level instead, it was typed again at each of the walks' many calls of
    :func:`rayaccel.rays.ray_at`: ``tests/test_bvh.py`` on an empty cache ended at 6.0 GB of
    memory against 0.9 GB, and the whole suite was killed at 24 GB."""
    if not (isinstance(origins, types.Array) and origins.dtype in (types.float64, types.float32)
            and (origins.ndim == 2 or rays_readable(origins)) and isinstance(i, types.Integer)):
        return None
    signature = types.UniTuple(types.float64, 3)(origins, i)

    def codegen(context, builder, sig, args):
        array_type = sig.args[0]
        array = context.make_array(array_type)(context, builder, args[0])
        intp = context.get_value_type(types.intp)
        row = context.cast(builder, args[1], sig.args[1], types.intp)
        values = []
        for axis in range(3):
            if array_type.ndim == 2:
                pointer = cgutils.get_item_pointer(context, builder, array_type, array, [row, ir.Constant(intp, axis)])
            else:
                pointer = builder.gep(array.data, [ir.Constant(intp, axis)])
            value = builder.load(pointer)
            values.append(builder.fpext(value, ir.DoubleType()) if array_type.dtype == types.float32 else value)
        return context.make_tuple(builder, sig.return_type, values)

    return signature, codegen
