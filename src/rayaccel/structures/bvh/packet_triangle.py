"""The watertight test of one triangle against every ray of a packet at once, in vector instructions.

A camera packet's rays enter the same leaves, and the packet walk tested each of their
triangles ray after ray. This test runs the watertight triangle test (Woop, Benthin & Wald,
"Watertight Ray/Triangle Intersection", JCGT 2(1), 2013, as
:func:`rayaccel.geometry.triangle.intersect_triangle` computes it: the corners relative to
the ray's origin, sheared so that the ray runs along +z, the three edge functions, then the
determinant, the distance and the barycentrics) on the eight rays in the vector lanes, as
packet tracers do (Wald, Slusallek, Benthin & Wagner, "Interactive Rendering with Coherent
Ray Tracing", Eurographics 2001). It asks that the packet's rays share the triangle test's
axes ``kx, ky, kz``, so that one load of each corner coordinate serves every lane. Each lane
computes what the single-ray test computes for its ray, operation for operation in float64
(no fused multiply-add: LLVM contracts nothing that is not marked for it), so each lane's
verdict, distance and barycentrics are the single-ray test's, to the bit.

The second half (determinant, distance, barycentrics: three divisions) runs only when some
lane passes inside the edges. It used to be left to the single-ray test, lane after lane,
for the lanes inside: those calls took 11-12 % of the forest's camera-ray walk (one thread,
CPU time, the walk timed with each call made twice).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ...geometry.triangle import DEGENERATE
from .packet_slab import PACKET, PACKET_ROWS

__all__ = ["SHEAR_ROW", "SHEAR_ROWS", "HIT_ROW", "HIT_ROWS", "hits_by_lane"]

SHEAR_ROW = 10
"""The first of the rows of a packet's ray state that :func:`hits_by_lane` reads: each
ray's shear ``sx``, ``sy`` and its origin on the axes ``kx``, ``ky``, ``kz``; then ``sz``."""
SHEAR_ROWS = 6
HIT_ROW = SHEAR_ROW + SHEAR_ROWS
"""The first of the rows :func:`hits_by_lane` writes: each lane's distance ``t``, then ``u``
and ``v``, on the triangle it tested."""
HIT_ROWS = 3
_T_MIN_ROW, _BEST_ROW = PACKET_ROWS - 2, PACKET_ROWS - 1


@intrinsic
def hits_by_lane(typingctx, state, lanes, ax, ay, az, bx, by, bz, cx, cy, cz):
    """The lanes of ``lanes`` (bit ``r`` for lane ``r``) whose ray hits the triangle with corners
    ``a``, ``b``, ``c`` given on the packet's axes (``ax`` is corner a's coordinate on axis
    ``kx``, ``az`` on ``kz``) between its ``t_min`` and its best distance so far, as
    :func:`rayaccel.geometry.triangle.intersect_triangle` decides it; their ``t``, ``u`` and
    ``v`` go to the rows from :data:`HIT_ROW` on. ``state`` holds the rays' limits (rows
    ``PACKET_ROWS - 2`` and ``- 1``) and their constants from row :data:`SHEAR_ROW` on, rows of
    :data:`PACKET` float64."""
    signature = types.int64(state, lanes, ax, ay, az, bx, by, bz, cx, cy, cz)

    def codegen(context, builder, sig, args):
        state_array, lane_bits = args[0], args[1]
        intp = context.get_value_type(types.intp)
        int64 = ir.IntType(64)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        data = builder.bitcast(context.make_array(sig.args[0])(context, builder, state_array).data,
                               doubles.as_pointer())

        def row(k):
            return builder.gep(data, [ir.Constant(intp, k)])

        sx, sy, okx, oky, okz, sz = (builder.load(row(SHEAR_ROW + k), align=8) for k in range(SHEAR_ROWS))

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
        products = (builder.fmul(cx_, by_), builder.fmul(cy_, bx_), builder.fmul(ax_, cy_), builder.fmul(ay_, cx_),
                    builder.fmul(bx_, ay_), builder.fmul(by_, ax_))
        e0 = builder.fsub(products[0], products[1])
        e1 = builder.fsub(products[2], products[3])
        e2 = builder.fsub(products[4], products[5])
        zero = ir.Constant(doubles, [0.0] * PACKET)
        negative = builder.or_(builder.or_(builder.fcmp_ordered("<", e0, zero), builder.fcmp_ordered("<", e1, zero)),
                               builder.fcmp_ordered("<", e2, zero))
        positive = builder.or_(builder.or_(builder.fcmp_ordered(">", e0, zero), builder.fcmp_ordered(">", e1, zero)),
                               builder.fcmp_ordered(">", e2, zero))
        inside = builder.not_(builder.and_(negative, positive))
        live = context.cast(builder, lane_bits, sig.args[1], types.int64)
        inside_lanes = builder.and_(builder.zext(builder.bitcast(inside, ir.IntType(PACKET)), int64), live)
        entry = builder.block
        with builder.if_then(builder.icmp_unsigned("!=", inside_lanes, int64(0)), likely=False):
            fabs = cgutils.get_or_insert_function(builder.module, ir.FunctionType(doubles, [doubles]),
                                                  f"llvm.fabs.v{PACKET}f64")
            det = builder.fadd(builder.fadd(e0, e1), e2)
            size = builder.call(fabs, [products[0]])
            for product in products[1:]:
                size = builder.fadd(size, builder.call(fabs, [product]))
            degenerate_limit = builder.fmul(ir.Constant(doubles, [DEGENERATE] * PACKET), size)
            proper = builder.fcmp_unordered(">", builder.call(fabs, [det]), degenerate_limit)
            depth = builder.fadd(builder.fadd(builder.fmul(e0, az_), builder.fmul(e1, bz_)), builder.fmul(e2, cz_))
            t = builder.fdiv(builder.fmul(sz, depth), det)
            in_range = builder.and_(builder.fcmp_ordered(">=", t, builder.load(row(_T_MIN_ROW), align=8)),
                                    builder.fcmp_ordered("<=", t, builder.load(row(_BEST_ROW), align=8)))
            builder.store(t, row(HIT_ROW), align=8)
            builder.store(builder.fdiv(e1, det), row(HIT_ROW + 1), align=8)
            builder.store(builder.fdiv(e2, det), row(HIT_ROW + 2), align=8)
            hit = builder.and_(builder.and_(inside, proper), in_range)
            hit_lanes = builder.and_(builder.zext(builder.bitcast(hit, ir.IntType(PACKET)), int64), live)
            tested = builder.block
        result = builder.phi(int64)
        result.add_incoming(int64(0), entry)
        result.add_incoming(hit_lanes, tested)
        return result

    return signature, codegen
