"""The watertight test of one triangle against every ray of a packet at once, in vector instructions,
and the set-up of the rays' constants it reads.

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
CPU time, the walk timed with each call made twice). Of its divisions, the barycentrics' two
run only when some lane hits, which a ray crossing the triangle's plane behind its best hit or
before its ``t_min`` (a shadow ray's own surface) does not (2026-12-08, one thread, settled
calls, medians of 9, processes alternating with the code before, time over time before, three
pairs: forest camera rays 0.98-1.01 closest / 0.975-1.03 any hit, shadow rays 0.975-0.99 /
0.967-0.99; full dragon 0.955-1.02 / 0.97-1.02, shadow 0.96-1.03; the same answers).

The corners of a float32 mesh (the lanes layout, :func:`rayaccel.geometry.gather.stored_corner`)
come in as stored and are spread over the lanes before they are widened, which the processor does
in one instruction a coordinate (a conversion with a broadcast from memory) where widening first
took three; :func:`.packet_slab.enter_child_lanes` reads a leaf's box so. Against the code before,
the same answers, settled calls, medians of 9, processes alternating (2026-12-07, Intel host with
AVX-512), time over time before: one thread, forest camera rays closest 0.96-1.01 / any hit
0.97-1.01, shadow rays 0.92-1.01 / 0.95-1.04 (six pairs); full dragon camera 0.94-0.98 /
0.93-0.97, shadow 0.93-1.02 / 0.95-1.02 (three); two threads on the forest within the noise (0.95-1.04).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..._ray_lanes import rays_by_axis, rays_readable, splat
from ...geometry.triangle import DEGENERATE
from .packet_slab import PACKET, PACKET_ROWS
from .wide_slab import float_intrinsic

__all__ = ["SHEAR_ROW", "SHEAR_ROWS", "HIT_ROW", "HIT_ROWS", "NOT_SHARED", "set_up_shear", "hits_by_lane"]

SHEAR_ROW = 10
"""The first of the rows of a packet's ray state that :func:`hits_by_lane` reads: each
ray's shear ``sx``, ``sy`` and its origin on the axes ``kx``, ``ky``, ``kz``; then ``sz``."""
SHEAR_ROWS = 6
HIT_ROW = SHEAR_ROW + SHEAR_ROWS
"""The first of the rows :func:`hits_by_lane` writes: each lane's distance ``t``, then ``u``
and ``v``, on the triangle it tested."""
HIT_ROWS = 3
_T_MIN_ROW, _BEST_ROW = PACKET_ROWS - 2, PACKET_ROWS - 1
NOT_SHARED = -1
"""What :func:`set_up_shear` returns for rays whose triangle-test axes differ."""


def _pick(builder, axis, vectors):
    """``vectors[axis]`` for an ``axis`` (0, 1 or 2) known only when the code runs."""
    int64 = ir.IntType(64)
    return builder.select(builder.icmp_signed("==", axis, int64(0)), vectors[0],
                          builder.select(builder.icmp_signed("==", axis, int64(1)), vectors[1], vectors[2]))


@intrinsic
def set_up_shear(typingctx, origins, directions, first, second, state):
    """The triangle test's constants (:func:`rayaccel.geometry.primitive.ray_setup`) of the
    :data:`PACKET` rays of rows ``first`` to ``first + 3`` and ``second`` to ``second + 3`` (as
    :func:`.packet_slab.load_packet` takes them) of ``origins`` and ``directions``, in vector
    instructions, written into ``state`` from row :data:`SHEAR_ROW` on as
    :func:`hits_by_lane` reads them: each ray's shear ``sx``, ``sy``, its origin on the axes
    ``kx``, ``ky``, ``kz``, then ``sz``. The axes are those of
    :func:`rayaccel.geometry.triangle.shear_setup` (``kz`` the dominant axis of the direction,
    ``kx`` and ``ky`` swapped where it points down ``kz``), and each lane computes its constants
    as the scalar set-up does, so to the bit. Returns ``kx + 4 ky + 16 kz`` when every ray has
    the same axes, else :data:`NOT_SHARED`. The set-up ray after ray that it replaces took 77 ns
    a packet of the forest's camera rays; against it, one thread, CPU time, forest camera and
    shadow rays 1.03-1.10 times as fast, the full dragon's 0.99-1.04."""
    if not rays_readable(origins, directions):
        return None
    signature = types.int64(origins, directions, first, second, state)

    def codegen(context, builder, sig, args):
        origin_array, direction_array, first_row, second_row, state_array = args
        intp = context.get_value_type(types.intp)
        int64 = ir.IntType(64)
        mask_type = ir.IntType(PACKET)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        row = context.cast(builder, first_row, sig.args[2], types.intp)
        second_row = context.cast(builder, second_row, sig.args[3], types.intp)
        origin = rays_by_axis(context, builder, sig.args[0], origin_array, row, second_row)
        direction = rays_by_axis(context, builder, sig.args[1], direction_array, row, second_row)
        ax, ay, az = (float_intrinsic(builder, "fabs", d) for d in direction)
        x_major = builder.and_(builder.fcmp_ordered(">=", ax, ay), builder.fcmp_ordered(">=", ax, az))
        y_major = builder.and_(builder.not_(x_major), builder.fcmp_ordered(">=", ay, az))

        def every_lane(condition):
            return builder.icmp_unsigned("==", builder.bitcast(condition, mask_type), mask_type(-1))

        def no_lane(condition):
            return builder.icmp_unsigned("==", builder.bitcast(condition, mask_type), mask_type(0))

        all_x, all_y = every_lane(x_major), every_lane(y_major)
        all_z = builder.and_(no_lane(x_major), no_lane(y_major))
        kz = builder.select(all_x, int64(0), builder.select(all_y, int64(1), int64(2)))
        kx_up = builder.select(builder.icmp_signed("<", kz, int64(2)), builder.add(kz, int64(1)), int64(0))
        ky_up = builder.select(builder.icmp_signed("<", kx_up, int64(2)), builder.add(kx_up, int64(1)), int64(0))
        d_kz = _pick(builder, kz, direction)
        down = builder.fcmp_ordered("<", d_kz, ir.Constant(doubles, [0.0] * PACKET))
        all_down, none_down = every_lane(down), no_lane(down)
        kx = builder.select(all_down, ky_up, kx_up)
        ky = builder.select(all_down, kx_up, ky_up)
        sz = builder.fdiv(ir.Constant(doubles, [1.0] * PACKET), d_kz)
        rows = (builder.fmul(_pick(builder, kx, direction), sz), builder.fmul(_pick(builder, ky, direction), sz),
                _pick(builder, kx, origin), _pick(builder, ky, origin), _pick(builder, kz, origin), sz)
        data = builder.bitcast(context.make_array(sig.args[4])(context, builder, state_array).data,
                               doubles.as_pointer())
        for k, vector in enumerate(rows):
            builder.store(vector, builder.gep(data, [ir.Constant(intp, SHEAR_ROW + k)]), align=8)
        shared = builder.and_(builder.or_(builder.or_(all_x, all_y), all_z), builder.or_(all_down, none_down))
        code = builder.or_(builder.or_(kx, builder.shl(ky, int64(2))), builder.shl(kz, int64(4)))
        return builder.select(shared, code, int64(NOT_SHARED))

    return signature, codegen


def _widened_splat(context, builder, value, value_type, doubles):
    """The IR of ``value`` (float32 or float64) in every lane of ``doubles``: a float32 number
    splat first and widened as a vector, which takes one broadcast from memory and one conversion."""
    if value_type == types.float32:
        return builder.fpext(splat(builder, value, ir.VectorType(ir.FloatType(), PACKET)), doubles)
    return splat(builder, context.cast(builder, value, value_type, types.float64), doubles)


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

        a_x, a_y, a_z, b_x, b_y, b_z, c_x, c_y, c_z = (_widened_splat(context, builder, value, value_type, doubles)
                                                        for value, value_type in zip(args[2:], sig.args[2:]))
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
            det = builder.fadd(builder.fadd(e0, e1), e2)
            size = float_intrinsic(builder, "fabs", products[0])
            for product in products[1:]:
                size = builder.fadd(size, float_intrinsic(builder, "fabs", product))
            degenerate_limit = builder.fmul(ir.Constant(doubles, [DEGENERATE] * PACKET), size)
            proper = builder.fcmp_unordered(">", float_intrinsic(builder, "fabs", det), degenerate_limit)
            depth = builder.fadd(builder.fadd(builder.fmul(e0, az_), builder.fmul(e1, bz_)), builder.fmul(e2, cz_))
            t = builder.fdiv(builder.fmul(sz, depth), det)
            in_range = builder.and_(builder.fcmp_ordered(">=", t, builder.load(row(_T_MIN_ROW), align=8)),
                                    builder.fcmp_ordered("<=", t, builder.load(row(_BEST_ROW), align=8)))
            builder.store(t, row(HIT_ROW), align=8)
            hit = builder.and_(builder.and_(inside, proper), in_range)
            hit_lanes = builder.and_(builder.zext(builder.bitcast(hit, ir.IntType(PACKET)), int64), live)
            with builder.if_then(builder.icmp_unsigned("!=", hit_lanes, int64(0)), likely=False):
                builder.store(builder.fdiv(e1, det), row(HIT_ROW + 1), align=8)
                builder.store(builder.fdiv(e2, det), row(HIT_ROW + 2), align=8)
            tested = builder.block
        result = builder.phi(int64)
        result.add_incoming(int64(0), entry)
        result.add_incoming(hit_lanes, tested)
        return result

    return signature, codegen
