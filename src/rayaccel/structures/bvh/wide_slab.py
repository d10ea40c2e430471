"""Slab test of a wide node's eight child boxes at once, in LLVM vector instructions.

The slab test is Kay & Kajiya's ("Ray Tracing Complex Scenes", SIGGRAPH
1986), with the near face of each axis chosen once per ray (pbrt's
``dirIsNeg``) and NaN-safe bounds (:func:`.traverse.tighten`): a NaN from
``0 * inf`` (an origin on a slab plane, a zero direction component) never
replaces the running entry or exit distance.

A wide record stores each box component for its eight children side by side
(:mod:`.wide`), so one 32-byte load fetches, say, ``lo_x`` of all eight. Written
as scalar code, Numba leaves the children's tests scalar: LLVM's SLP
vectoriser, which would merge them, is off in Numba by default
(``NUMBA_SLP_VECTORIZE=0``), and a library must not switch it on for its
users' code. :func:`enter_children` therefore emits the vector IR itself: per
axis, two loads of eight float32 components, then subtract, multiply and
select on all eight children at once, in float32 (one ``ymm`` register of
eight lanes on AVX2; float64 lanes took two, and a ``zmm`` register on
AVX-512 is two halves on AMD's Zen 4), clipped to float32 bounds on the ray's
``[t_min, t_max]``. It returns the entered children as the bits of an integer,
which the traversal walks with :func:`highest_bit`, as Embree's does with its
``movemask``, and leaves their entry distances in float32, along the scaled
direction: the walk widens and scales back only those it pushes
(:func:`.traverse_wide.descend`), as Embree keeps its node distances in float.

The float32 test is conservative, in the manner of Ize's "Robust BVH Ray
Traversal" (JCGT 2013): it enters every box the exact float64 test enters, at
an entry distance no greater than the exact one, so the walk still meets every
primitive that could be hit before its best hit, and its answers are those of
the exact primitive tests (children entered at nearly equal distances may be
visited in another order). :func:`slab_ray` scales the direction by a power of
two to a largest component in ``[1, 2)`` (exactly), and moves the origin, for
the near faces, forward by ``SLAB_SLACK * (reach + |o|)`` along each axis
(backward for the far faces) before rounding it to float32, where ``reach``
bounds the boxes' coordinates: the rounding of the origin, of the difference,
of the reciprocal and of the product each err by at most a float32 half-ulp
of quantities below ``reach + |o|`` (as a distance along the axis), four in
all, and the move is sixteen. :func:`slab_limits` widens the ray's
``[t_min, t_max]`` outwards to float32 bounds (by ``2**-22`` of each end and
``2**-140``). This holds while the scaled distances of any child the exact
test enters fit float32 comfortably, which the largest direction component,
scaled to ``[1, 2)``, bounds by ``2 (reach + |o|)``; a larger distance along
another axis only culls a child the exact test culls too. A ray outside that
range (coordinates beyond ``2**100`` or below ``2**-100``, a direction
component below ``2**-100`` of the largest but not zero, a largest component
beyond ``2**900`` or below ``2**-900``, subnormal ones included) gets an
infinite move, which enters every child in use (at entry distances that may
be infinite), and is answered exactly by its primitive tests. An empty slot
(``lo = +inf``, ``hi = -inf``) is never entered: its faces sum to NaN.
Measured against the float64 lanes (in-process A/B, one thread, 2**18 rays,
speed after over before, closest / any hit, two to four runs): forest-small-chair
incoherent 1.02-1.09 / 1.02-1.08, shadow 1.08-1.10 / 1.08-1.12; dragon-203k
incoherent 1.01-1.06 / 1.02-1.04, shadow 1.03-1.04 / 1.05-1.09; the full
dragon's incoherent rays, whose walk waits on memory, 0.99 / 1.00. A first
version that read ``t_min`` and ``t_max`` as float64 at every node and scaled
each entry distance back there (two more vector operations a node) and called
``math.frexp`` per ray was slower on the forest (0.92-0.95 / 0.90-0.92); an earlier
float32 test of four-wide nodes, on the full dragon only, gained nothing
either (x0.98 to x1.03).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..._jit import inline_kernel, thread_rows
from ..._ray_lanes import splat
from .wide import WIDTH, is_record_array, record_row

__all__ = ["SLAB_FLOATS", "SLAB_SLACK", "child_entry_rows", "enter_children", "slab_ray", "slab_ray_ir", "slab_limits",
           "scaled_limit", "scaled_limit_ir", "box_reach", "highest_bit", "lowest_bit", "bit_count",
           "tighten_lanes", "tighten_to_slab", "entered_children", "float_intrinsic"]

SLAB_FLOATS = 11
"""Numbers of a ray's :func:`slab_ray`."""
SLAB_SLACK = 2.0 ** -20
"""The origin's move of :func:`slab_ray`, relative to the coordinates' size: sixteen float32
half-ulps."""
_LARGEST = 2.0 ** 100
_SMALLEST = 2.0 ** -100
_SCALE_LOW = 2.0 ** -900
_SCALE_HIGH = 2.0 ** 900
_LIMIT_SLACK = 2.0 ** -22
_LIMIT_FLOOR = 2.0 ** -140


@intrinsic
def slab_ray(typingctx, ox, oy, oz, dx, dy, dz, ix, iy, iz, reach_x, reach_y, reach_z):
    """The constants of :func:`enter_children` for the ray from ``(ox, oy, oz)`` along
    ``(dx, dy, dz)``, whose reciprocal is ``(ix, iy, iz)``, among boxes whose coordinates along
    each axis lie within ``reach_*`` of 0 (see the module docstring): in float32, the origin
    moved for the near faces, moved for the far faces, and the reciprocal of the direction
    scaled by a power of two ``s`` to a largest component in ``[1, 2)``; then ``s``, which turns
    distances along the scaled direction back into the ray's, and ``1 / s``. Emitted as IR: the
    same arithmetic written as Numba code made the first ``intersect`` on an empty cache compile
    for 6.26-6.45 s of CPU instead of 5.38 (bunny, ``benchmarks/bench_compile.py``)."""
    float32, float64 = types.float32, types.float64
    signature = types.Tuple((float32,) * 9 + (float64, float64))(*(float64,) * 12)

    def codegen(context, builder, sig, args):
        values = slab_ray_ir(builder, args[0:3], args[3:6], args[6:9], args[9:12])
        return context.make_tuple(builder, sig.return_type, values)

    return signature, codegen


def slab_ray_ir(builder, origin, direction, inverse, reach):
    """The IR of :func:`slab_ray` on float64 values, or lane for lane on vectors of them (the
    packets' lanes, :func:`.lane_slab.set_up_lane_slabs`): the nine float32 numbers (or
    vectors), then ``s`` and ``1 / s``."""
    shape = _Shape(origin[0], builder)
    kind, single, number, call = shape.kind, shape.single, shape.number, shape.call
    int64 = ir.IntType(64)
    integers = int64 if shape.lanes is None else ir.VectorType(int64, shape.lanes)

    def integer(value):
        return ir.Constant(integers, value if shape.lanes is None else [value] * shape.lanes)

    def larger(a, b):
        return builder.select(builder.fcmp_ordered(">", a, b), a, b)

    def smaller(a, b):
        return builder.select(builder.fcmp_ordered("<", a, b), a, b)

    magnitudes = [call("fabs", d) for d in direction]
    largest = larger(larger(magnitudes[0], magnitudes[1]), magnitudes[2])
    largest = smaller(larger(largest, number(2.0 ** -1022)), number(2.0 ** 1022))
    exponent = builder.and_(builder.bitcast(largest, integers), integer(0x7FF0000000000000))
    unscale = builder.bitcast(exponent, kind)
    scale = builder.bitcast(builder.sub(integer(0x7FE0000000000000), exponent), kind)
    scaled = [builder.fmul(i, unscale) for i in inverse]
    spans = [builder.fadd(r, call("fabs", o)) for r, o in zip(reach, origin)]
    checks = [builder.fcmp_ordered(">=", scale, number(_SCALE_LOW)),
              builder.fcmp_ordered("<=", scale, number(_SCALE_HIGH)),
              builder.fcmp_ordered(">=", smaller(smaller(spans[0], spans[1]), spans[2]), number(_SMALLEST)),
              builder.fcmp_ordered("<=", larger(larger(spans[0], spans[1]), spans[2]), number(_LARGEST))]
    for d, i in zip(direction, scaled):
        checks.append(builder.or_(builder.fcmp_ordered("==", d, number(0.0)),
                                  builder.fcmp_ordered("<=", call("fabs", i), number(_LARGEST))))
    in_range = checks[0]
    for check in checks[1:]:
        in_range = builder.and_(in_range, check)
    slack = builder.select(in_range, number(SLAB_SLACK), number(float("inf")))
    moves = [call("copysign", builder.fmul(slack, span), i) for span, i in zip(spans, scaled)]
    return ([builder.fptrunc(builder.fadd(o, m), single) for o, m in zip(origin, moves)]
            + [builder.fptrunc(builder.fsub(o, m), single) for o, m in zip(origin, moves)]
            + [builder.fptrunc(i, single) for i in scaled] + [scale, unscale])


@inline_kernel
def slab_limits(slab, t_min, t_max):
    """The interval ``[t_min, t_max]`` of the ray whose :func:`slab_ray` is ``slab`` on its scaled
    direction, widened to float32 bounds (:func:`enter_children`'s ``enter_from`` and
    ``exit_by``): each end moved outwards by ``2**-22`` of itself and ``2**-140``, then rounded
    to nearest, which errs by at most ``2**-24`` of the result or ``2**-150``."""
    return scaled_limit(t_min, slab[10], -1.0), scaled_limit(t_max, slab[10], 1.0)


@intrinsic
def scaled_limit(typingctx, t, unscale, side):
    """One end of :func:`slab_limits`: ``t`` on the direction scaled by ``unscale`` (``slab[10]``
    of :func:`slab_ray`), moved outwards (``side`` -1 for ``t_min``, 1 for ``t_max``) and rounded
    to float32 (:func:`scaled_limit_ir`)."""
    float64 = types.float64
    signature = types.float32(float64, float64, float64)

    def codegen(context, builder, sig, args):
        return scaled_limit_ir(builder, *args)

    return signature, codegen


def scaled_limit_ir(builder, t, unscale, side):
    """The IR of :func:`scaled_limit` on float64 values, or lane for lane on vectors of them (a
    packet's lanes, :func:`.lane_slab.bound_lane_slabs`): ``t * unscale``, moved by ``side``
    times ``2**-22`` of its magnitude plus ``2**-140``, rounded to float32 (or a vector of them)."""
    shape = _Shape(t, builder)
    scaled = builder.fmul(t, unscale)
    margin = builder.fadd(builder.fmul(shape.call("fabs", scaled), shape.number(_LIMIT_SLACK)),
                          shape.number(_LIMIT_FLOOR))
    return builder.fptrunc(builder.fadd(scaled, builder.fmul(side, margin)), shape.single)


def float_intrinsic(builder, name, *values):
    """The IR of LLVM's float intrinsic ``name`` (``fabs``, ``fma``, ...) on float64 values or
    vectors of them."""
    return _Shape(values[0], builder).call(name, *values)


class _Shape:
    """What IR written once for a float64 value or a vector of them needs of that shape: the
    float64 type (``kind``) and its float32 twin (``single``), its lanes (``None`` for a scalar),
    constants of it (``number``) and calls of LLVM's float intrinsics on it (``call``)."""

    def __init__(self, value, builder):
        self.kind = value.type
        self.lanes = self.kind.count if isinstance(self.kind, ir.VectorType) else None
        self.single = ir.FloatType() if self.lanes is None else ir.VectorType(ir.FloatType(), self.lanes)
        self._suffix = "f64" if self.lanes is None else f"v{self.lanes}f64"
        self._builder = builder

    def number(self, value):
        return ir.Constant(self.kind, value if self.lanes is None else [value] * self.lanes)

    def call(self, name, *values):
        function = cgutils.get_or_insert_function(self._builder.module,
                                                  ir.FunctionType(self.kind, [self.kind] * len(values)),
                                                  f"llvm.{name}.{self._suffix}")
        return self._builder.call(function, list(values))


@inline_kernel
def box_reach(lo, hi):
    """The ``reach`` of :func:`slab_ray` for the boxes inside the box from ``lo`` to ``hi``: the
    largest magnitude of its coordinates along each axis."""
    return (max(abs(np.float64(lo[0])), abs(np.float64(hi[0]))), max(abs(np.float64(lo[1])), abs(np.float64(hi[1]))),
            max(abs(np.float64(lo[2])), abs(np.float64(hi[2]))))


def child_entry_rows(rows):
    """Per-thread rows (:func:`rayaccel._jit.thread_rows`) for the entry distances
    :func:`enter_children` writes, ``rows`` of them."""
    return thread_rows((rows, WIDTH), np.float32)


@intrinsic
def enter_children(typingctx, records, node, near_x, near_y, near_z, slab, enter_from, exit_by, entry):
    """Test the ray against the child boxes of wide ``node``: writes into ``entry[c]`` a distance
    no greater than the one at which it enters child ``c`` within its interval, ``inf`` where it
    misses, and returns the mask of the children it enters (bit ``c`` for child ``c``),
    conservatively (see the module docstring). ``records`` is the (n, 64) float32 wide layout,
    ``near_*`` the column block (0-5) of each axis's near face, ``slab`` the ray's
    :func:`slab_ray`, ``enter_from`` and ``exit_by`` the interval's :func:`slab_limits`,
    ``entry`` a contiguous float32 array of ``WIDTH`` or more (a row of :func:`child_entry_rows`).
    The distances are the float32 lanes' own, along the scaled direction; multiplied by
    ``slab[9]`` they are the ray's, which a walk computes for the children it pushes alone
    (:func:`.traverse_wide.descend`)."""
    if not is_record_array(records) or entry.dtype != types.float32:
        return None
    signature = types.int64(records, node, near_x, near_y, near_z, slab, enter_from, exit_by, entry)

    def codegen(context, builder, sig, args):
        records_type = sig.args[0]
        array, node_index, *nears, slab_value, enter_limit, exit_limit, entry_array = args
        row = record_row(context, builder, records_type, array, node_index, sig.args[1])
        floats = ir.VectorType(ir.FloatType(), WIDTH)
        intp = context.get_value_type(types.intp)

        def component(block):
            pointer = builder.gep(row, [builder.mul(block, ir.Constant(intp, WIDTH))])
            return builder.load(builder.bitcast(pointer, floats.as_pointer()), align=4)

        def constant(k):
            return splat(builder, builder.extract_value(slab_value, k), floats)

        enter = splat(builder, enter_limit, floats)
        exit_ = splat(builder, exit_limit, floats)
        used = None
        for axis in range(3):
            near_block = context.cast(builder, nears[axis], sig.args[2 + axis], types.intp)
            far_block = builder.sub(ir.Constant(intp, 2 * axis + 3), near_block)
            near_face, far_face = component(near_block), component(far_block)
            if axis == 0:
                faces = builder.fadd(near_face, far_face)
                used = builder.fcmp_ordered("ord", faces, faces)
            enter, exit_ = tighten_to_slab(builder, near_face, far_face, constant(axis), constant(6 + axis), enter,
                                           exit_, far_origin=constant(3 + axis))
        return entered_children(context, builder, sig.args[8], entry_array, enter, exit_, used)

    return signature, codegen


def tighten_lanes(builder, near, far, enter, exit_):
    """The IR of :func:`.traverse.tighten` on vectors: each lane's interval narrowed to a slab's
    ``[near, far]``, a NaN bound (``0 * inf``) leaving it as it was."""
    enter = builder.select(builder.fcmp_ordered(">", near, enter), near, enter)
    exit_ = builder.select(builder.fcmp_ordered("<", far, exit_), far, exit_)
    return enter, exit_


def tighten_to_slab(builder, near_face, far_face, origin, inverse, enter, exit_, far_origin=None):
    """The IR of one slab of the slab test on vectors: the distances ``(face - origin) * inverse``
    to the near and far faces, each lane's interval narrowed to them (:func:`tighten_lanes`);
    ``far_origin``, when given, is the origin the far faces are measured from (:func:`slab_ray`
    moves it apart from the near faces' one)."""
    near = builder.fmul(builder.fsub(near_face, origin), inverse)
    far = builder.fmul(builder.fsub(far_face, origin if far_origin is None else far_origin), inverse)
    return tighten_lanes(builder, near, far, enter, exit_)


def entered_children(context, builder, entry_type, entry_array, enter, exit_, used=None):
    """The IR that ends a test of eight child boxes: stores each child's entry distance ``enter``
    (``inf`` where the interval is empty, or the slot is not ``used``) into the ``entry`` array,
    whose elements are of ``enter``'s type, and returns the mask of the entered."""
    entered = builder.fcmp_ordered("<=", enter, exit_)
    if used is not None:
        entered = builder.and_(entered, used)
    lanes = enter.type
    missed = ir.Constant(lanes, [float("inf")] * WIDTH)
    entry_view = context.make_array(entry_type)(context, builder, entry_array)
    builder.store(builder.select(entered, enter, missed), builder.bitcast(entry_view.data, lanes.as_pointer()),
                  align=entry_type.dtype.bitwidth // 8)
    return builder.zext(builder.bitcast(entered, ir.IntType(WIDTH)), ir.IntType(64))


def _zero_bits(builder, name, mask):
    """The IR counting ``mask``'s zero bits from one end: LLVM's ``name``, ``ctlz`` (leading) or
    ``cttz`` (trailing), on an int64 other than 0."""
    int64 = ir.IntType(64)
    count = cgutils.get_or_insert_function(builder.module, ir.FunctionType(int64, [int64, ir.IntType(1)]),
                                           f"llvm.{name}.i64")
    return builder.call(count, [mask, ir.IntType(1)(1)])


@intrinsic
def highest_bit(typingctx, mask):
    """The index of the highest set bit of ``mask`` (an int64 other than 0): one ``lzcnt``."""
    signature = types.int64(mask)

    def codegen(context, builder, sig, args):
        mask_value = context.cast(builder, args[0], sig.args[0], types.int64)
        return builder.sub(ir.IntType(64)(63), _zero_bits(builder, "ctlz", mask_value))

    return signature, codegen


@intrinsic
def lowest_bit(typingctx, mask):
    """The index of the lowest set bit of ``mask`` (an int64 other than 0): one ``tzcnt``."""
    signature = types.int64(mask)

    def codegen(context, builder, sig, args):
        return _zero_bits(builder, "cttz", context.cast(builder, args[0], sig.args[0], types.int64))

    return signature, codegen


@intrinsic
def bit_count(typingctx, mask):
    """How many bits of ``mask`` (an int64) are set: one ``popcnt``."""
    signature = types.int64(mask)

    def codegen(context, builder, sig, args):
        int64 = ir.IntType(64)
        count = cgutils.get_or_insert_function(builder.module, ir.FunctionType(int64, [int64]), "llvm.ctpop.i64")
        return builder.call(count, [context.cast(builder, args[0], sig.args[0], types.int64)])

    return signature, codegen
