"""Slab test of a wide node's four child boxes at once, in LLVM vector instructions.

The slab test is Kay & Kajiya's ("Ray Tracing Complex Scenes", SIGGRAPH
1986), with the near face of each axis chosen once per ray (pbrt's
``dirIsNeg``) and NaN-safe bounds (:func:`.traverse.tighten`): a NaN from
``0 * inf`` (an origin on a slab plane, a zero direction component) never
replaces the running entry or exit distance.

A wide record stores each box component for its four children side by side
(:mod:`.wide`), so one 16-byte load fetches, say, ``lo_x`` of all four. Written
as scalar code, Numba leaves the four children's tests scalar: LLVM's SLP
vectoriser, which would merge them, is off in Numba by default
(``NUMBA_SLP_VECTORIZE=0``), and a library must not switch it on for its
users' code. :func:`enter_children` therefore emits the vector IR itself: per
axis, two loads of four float32 components, widened to four float64 lanes,
then subtract, multiply and select on all four children at once (on AVX2, as
``inspect_asm()`` shows: ``vcvtps2pd``, ``vsubpd``, ``vmulpd``, ``vmaxpd`` and
``vminpd`` on ``ymm`` registers, and one ``vblendvpd`` for the misses). The
arithmetic is exactly the scalar test's, lane by lane, in float64, so it culls
exactly the same nodes.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["enter_children"]

_LANES = 4


@intrinsic
def enter_children(typingctx, records, node, near_x, near_y, near_z, origin, inv_dir, t_min, t_max):
    """``(t0, t1, t2, t3)``: the distance at which the ray enters each child box of wide
    ``node`` within ``[t_min, t_max]``, ``inf`` where it misses. ``records`` is the
    (n, 32) float32 wide layout, ``near_*`` the column block (0-5) of each axis's
    near face, ``origin`` and ``inv_dir`` float64 triples."""
    signature = types.UniTuple(types.float64, _LANES)(records, node, near_x, near_y, near_z, origin, inv_dir, t_min,
                                                      t_max)

    def codegen(context, builder, sig, args):
        records_type = sig.args[0]
        array, node_index, *nears, origin_value, inv_value, enter_limit, exit_limit = args
        view = context.make_array(records_type)(context, builder, array)
        row = cgutils.get_item_pointer(context, builder, records_type, view,
                                       [context.cast(builder, node_index, sig.args[1], types.intp),
                                        context.get_constant(types.intp, 0)])
        floats = ir.VectorType(ir.FloatType(), _LANES)
        doubles = ir.VectorType(ir.DoubleType(), _LANES)
        intp = context.get_value_type(types.intp)

        def splat(value):
            vector = ir.Constant(doubles, ir.Undefined)
            for lane in range(_LANES):
                vector = builder.insert_element(vector, value, ir.IntType(32)(lane))
            return vector

        def component(block):
            pointer = builder.gep(row, [builder.mul(block, ir.Constant(intp, _LANES))])
            return builder.fpext(builder.load(builder.bitcast(pointer, floats.as_pointer()), align=16), doubles)

        enter = splat(enter_limit)
        exit_ = splat(exit_limit)
        for axis in range(3):
            o = splat(builder.extract_value(origin_value, axis))
            inv = splat(builder.extract_value(inv_value, axis))
            near_block = context.cast(builder, nears[axis], sig.args[2 + axis], types.intp)
            far_block = builder.sub(ir.Constant(intp, 2 * axis + 3), near_block)
            near = builder.fmul(builder.fsub(component(near_block), o), inv)
            far = builder.fmul(builder.fsub(component(far_block), o), inv)
            enter = builder.select(builder.fcmp_ordered(">", near, enter), near, enter)
            exit_ = builder.select(builder.fcmp_ordered("<", far, exit_), far, exit_)
        missed = ir.Constant(doubles, [float("inf")] * _LANES)
        entry = builder.select(builder.fcmp_ordered("<=", enter, exit_), enter, missed)
        lanes = [builder.extract_element(entry, ir.IntType(32)(lane)) for lane in range(_LANES)]
        return context.make_tuple(builder, sig.return_type, lanes)

    return signature, codegen
