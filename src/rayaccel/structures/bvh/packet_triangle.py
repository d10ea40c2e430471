"""The edge test of one triangle against every ray of a packet at once, in vector instructions.

A camera packet's rays enter the same leaves, and the packet walk tested each of their
triangles ray after ray. This test runs the first half of the watertight triangle test
(Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection", JCGT 2(1), 2013, as
:func:`rayaccel.geometry.triangle.intersect_triangle` computes it: the corners relative to
the ray's origin, sheared so that the ray runs along +z, and the three edge functions) on
the eight rays in the vector lanes, as packet tracers do (Wald, Slusallek, Benthin & Wagner,
"Interactive Rendering with Coherent Ray Tracing", Eurographics 2001). It asks that the
packet's rays share the triangle test's axes ``kx, ky, kz``, so that one load of each corner
coordinate serves every lane. Each lane computes what the single-ray test computes for its
ray, operation for operation in float64 (no fused multiply-add: LLVM contracts nothing
that is not marked for it), so a lane it reports outside the edges is one the single-ray
test would reject there too; the few lanes inside are finished by the single-ray test.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from .packet_slab import PACKET

__all__ = ["SHEAR_ROW", "SHEAR_ROWS", "inside_edges_by_lane"]

SHEAR_ROW = 10
"""The first of the rows of a packet's ray state that :func:`inside_edges_by_lane` reads: each
ray's shear ``sx``, ``sy`` and its origin on the axes ``kx``, ``ky``, ``kz``; then ``sz``."""
SHEAR_ROWS = 6


@intrinsic
def inside_edges_by_lane(typingctx, state, lanes, ax, ay, az, bx, by, bz, cx, cy, cz):
    """The lanes of ``lanes`` (bit ``r`` for lane ``r``) whose ray passes inside the edges of the
    triangle with corners ``a``, ``b``, ``c`` given on the packet's axes (``ax`` is corner a's
    coordinate on axis ``kx``, ``az`` on ``kz``): the edge functions not of both signs, as
    :func:`rayaccel.geometry.triangle.intersect_triangle` decides it; ``state`` holds the rays'
    constants from row :data:`SHEAR_ROW` on (rows of :data:`PACKET` float64)."""
    signature = types.int64(state, lanes, ax, ay, az, bx, by, bz, cx, cy, cz)

    def codegen(context, builder, sig, args):
        state_array, lane_bits = args[0], args[1]
        intp = context.get_value_type(types.intp)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        data = builder.bitcast(context.make_array(sig.args[0])(context, builder, state_array).data,
                               doubles.as_pointer())
        sx, sy, okx, oky, okz = (builder.load(builder.gep(data, [ir.Constant(intp, SHEAR_ROW + k)]), align=8)
                                 for k in range(5))

        def splat(value):
            vector = ir.Constant(doubles, ir.Undefined)
            for lane in range(PACKET):
                vector = builder.insert_element(vector, value, ir.IntType(32)(lane))
            return vector

        a_x, a_y, a_z, b_x, b_y, b_z, c_x, c_y, c_z = (splat(value) for value in args[2:])
        az_ = builder.fsub(a_z, okz)
        bz_ = builder.fsub(b_z, okz)
        cz_ = builder.fsub(c_z, okz)
        ax_ = builder.fsub(builder.fsub(a_x, okx), builder.fmul(sx, az_))
        ay_ = builder.fsub(builder.fsub(a_y, oky), builder.fmul(sy, az_))
        bx_ = builder.fsub(builder.fsub(b_x, okx), builder.fmul(sx, bz_))
        by_ = builder.fsub(builder.fsub(b_y, oky), builder.fmul(sy, bz_))
        cx_ = builder.fsub(builder.fsub(c_x, okx), builder.fmul(sx, cz_))
        cy_ = builder.fsub(builder.fsub(c_y, oky), builder.fmul(sy, cz_))
        e0 = builder.fsub(builder.fmul(cx_, by_), builder.fmul(cy_, bx_))
        e1 = builder.fsub(builder.fmul(ax_, cy_), builder.fmul(ay_, cx_))
        e2 = builder.fsub(builder.fmul(bx_, ay_), builder.fmul(by_, ax_))
        zero = ir.Constant(doubles, [0.0] * PACKET)
        negative = builder.or_(builder.or_(builder.fcmp_ordered("<", e0, zero), builder.fcmp_ordered("<", e1, zero)),
                               builder.fcmp_ordered("<", e2, zero))
        positive = builder.or_(builder.or_(builder.fcmp_ordered(">", e0, zero), builder.fcmp_ordered(">", e1, zero)),
                               builder.fcmp_ordered(">", e2, zero))
        inside = builder.not_(builder.and_(negative, positive))
        mask = builder.zext(builder.bitcast(inside, ir.IntType(PACKET)), ir.IntType(64))
        return builder.and_(mask, context.cast(builder, lane_bits, sig.args[1], types.int64))

    return signature, codegen
