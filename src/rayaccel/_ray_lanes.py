"""Eight rays' coordinates in vector lanes, for the LLVM intrinsics that handle rays side by side.

A C-contiguous (n, 3) ray array holds eight consecutive rays in 24 consecutive
numbers: three vector loads fetch them, and two shuffles put each axis of the
eight rays into one vector, one lane a ray. The packet walks
(:mod:`rayaccel.structures.bvh.packet_slab`) and the walks' ray check
(:func:`rayaccel._validate.unusable_rays`) read rays this way; a loop over the
rays instead compiles to gathers, one per coordinate of eight rays.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types

__all__ = ["LANES", "rays_readable", "load_eight", "rays_by_axis"]

LANES = 8
"""Rays read at once, one per vector lane."""


def rays_readable(*arrays) -> bool:
    """Whether ray arrays (Numba types) are ones :func:`load_eight` reads: C-contiguous float64 or float32."""
    return all(isinstance(a, types.Array) and a.layout == "C" and a.dtype in (types.float64, types.float32)
               for a in arrays)


def load_eight(builder, array_type, pointer, count=LANES):
    """``count`` (eight unless given) consecutive numbers of a float64 or float32 array from
    ``pointer`` as a vector of float64 (float32 widened exactly, as :func:`rayaccel.rays.ray_at`
    widens them)."""
    doubles = ir.VectorType(ir.DoubleType(), count)
    if array_type.dtype == types.float64:
        return builder.load(builder.bitcast(pointer, doubles.as_pointer()), align=8)
    floats = ir.VectorType(ir.FloatType(), count)
    return builder.fpext(builder.load(builder.bitcast(pointer, floats.as_pointer()), align=4), doubles)


def rays_by_axis(context, builder, array_type, array, row, second=None):
    """The :data:`LANES` rows from ``row`` (an intp value) of an (n, 3) ray array that
    :func:`rays_readable` accepts, as three vectors of eight float64, x, y and z, one lane a ray:
    three loads of eight numbers, shuffled from rows to lanes. Given ``second`` (an intp value),
    lanes 4-7 take the four rows from ``second`` instead (a packet of two image rows,
    :mod:`rayaccel.ray_tiles`): each four rows' twelve numbers loaded as eight and four, then
    shuffled alike."""
    intp = context.get_value_type(types.intp)
    data = context.make_array(array_type)(context, builder, array).data
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
