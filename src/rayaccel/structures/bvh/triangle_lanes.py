"""The edge test of the watertight ray-triangle intersection on four triangles at once.

Most triangles a ray reaches in a BVH's leaves it misses, and the edge
functions of Woop, Benthin & Wald's test (:mod:`rayaccel.geometry.triangle`) are what tell
(forest-small-chair, incoherent rays: 0.68 of 4.17 triangles tested a ray get
past them). :func:`edges_admit` computes them for the four triangles of a
group of the lanes layout (:mod:`rayaccel.geometry.gather`) in vector instructions, as Embree
tests the four triangles of its ``Triangle4`` leaves together (Wald et al.,
"Embree: A Kernel Framework for Efficient CPU Ray Tracing", ACM TOG 33(4),
2014): each of the nine coordinates the test reads is one load of four float32
numbers, widened to four float64 lanes. The few triangles it admits are then
tested one by one in full (:func:`rayaccel.geometry.triangle.intersect_triangle`).

Each lane computes exactly the scalar test's float64 operations, in its order
and without fused multiply-adds (no ``contract`` flag), so a lane rejects a
triangle exactly when the scalar test would: the hits are bit for bit those of
testing every triangle in full. Filling the lanes from rows of nine floats
instead, a load for each coordinate of each triangle, cost more than the
lanes saved (README, "Tried and dropped").
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..._ray_lanes import splat
from ...geometry.gather import LANES, is_lanes_type, lane_pointer

__all__ = ["edges_admit"]


@intrinsic
def edges_admit(typingctx, lanes, group, kx, ky, kz, okx, oky, okz, sx, sy):
    """The mask (bit ``j`` for lane ``j``) of the triangles of group ``group`` of the lanes
    layout ``lanes`` whose edge functions do not put the ray outside: the sign test of
    :func:`rayaccel.geometry.triangle.intersect_triangle`, with the ray given as there by its shear's axes
    ``kx, ky, kz``, the origin's coordinates ``okx, oky, okz`` on them and the shear ``sx,
    sy``. A triangle it leaves out the full test would miss; one it admits may still be
    degenerate, or hit outside the ray's interval. Given another layout, in the branch of a
    walk that its constant :func:`rayaccel.geometry.gather.is_lanes` never runs, it admits all."""
    signature = types.int64(lanes, group, kx, ky, kz, okx, oky, okz, sx, sy)

    def codegen(context, builder, sig, args):
        int64 = ir.IntType(64)
        if not is_lanes_type(sig.args[0]):
            return int64((1 << LANES) - 1)
        group_value = context.cast(builder, args[1], sig.args[1], types.int64)
        axes = [context.cast(builder, value, sig.args[2 + i], types.int64) for i, value in enumerate(args[2:5])]
        floats = ir.VectorType(ir.FloatType(), LANES)
        doubles = ir.VectorType(ir.DoubleType(), LANES)
        origin_x, origin_y, origin_z, shear_x, shear_y = (
            splat(builder, context.cast(builder, value, sig.args[5 + i], types.float64), doubles)
            for i, value in enumerate(args[5:]))

        def coordinate(j, axis):
            row = builder.add(axis, int64(3 * j))
            pointer = lane_pointer(context, builder, sig.args[0], args[0], group_value, row)
            return builder.fpext(builder.load(builder.bitcast(pointer, floats.as_pointer()), align=4), doubles)

        sheared = []
        for j in range(3):
            z = builder.fsub(coordinate(j, axes[2]), origin_z)
            x = builder.fsub(builder.fsub(coordinate(j, axes[0]), origin_x), builder.fmul(shear_x, z))
            y = builder.fsub(builder.fsub(coordinate(j, axes[1]), origin_y), builder.fmul(shear_y, z))
            sheared.append((x, y))
        (ax, ay), (bx, by), (cx, cy) = sheared
        edges = [builder.fsub(builder.fmul(px, qy), builder.fmul(py, qx))
                 for (px, py), (qx, qy) in (((cx, cy), (bx, by)), ((ax, ay), (cx, cy)), ((bx, by), (ax, ay)))]
        zero = ir.Constant(doubles, [0.0] * LANES)
        below = [builder.fcmp_ordered("<", e, zero) for e in edges]
        above = [builder.fcmp_ordered(">", e, zero) for e in edges]
        outside = builder.and_(builder.or_(builder.or_(below[0], below[1]), below[2]),
                               builder.or_(builder.or_(above[0], above[1]), above[2]))
        return builder.zext(builder.bitcast(builder.not_(outside), ir.IntType(LANES)), int64)

    return signature, codegen

