"""Box tests of a ray packet against a wide node, in vector instructions, and the packet's loading.

Two tests, after Wald, Slusallek, Benthin & Wagner ("Interactive Rendering with
Coherent Ray Tracing", Eurographics 2001: a packet's rays in vector lanes) and Wald,
Boulos & Shirley ("Ray Tracing Deformable Scenes Using Dynamic Bounding Volume
Hierarchies", ACM TOG 26(1), 2007: a box culled for a whole packet by interval
arithmetic over its rays):

* :func:`enter_children_interval`: the packet as a whole against the node's eight child
  boxes at once, in float64: each slab distance computed from the packet's extreme origin
  and the inverse direction at either end of its range, whichever gives the nearer entry
  (farther exit). Rounding is monotone, so no ray of the packet enters a box earlier or
  leaves it later than this bound says: a box it culls, every one of its rays would cull
  on its own. It asks that the packet's rays point to the same side along each axis (their
  inverse directions of one sign).
* :func:`enter_child_lanes`: one child box against each ray of the packet, one vector
  lane a ray, computing what the exact test (:func:`.traverse.enter_box`) computes for that
  ray, in float64; the packet walk asks it of the leaves the packet enters, so that a ray
  tests only the primitives of leaves it enters itself.
* the tests of packets whose rays start apart (shadow rays), where interval bounds would cull
  little: :mod:`.lane_slab`.

All keep the exact test's NaN-safe bounds (an origin on a slab plane with a zero
direction component gives ``0 * inf``, which never tightens the interval).
:func:`load_packet` and :func:`load_lanes` move eight rays from the caller's rows into the
packet's lanes, :func:`load_lane_limits` their ``t_min`` and ``t_max``; :func:`bound_span` bounds
a longer run of rays for :func:`enter_children_interval`.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..._ray_lanes import LANES, load_eight, rays_by_axis, rays_readable, shared_by_lanes, splat
from .wide import WIDTH, record_row
from .wide_slab import entered_children, float_intrinsic, tighten_lanes, tighten_to_slab

__all__ = ["PACKET", "PACKET_ROWS", "BOUND_T_MIN", "BOUND_BEST", "BOUND_VALUES", "enter_children_interval",
           "enter_child_lanes", "load_lane_limits", "load_packet", "load_lanes", "bound_span", "reduce_lanes",
           "vector_rows"]

PACKET = LANES
"""Rays per packet, one per vector lane."""
PACKET_ROWS = 8
"""Rows of :data:`PACKET` float64 in a packet's ray state: origin x, y, z, inverse
direction x, y, z, ``t_min``, best distance so far."""
BOUND_T_MIN = 15
BOUND_BEST = 16
BOUND_VALUES = 17
"""Float64 values of a packet's bounds: for each axis five, its near block (0-2 for the
box's ``lo``, 3-5 for ``hi``, as a float), the extreme origins that bound its rays' near and
far distances, and the two ends of its rays' inverse directions; then, at :data:`BOUND_T_MIN`
and :data:`BOUND_BEST`, the smallest ``t_min`` and the farthest best distance of its rays."""


@intrinsic
def enter_children_interval(typingctx, records, node, bounds, entry):
    """The packet whose ``bounds`` (:data:`BOUND_VALUES`) are given against the child boxes of wide
    ``node``: the mask of the children one of its rays may enter (bit ``c`` for child ``c``),
    and in ``entry[c]`` a distance no larger than any of its rays' entry into child ``c``."""
    signature = types.int64(records, node, bounds, entry)

    def codegen(context, builder, sig, args):
        array, node_index, bounds_array, entry_array = args
        intp = context.get_value_type(types.intp)
        floats = ir.VectorType(ir.FloatType(), WIDTH)
        doubles = ir.VectorType(ir.DoubleType(), WIDTH)
        row = record_row(context, builder, sig.args[0], array, node_index, sig.args[1])
        values = context.make_array(sig.args[2])(context, builder, bounds_array).data

        def value(k):
            return builder.load(builder.gep(values, [ir.Constant(intp, k)]))

        def component(block):
            pointer = builder.gep(row, [builder.mul(block, ir.Constant(intp, WIDTH))])
            return builder.fpext(builder.load(builder.bitcast(pointer, floats.as_pointer()), align=32), doubles)

        enter = splat(builder, value(BOUND_T_MIN), doubles)
        exit_ = splat(builder, value(BOUND_BEST), doubles)
        for axis in range(3):
            near_block = builder.fptosi(value(5 * axis), intp)
            far_block = builder.sub(ir.Constant(intp, 2 * axis + 3), near_block)
            near_o, far_o, inv_low, inv_high = (splat(builder, value(5 * axis + k), doubles) for k in range(1, 5))
            near_gap = builder.fsub(component(near_block), near_o)
            far_gap = builder.fsub(component(far_block), far_o)
            near_low, near_high = builder.fmul(near_gap, inv_low), builder.fmul(near_gap, inv_high)
            far_low, far_high = builder.fmul(far_gap, inv_low), builder.fmul(far_gap, inv_high)
            near = builder.select(builder.fcmp_ordered("<", near_high, near_low), near_high, near_low)
            far = builder.select(builder.fcmp_ordered(">", far_high, far_low), far_high, far_low)
            enter, exit_ = tighten_lanes(builder, near, far, enter, exit_)
        return entered_children(context, builder, sig.args[3], entry_array, enter, exit_)

    return signature, codegen


@intrinsic
def enter_child_lanes(typingctx, records, node, child, state, lanes):
    """The rays of the packet in ``lanes`` (bit ``r`` for lane ``r``) that enter child box
    ``child`` of wide ``node`` before their best hit, as a lane mask; ``state`` holds the
    packet's :data:`PACKET_ROWS` rows of :data:`PACKET` float64."""
    signature = types.int64(records, node, child, state, lanes)

    def codegen(context, builder, sig, args):
        array, node_index, child_index, state_array, lane_bits = args
        intp = context.get_value_type(types.intp)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        floats = ir.VectorType(ir.FloatType(), PACKET)
        row = record_row(context, builder, sig.args[0], array, node_index, sig.args[1])
        child_value = context.cast(builder, child_index, sig.args[2], types.intp)
        state_data = context.make_array(sig.args[3])(context, builder, state_array).data
        vectors = builder.bitcast(state_data, doubles.as_pointer())
        rows = [builder.load(builder.gep(vectors, [ir.Constant(intp, k)]), align=8) for k in range(PACKET_ROWS)]

        def corner(block):
            column = builder.add(ir.Constant(intp, WIDTH * block), child_value)
            return builder.fpext(splat(builder, builder.load(builder.gep(row, [column])), floats), doubles)

        enter, exit_ = rows[6], rows[7]
        zero = ir.Constant(doubles, [0.0] * PACKET)
        for axis in range(3):
            lo, hi = corner(axis), corner(axis + 3)
            origin, inverse = rows[axis], rows[axis + 3]
            positive = builder.fcmp_ordered(">=", inverse, zero)
            enter, exit_ = tighten_to_slab(builder, builder.select(positive, lo, hi), builder.select(positive, hi, lo),
                                           origin, inverse, enter, exit_)
        entered = builder.zext(builder.bitcast(builder.fcmp_ordered("<=", enter, exit_), ir.IntType(PACKET)),
                               ir.IntType(64))
        return builder.and_(entered, context.cast(builder, lane_bits, sig.args[4], types.int64))

    return signature, codegen


@intrinsic
def load_lane_limits(typingctx, t_min, t_max, first, second, state):
    """Rows 6 and 7 of ``state`` (``t_min`` and the best distance so far) for the :data:`PACKET`
    rays of rows ``first`` to ``first + 3`` and ``second`` to ``second + 3``, as
    :func:`load_packet` takes them, from a batch's ``t_min`` and ``t_max`` (float64, one value
    per ray or one for all, :func:`rayaccel.rays.ray_limit`): two vector loads each, or one
    value spread over the lanes. Lane by lane, with the bounds of
    :func:`.lane_slab.bound_lane_slab` and the lanes' best-hit fields, the loop over a shadow
    packet's lanes took 51 of the 240 instructions a ray that misses the scene's box costs, 8
    after (its stores of the best-hit fields; forest-small-chair, counted on AVX2 code). Loaded
    and bounded so (with :func:`.lane_slab.bound_lane_slabs`, and :func:`load_lanes`
    for the rays), one thread, CPU time, medians of 7 alternating in one process, closest / any
    hit: forest shadow rays 1.06 / 1.10, camera rays 1.06 / 1.10; full dragon shadow rays 1.04 /
    1.04, camera rays 1.05 / 1.01."""
    limits = (t_min, t_max)
    if not all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype == types.float64
               for a in limits):
        return None
    signature = types.void(t_min, t_max, first, second, state)

    def codegen(context, builder, sig, args):
        intp = context.get_value_type(types.intp)
        rows = [context.cast(builder, args[k], sig.args[k], types.intp) for k in (2, 3)]
        state_data = vector_rows(context, builder, sig.args[4], args[4], ir.VectorType(ir.DoubleType(), PACKET))
        for k in range(2):
            lanes = _limit_lanes(context, builder, sig.args[k], args[k], *rows)
            builder.store(lanes, builder.gep(state_data, [ir.Constant(intp, 6 + k)]), align=8)
        return context.get_dummy_value()

    return signature, codegen


def _limit_lanes(context, builder, array_type, array, first, second):
    """A batch's ``t_min`` or ``t_max`` for the rays of a packet (:func:`load_lane_limits`) as a
    vector of :data:`PACKET` float64."""
    intp = context.get_value_type(types.intp)
    half = PACKET // 2
    doubles = ir.VectorType(ir.DoubleType(), PACKET)
    fours = ir.VectorType(ir.DoubleType(), half)
    values = context.make_array(array_type)(context, builder, array)
    data = values.data
    length = cgutils.unpack_tuple(builder, values.shape, 1)[0]
    per_ray = builder.icmp_signed(">", length, ir.Constant(intp, 1))
    with builder.if_else(per_ray) as (one_each, one_for_all):
        with one_each:
            parts = [builder.load(builder.bitcast(builder.gep(data, [row]), fours.as_pointer()), align=8)
                     for row in (first, second)]
            each = builder.shuffle_vector(*parts, ir.Constant(ir.VectorType(ir.IntType(32), PACKET),
                                                              list(range(PACKET))))
            each_block = builder.block
        with one_for_all:
            shared = splat(builder, builder.load(data), doubles)
            shared_block = builder.block
    lanes = builder.phi(doubles)
    lanes.add_incoming(each, each_block)
    lanes.add_incoming(shared, shared_block)
    return lanes


@intrinsic
def load_packet(typingctx, origins, directions, first, second, state, bounds):
    """Load the :data:`PACKET` rays of rows ``first`` to ``first + 3`` and ``second`` to ``second + 3``
    (``first + 4`` for eight consecutive rays, a row's length on for a tile of an image,
    :mod:`rayaccel.ray_tiles`) of ``origins`` and ``directions`` ((n, 3) C-contiguous float64 or
    float32) into rows 0-5 of ``state`` (:func:`load_lanes`). Returns 1 when the rays point to both
    sides along some axis, else 0 after writing the packet's interval bounds (rows 0-14 of
    :data:`BOUND_VALUES`) into ``bounds``, as the scalar set-up of the packet walk computes them."""
    if not rays_readable(origins, directions):
        return None
    signature = types.int64(origins, directions, first, second, state, bounds)

    def codegen(context, builder, sig, args):
        origin, inverse = _load_rays(context, builder, sig, args)
        signs = [_positive_lanes(builder, vector) for vector in inverse]
        bounds_data = context.make_array(sig.args[5])(context, builder, args[5]).data
        for axis in range(3):
            positive = builder.icmp_unsigned("==", signs[axis], ir.IntType(PACKET)(-1))
            o_low, o_high = reduce_lanes(builder, origin[axis], "<"), reduce_lanes(builder, origin[axis], ">")
            _store_axis_bounds(builder, bounds_data, axis, positive, o_low, o_high,
                               reduce_lanes(builder, inverse[axis], "<"), reduce_lanes(builder, inverse[axis], ">"))
        return _mixed_signs(builder, signs)

    return signature, codegen


@intrinsic
def load_lanes(typingctx, origins, directions, first, second, state):
    """:func:`load_packet` without the packet's bounds, for packets whose rays are tested lane by
    lane: the origins and inverse directions of the :data:`PACKET` rays into rows 0-5 of ``state``,
    one lane a ray, by four loads per array (:func:`rayaccel._ray_lanes.rays_by_axis`), shuffled
    from rows to lanes, and three vector divisions. Returns 1 when the rays point to both sides
    along some axis, else 0."""
    if not rays_readable(origins, directions):
        return None
    signature = types.int64(origins, directions, first, second, state)

    def codegen(context, builder, sig, args):
        _, inverse = _load_rays(context, builder, sig, args)
        return _mixed_signs(builder, [_positive_lanes(builder, vector) for vector in inverse])

    return signature, codegen


def _load_rays(context, builder, sig, args):
    """The IR of :func:`load_lanes` (arguments ``origins, directions, first, second, state``
    first in ``sig`` and ``args``); returns the origins and the inverse directions, three vectors
    each."""
    intp = context.get_value_type(types.intp)
    doubles = ir.VectorType(ir.DoubleType(), PACKET)
    row = context.cast(builder, args[2], sig.args[2], types.intp)
    second_row = context.cast(builder, args[3], sig.args[3], types.intp)
    origin = rays_by_axis(context, builder, sig.args[0], args[0], row, second_row)
    direction = rays_by_axis(context, builder, sig.args[1], args[1], row, second_row)
    ones = ir.Constant(doubles, [1.0] * PACKET)
    inverse = [builder.fdiv(ones, d) for d in direction]
    state_data = vector_rows(context, builder, sig.args[4], args[4], doubles)
    for k, vector in enumerate(origin + inverse):
        builder.store(vector, builder.gep(state_data, [ir.Constant(intp, k)]), align=8)
    return origin, inverse


def _positive_lanes(builder, inverse):
    """The IR of the lanes (bit ``r`` for lane ``r``) whose inverse direction in ``inverse`` is not
    negative."""
    zero = ir.Constant(inverse.type, [0.0] * PACKET)
    return builder.bitcast(builder.fcmp_ordered(">=", inverse, zero), ir.IntType(PACKET))


def _mixed_signs(builder, signs):
    """The IR of 1 (int64) when the lanes' inverse directions have both signs along some axis, from
    each axis's :func:`_positive_lanes`, else 0."""
    mixed = ir.IntType(1)(0)
    for axis_signs in signs:
        shared = builder.or_(builder.icmp_unsigned("==", axis_signs, ir.IntType(PACKET)(-1)),
                             builder.icmp_unsigned("==", axis_signs, ir.IntType(PACKET)(0)))
        mixed = builder.or_(mixed, builder.not_(shared))
    return builder.zext(mixed, ir.IntType(64))


def vector_rows(context, builder, array_type, array, vector_type):
    """The IR of a pointer to the rows of ``vector_type`` that a contiguous array's data holds (a
    packet's state or slab rows, one row of :data:`PACKET` numbers a vector)."""
    return builder.bitcast(context.make_array(array_type)(context, builder, array).data, vector_type.as_pointer())


def _store_axis_bounds(builder, bounds_data, axis, positive, o_low, o_high, inv_low, inv_high):
    """Write one axis's five interval bounds (:data:`BOUND_VALUES`) of rays whose directions along
    it are all positive (``positive`` true) or all negative: the near block, the extreme origins
    that bound the near and far distances, and the ends of the inverse directions."""
    double = ir.DoubleType()
    values = (builder.select(positive, ir.Constant(double, float(axis)), ir.Constant(double, float(axis + 3))),
              builder.select(positive, o_high, o_low), builder.select(positive, o_low, o_high), inv_low, inv_high)
    for k, value in enumerate(values):
        builder.store(value, builder.gep(bounds_data, [ir.IntType(64)(5 * axis + k)]))


def _lane_axes(part):
    """The axis each lane holds of the ``part``-th of the three vectors of eight float64 that hold
    eight consecutive rows of an (n, 3) array."""
    return [(PACKET * part + lane) % 3 for lane in range(PACKET)]


def reduce_lanes(builder, vector, compare):
    """The IR of the smallest (``compare`` "<") or largest (">") lane of ``vector``."""
    for width in (4, 2, 1):
        mask = ir.Constant(ir.VectorType(ir.IntType(32), PACKET), [(lane + width) % PACKET for lane in range(PACKET)])
        moved = builder.shuffle_vector(vector, vector, mask)
        vector = builder.select(builder.fcmp_ordered(compare, moved, vector), moved, vector)
    return builder.extract_element(vector, ir.IntType(32)(0))


@intrinsic
def bound_span(typingctx, origins, directions, first, second, packets, bounds):
    """The interval bounds of ``PACKET * packets`` rays of ``origins`` and ``directions`` ((n, 3)
    C-contiguous float64 or float32; ``origins`` may be a (3,) origin they share, read once), the
    first half from row ``first`` on and the second from row ``second`` on (the rows that follow,
    or the next image row's for tiles, :mod:`rayaccel.ray_tiles`), for :func:`enter_children_interval`: returns
    0 after writing rows 0-14 of :data:`BOUND_VALUES` into ``bounds``, or 1, leaving ``bounds``
    unfinished, when along some axis the directions are not all of one strict sign. Each
    group of eight rows is read as three vectors of eight coordinates and folded into running
    minima and maxima lane by lane, with no shuffle; the lanes of each axis are reduced once at
    the end. The inverse directions are bounded by the inverses of the extreme directions: a
    correctly rounded division is monotone, so each ray's own inverse lies between them.
    Returns 2 instead when some coordinate is NaN or infinite (each coordinate times zero, summed,
    is then not zero), so that rays bounded with 0 are all usable
    (:func:`rayaccel._validate.unusable_ray`: finite, and with no zero component no zero
    direction), which spares the packet walk a check of its own of those rays: one fused
    multiply-add per eight coordinates in place of the check's reading of the rays into lanes.
    Forest camera rays (1024^2), instructions counted on AVX2 code: closest hit 178.6 -> 174.0
    million, any hit 90.5 -> 85.7; one thread, CPU time, processes alternating (medians of 6-8
    processes, each the median of 5 timings), closest / any hit: forest 1.02 / 1.06, full dragon
    1.02 / 1.04."""
    if not rays_readable(origins, directions):
        return None
    signature = types.int64(origins, directions, first, second, packets, bounds)

    def codegen(context, builder, sig, args):
        origin_array, direction_array, first_row, second_row, packet_count, bounds_array = args
        intp = context.get_value_type(types.intp)
        double = ir.DoubleType()
        doubles = ir.VectorType(double, PACKET)
        row = context.cast(builder, first_row, sig.args[2], types.intp)
        second_start = context.cast(builder, second_row, sig.args[3], types.intp)
        count = context.cast(builder, packet_count, sig.args[4], types.intp)
        half = builder.lshr(count, ir.Constant(intp, 1))
        data = [context.make_array(array_type)(context, builder, array).data
                for array_type, array in ((sig.args[0], origin_array), (sig.args[1], direction_array))]
        highest = ir.Constant(doubles, [float("inf")] * PACKET)
        lowest = ir.Constant(doubles, [float("-inf")] * PACKET)
        zeros = ir.Constant(doubles, [0.0] * PACKET)
        finite_sum = cgutils.alloca_once(builder, doubles)
        builder.store(zeros, finite_sum)
        shared_origin = sig.args[0].ndim == 1
        read_in_rows = (1,) if shared_origin else (0, 1)
        if shared_origin:
            origin = [shared_by_lanes(builder, sig.args[0], builder.gep(data[0], [ir.Constant(intp, axis)]))
                      for axis in range(3)]
            for vector in origin:
                builder.store(float_intrinsic(builder, "fma", vector, zeros, builder.load(finite_sum)), finite_sum)
        running = {}
        for array in read_in_rows:
            for part in range(3):
                for compare, start in (("<", highest), (">", lowest)):
                    slot = cgutils.alloca_once(builder, doubles)
                    builder.store(start, slot)
                    running[array, part, compare] = slot
        with cgutils.for_range(builder, count) as loop:
            in_first = builder.icmp_signed("<", loop.index, half)
            group_row = builder.select(in_first, builder.add(row, builder.mul(loop.index, ir.Constant(intp, PACKET))),
                                       builder.add(second_start, builder.mul(builder.sub(loop.index, half),
                                                                             ir.Constant(intp, PACKET))))
            offset = builder.mul(group_row, ir.Constant(intp, 3))
            for array in read_in_rows:
                block = builder.gep(data[array], [offset])
                for part in range(3):
                    values = load_eight(builder, sig.args[array],
                                        builder.gep(block, [ir.Constant(intp, PACKET * part)]))
                    builder.store(float_intrinsic(builder, "fma", values, zeros, builder.load(finite_sum)), finite_sum)
                    for compare in ("<", ">"):
                        slot = running[array, part, compare]
                        kept = builder.load(slot)
                        builder.store(builder.select(builder.fcmp_ordered(compare, values, kept), values, kept), slot)

        def extreme(array, axis, compare):
            fill = highest if compare == "<" else lowest
            combined = fill
            for part in range(3):
                lanes = ir.Constant(ir.VectorType(ir.IntType(1), PACKET), [a == axis for a in _lane_axes(part)])
                vector = builder.select(lanes, builder.load(running[array, part, compare]), fill)
                combined = builder.select(builder.fcmp_ordered(compare, vector, combined), vector, combined)
            return reduce_lanes(builder, combined, compare)

        bounds_data = context.make_array(sig.args[5])(context, builder, bounds_array).data
        zero = ir.Constant(double, 0.0)
        one = ir.Constant(double, 1.0)
        unsigned = ir.IntType(1)(0)
        for axis in range(3):
            if shared_origin:
                o_low = o_high = builder.extract_element(origin[axis], ir.IntType(32)(0))
            else:
                o_low, o_high = extreme(0, axis, "<"), extreme(0, axis, ">")
            d_low, d_high = extreme(1, axis, "<"), extreme(1, axis, ">")
            positive = builder.fcmp_ordered(">", d_low, zero)
            signed = builder.or_(positive, builder.fcmp_ordered("<", d_high, zero))
            unsigned = builder.or_(unsigned, builder.not_(signed))
            _store_axis_bounds(builder, bounds_data, axis, positive, o_low, o_high, builder.fdiv(one, d_high),
                               builder.fdiv(one, d_low))
        int64 = ir.IntType(64)
        nonfinite_lanes = builder.fcmp_unordered("!=", builder.load(finite_sum), zeros)
        nonfinite = builder.icmp_unsigned("!=", builder.bitcast(nonfinite_lanes, ir.IntType(PACKET)),
                                          ir.IntType(PACKET)(0))
        return builder.select(nonfinite, int64(2), builder.zext(unsigned, int64))

    return signature, codegen
