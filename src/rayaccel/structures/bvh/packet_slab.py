"""Box tests of a ray packet against a wide node, in vector instructions, and the packet's loading.

Three tests, after Wald, Slusallek, Benthin & Wagner ("Interactive Rendering with
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
* :func:`enter_children_by_lane`: each ray of the packet against the eight child boxes,
  the single-ray walk's conservative float32 test lane after lane, for packets whose rays
  start apart (shadow rays), where the interval bounds would cull little.

All keep the exact test's NaN-safe bounds (an origin on a slab plane with a zero
direction component gives ``0 * inf``, which never tightens the interval).
:func:`load_packet` moves eight rays from the caller's rows into the packet's lanes;
:func:`bound_span` bounds a longer run of rays for :func:`enter_children_interval`.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..._jit import inline_kernel
from ..._ray_lanes import LANES, load_eight, rays_by_axis, rays_readable
from .wide import WIDTH, record_row
from .wide_slab import (
    entered_children,
    scaled_limit,
    scaled_limit_ir,
    slab_ray,
    slab_ray_ir,
    splat,
    tighten_lanes,
    tighten_to_slab,
)

__all__ = ["PACKET", "PACKET_ROWS", "LANE_SLAB_ROWS", "BOUND_T_MIN", "BOUND_BEST", "BOUND_VALUES",
           "enter_children_interval", "enter_child_lanes", "enter_children_by_lane", "enter_children_of_lanes",
           "set_up_lane_slab",
           "set_up_lane_slabs", "bound_lane_slab", "bound_lane_slabs", "narrow_lane_slab", "load_lane_limits",
           "load_packet", "load_lanes", "bound_span"]

PACKET = LANES
"""Rays per packet, one per vector lane."""
PACKET_ROWS = 8
"""Rows of :data:`PACKET` float64 in a packet's ray state: origin x, y, z, inverse
direction x, y, z, ``t_min``, best distance so far."""
LANE_SLAB_ROWS = 11
"""Rows of :data:`PACKET` float32 that :func:`enter_children_by_lane` reads, each ray's in its
lane: the origin moved for the near faces (x, y, z), moved for the far faces, the scaled inverse
direction (the first nine numbers of :func:`.wide_slab.slab_ray`), then the two ends of its
interval (:func:`.wide_slab.slab_limits`)."""
_NEAR_ORIGIN, _FAR_ORIGIN, _INVERSE, _ENTER_FROM, _EXIT_BY = 0, 3, 6, 9, 10
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
        row = record_row(context, builder, sig.args[0], array, node_index, sig.args[1])
        child_value = context.cast(builder, child_index, sig.args[2], types.intp)
        state_data = context.make_array(sig.args[3])(context, builder, state_array).data
        vectors = builder.bitcast(state_data, doubles.as_pointer())
        rows = [builder.load(builder.gep(vectors, [ir.Constant(intp, k)]), align=8) for k in range(PACKET_ROWS)]

        def corner(block):
            column = builder.add(ir.Constant(intp, WIDTH * block), child_value)
            return splat(builder, builder.fpext(builder.load(builder.gep(row, [column])), ir.DoubleType()), doubles)

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
def enter_children_by_lane(typingctx, records, node, slabs, scales, lanes, entry):
    """Each ray of the packet in ``lanes`` (bit ``r`` for lane ``r``) against the eight child
    boxes of wide ``node``, as the single-ray walk tests one ray (:func:`.wide_slab.enter_children`:
    float32 lanes, conservatively): returns the children each ray enters, byte ``r`` of the result
    for lane ``r`` (bit ``c`` for child ``c``; 0 for a lane not in ``lanes``), and writes into
    ``entry[c]`` (float64) a distance along the ray no greater than the nearest entry into child
    ``c`` of those rays (``inf`` where none enters). ``slabs`` holds the packet's
    :data:`LANE_SLAB_ROWS` rows of :data:`PACKET` float32 (:func:`.wide_slab.slab_ray` of each
    ray and its interval's :func:`.wide_slab.slab_limits`), ``scales`` each ray's ``slab[9]``,
    which turns its distances back into the ray's. The rays may point to either side along any
    axis; their tests are independent of each other, so the processor overlaps them. A lane not
    in ``lanes`` is branched over rather than computed and masked: below the top of the tree a
    shadow packet's rays part ways, and most nodes are entered by few of its lanes (shadow rays
    from 1024^2 camera hits, two threads, processes alternating with the masked test, 3 a side,
    closest / any hit: full dragon 1.36 / 1.42, forest 1.33 / 1.25)."""
    signature = types.int64(records, node, slabs, scales, lanes, entry)

    def codegen(context, builder, sig, args):
        array, node_index, slab_array, scale_array, lane_bits, entry_array = args
        intp = context.get_value_type(types.intp)
        int64 = ir.IntType(64)
        single = ir.FloatType()
        floats = ir.VectorType(single, WIDTH)
        doubles = ir.VectorType(ir.DoubleType(), WIDTH)
        row = record_row(context, builder, sig.args[0], array, node_index, sig.args[1])
        slab_data = context.make_array(sig.args[2])(context, builder, slab_array).data
        scale_data = context.make_array(sig.args[3])(context, builder, scale_array).data
        active = context.cast(builder, lane_bits, sig.args[4], types.int64)
        boxes = []
        for block in range(6):
            pointer = builder.gep(row, [ir.Constant(intp, WIDTH * block)])
            boxes.append(builder.load(builder.bitcast(pointer, floats.as_pointer()), align=32))
        faces = builder.fadd(boxes[0], boxes[3])
        used = builder.fcmp_ordered("ord", faces, faces)
        missed = ir.Constant(doubles, [float("inf")] * WIDTH)
        nearest = missed
        word = int64(0)
        for lane in range(PACKET):
            def value(slab_row):
                return builder.load(builder.gep(slab_data, [ir.Constant(intp, slab_row * PACKET + lane)]))

            in_lanes = builder.trunc(builder.lshr(active, int64(lane)), ir.IntType(1))
            before = builder.block
            with builder.if_then(in_lanes, likely=True):
                enter = splat(builder, value(_ENTER_FROM), floats)
                exit_ = splat(builder, value(_EXIT_BY), floats)
                for axis in range(3):
                    inverse = value(_INVERSE + axis)
                    positive = builder.fcmp_ordered(">=", inverse, ir.Constant(single, 0.0))
                    near_box = builder.select(positive, boxes[axis], boxes[axis + 3])
                    far_box = builder.select(positive, boxes[axis + 3], boxes[axis])
                    enter, exit_ = tighten_to_slab(builder, near_box, far_box,
                                                   splat(builder, value(_NEAR_ORIGIN + axis), floats),
                                                   splat(builder, inverse, floats), enter, exit_,
                                                   far_origin=splat(builder, value(_FAR_ORIGIN + axis), floats))
                entered = builder.and_(builder.fcmp_ordered("<=", enter, exit_), used)
                scale = builder.load(builder.gep(scale_data, [ir.Constant(intp, lane)]))
                distance = builder.fmul(builder.fpext(enter, doubles), splat(builder, scale, doubles))
                lane_entry = builder.select(entered, distance, missed)
                lane_nearest = builder.select(builder.fcmp_ordered("<", lane_entry, nearest), lane_entry, nearest)
                children = builder.zext(builder.bitcast(entered, ir.IntType(WIDTH)), int64)
                lane_word = builder.or_(word, builder.shl(children, int64(8 * lane)))
                tested = builder.block
            merged_nearest = builder.phi(doubles)
            merged_nearest.add_incoming(nearest, before)
            merged_nearest.add_incoming(lane_nearest, tested)
            merged_word = builder.phi(int64)
            merged_word.add_incoming(word, before)
            merged_word.add_incoming(lane_word, tested)
            nearest, word = merged_nearest, merged_word
        entry_view = context.make_array(sig.args[5])(context, builder, entry_array)
        builder.store(nearest, builder.bitcast(entry_view.data, doubles.as_pointer()), align=8)
        return word

    return signature, codegen


@intrinsic
def enter_children_of_lanes(typingctx, records, node, slabs, scales, lanes, entry, read_entries, near_x, near_y,
                            near_z):
    """:func:`enter_children_by_lane` with the roles of lanes and children exchanged: each child box
    against the packet's rays at once, one vector lane a ray, for nodes that most of the packet's
    rays enter (at the top of the tree, before they part ways). Returns ``(children, by_child)``:
    the children some ray in ``lanes`` enters (bit ``c``), and byte ``c`` the rays in ``lanes``
    entering child ``c`` (bit ``r``). Each lane's slab arithmetic is the lane test's, so the rays
    enter the same children.

    ``entry[c]`` gets a distance no greater than the nearest entry into child ``c`` of those rays,
    as from :func:`enter_children_by_lane`, for a walk that orders or culls children by it
    (``read_entries``: a closest hit, a listing): the nearest of the rays' float32 entries, times
    the smallest of their scales (the largest, for a negative entry), which is the exact nearest
    when the rays share their scale, as rays to one light from nearby points mostly do. An any hit
    neither orders children nor narrows its rays' intervals, so its walk culls nothing an entered
    child holds: it gets ``-inf``. The exact nearest distance of each child, eight float64 products reduced lane
    by lane, cost as much as the exchanged test saved (forest-small-chair shadow rays, nodes
    entered by all eight rays: closest / any hit 1.00 / 1.01 against the lane test, one thread,
    CPU time, medians of 7)."""
    signature = types.UniTuple(types.int64, 2)(records, node, slabs, scales, lanes, entry, read_entries, near_x,
                                                  near_y, near_z)

    def codegen(context, builder, sig, args):
        array, node_index, slab_array, scale_array, lane_bits, entry_array, read_flag = args[:7]
        intp = context.get_value_type(types.intp)
        int64 = ir.IntType(64)
        floats = ir.VectorType(ir.FloatType(), PACKET)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        row = record_row(context, builder, sig.args[0], array, node_index, sig.args[1])
        box_values = builder.bitcast(row, ir.FloatType().as_pointer())
        slab_rows = builder.bitcast(context.make_array(sig.args[2])(context, builder, slab_array).data,
                                    floats.as_pointer())
        slab = [builder.load(builder.gep(slab_rows, [ir.Constant(intp, k)]), align=4) for k in range(LANE_SLAB_ROWS)]
        active = builder.trunc(context.cast(builder, lane_bits, sig.args[4], types.int64), ir.IntType(PACKET))
        in_lanes = builder.bitcast(active, ir.VectorType(ir.IntType(1), PACKET))
        nears = [context.cast(builder, value, sig.args[7 + axis], types.intp) for axis, value in enumerate(args[7:])]
        blocks = nears + [builder.sub(ir.Constant(intp, 2 * axis + 3), near) for axis, near in enumerate(nears)]
        face_rows = [builder.gep(box_values, [builder.mul(block, ir.Constant(intp, WIDTH))]) for block in blocks]
        missed = ir.Constant(floats, [float("inf")] * PACKET)
        children = int64(0)
        by_child = int64(0)
        entries = []
        for child in range(WIDTH):
            faces = [splat(builder, builder.load(builder.gep(face_row, [ir.Constant(intp, child)])), floats)
                     for face_row in face_rows]
            enter, exit_ = slab[_ENTER_FROM], slab[_EXIT_BY]
            for axis in range(3):
                enter, exit_ = tighten_to_slab(builder, faces[axis], faces[axis + 3], slab[_NEAR_ORIGIN + axis],
                                               slab[_INVERSE + axis], enter, exit_,
                                               far_origin=slab[_FAR_ORIGIN + axis])
            used = builder.fadd(faces[0], faces[3])
            entered = builder.and_(builder.and_(builder.fcmp_ordered("<=", enter, exit_), in_lanes),
                                   builder.fcmp_ordered("ord", used, used))
            rays = builder.zext(builder.bitcast(entered, ir.IntType(PACKET)), int64)
            by_child = builder.or_(by_child, builder.shl(rays, int64(8 * child)))
            some = builder.zext(builder.icmp_unsigned("!=", rays, int64(0)), int64)
            children = builder.or_(children, builder.shl(some, int64(child)))
            entries.append(builder.select(entered, enter, missed))
        entry_rows = builder.bitcast(context.make_array(sig.args[5])(context, builder, entry_array).data,
                                     doubles.as_pointer())
        reading = context.cast(builder, read_flag, sig.args[6], types.boolean)
        with builder.if_else(reading) as (read, unread):
            with read:
                scale_rows = builder.bitcast(context.make_array(sig.args[3])(context, builder, scale_array).data,
                                             doubles.as_pointer())
                scale = builder.load(scale_rows, align=8)
                nearest = builder.fpext(_smallest_of_each(builder, entries), doubles)
                factor = builder.select(builder.fcmp_ordered(">=", nearest, ir.Constant(doubles, [0.0] * PACKET)),
                                        splat(builder, _reduce_lanes(builder, scale, "<"), doubles),
                                        splat(builder, _reduce_lanes(builder, scale, ">"), doubles))
                builder.store(builder.fmul(nearest, factor), entry_rows, align=8)
            with unread:
                builder.store(ir.Constant(doubles, [float("-inf")] * PACKET), entry_rows, align=8)
        return context.make_tuple(builder, sig.return_type, (children, by_child))

    return signature, codegen


def _smallest_of_each(builder, vectors):
    """The IR of the vector whose lane ``k`` is the smallest lane of ``vectors[k]`` (as many vectors
    as lanes, a power of two): pairs of vectors halved and merged, level after level."""
    count = len(vectors)
    width = count // 2
    while len(vectors) > 1:
        merged = []
        for first, second in zip(vectors[0::2], vectors[1::2]):
            order = [[block + k for block in range(0, 2 * count, 2 * width) for k in range(width)],
                     [block + width + k for block in range(0, 2 * count, 2 * width) for k in range(width)]]
            low, high = (builder.shuffle_vector(first, second, ir.Constant(ir.VectorType(ir.IntType(32), count), o))
                         for o in order)
            merged.append(builder.select(builder.fcmp_ordered("<", high, low), high, low))
        vectors = merged
        width //= 2
    return vectors[0]


@inline_kernel
def set_up_lane_slab(slabs, scales, r, ox, oy, oz, dx, dy, dz, ix, iy, iz, reach_x, reach_y, reach_z):
    """Write lane ``r``'s slab rows of ``slabs`` (the first nine of :data:`LANE_SLAB_ROWS`) for the
    ray from ``(ox, oy, oz)`` along ``(dx, dy, dz)`` (reciprocal ``(ix, iy, iz)``) among boxes within
    ``reach_*`` of 0, and its ``slab[9]`` and ``slab[10]`` (:func:`.wide_slab.slab_ray`) into
    ``scales[r]`` and ``scales[PACKET + r]``: a packet's partial last lanes, the others taking
    :func:`set_up_lane_slabs`."""
    slab = slab_ray(ox, oy, oz, dx, dy, dz, ix, iy, iz, reach_x, reach_y, reach_z)
    slabs[_NEAR_ORIGIN * PACKET + r] = slab[0]
    slabs[(_NEAR_ORIGIN + 1) * PACKET + r] = slab[1]
    slabs[(_NEAR_ORIGIN + 2) * PACKET + r] = slab[2]
    slabs[_FAR_ORIGIN * PACKET + r] = slab[3]
    slabs[(_FAR_ORIGIN + 1) * PACKET + r] = slab[4]
    slabs[(_FAR_ORIGIN + 2) * PACKET + r] = slab[5]
    slabs[_INVERSE * PACKET + r] = slab[6]
    slabs[(_INVERSE + 1) * PACKET + r] = slab[7]
    slabs[(_INVERSE + 2) * PACKET + r] = slab[8]
    scales[r] = slab[9]
    scales[PACKET + r] = slab[10]


@intrinsic
def set_up_lane_slabs(typingctx, origins, directions, first, second, state, slabs, scales, reach_x, reach_y,
                      reach_z):
    """:func:`set_up_lane_slab` for the :data:`PACKET` rays of rows ``first`` to ``first + 3`` and
    ``second`` to ``second + 3`` of ``origins`` and ``directions`` (as :func:`load_packet` takes
    them; their reciprocals read from rows 3-5 of ``state``, where it wrote them), in vector
    instructions, each lane computing what the scalar set-up computes for its ray, to the bit
    (:func:`.wide_slab.slab_ray_ir`). Set up ray after ray, a packet's eight slabs took 7-13 % of
    a shadow query (forest, one thread: 1.0-1.9 ms of 14.3-14.6 ms more when done twice); in
    vector lanes, shadow rays, one thread, CPU time, medians of 7 alternating in one process,
    closest / any hit: forest 1.13 / 1.09, full dragon 1.06 / 1.06 (first shadow query on an empty
    cache 10.1-10.7 s of CPU, against 9.4-10.7 in the same hour)."""
    if not rays_readable(origins, directions):
        return None
    signature = types.void(origins, directions, first, second, state, slabs, scales, reach_x, reach_y, reach_z)

    def codegen(context, builder, sig, args):
        origin_array, direction_array, first_row, second_row, state_array, slab_array, scale_array = args[:7]
        intp = context.get_value_type(types.intp)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        floats = ir.VectorType(ir.FloatType(), PACKET)
        row = context.cast(builder, first_row, sig.args[2], types.intp)
        second_start = context.cast(builder, second_row, sig.args[3], types.intp)
        origin = rays_by_axis(context, builder, sig.args[0], origin_array, row, second_start)
        direction = rays_by_axis(context, builder, sig.args[1], direction_array, row, second_start)
        state_data = builder.bitcast(context.make_array(sig.args[4])(context, builder, state_array).data,
                                     doubles.as_pointer())
        inverse = [builder.load(builder.gep(state_data, [ir.Constant(intp, 3 + axis)]), align=8) for axis in range(3)]
        reach = [splat(builder, context.cast(builder, value, sig.args[7 + axis], types.float64), doubles)
                 for axis, value in enumerate(args[7:10])]
        values = slab_ray_ir(builder, origin, direction, inverse, reach)
        slab_data = builder.bitcast(context.make_array(sig.args[5])(context, builder, slab_array).data,
                                    floats.as_pointer())
        for k, vector in enumerate(values[:9]):
            builder.store(vector, builder.gep(slab_data, [ir.Constant(intp, k)]), align=4)
        scale_data = builder.bitcast(context.make_array(sig.args[6])(context, builder, scale_array).data,
                                     doubles.as_pointer())
        for k, vector in enumerate(values[9:]):
            builder.store(vector, builder.gep(scale_data, [ir.Constant(intp, k)]), align=8)
        return context.get_dummy_value()

    return signature, codegen


@inline_kernel
def bound_lane_slab(slabs, scales, r, t_min, best):
    """Lane ``r``'s interval in ``slabs``, ``[t_min, best]`` on its scaled direction
    (:func:`.wide_slab.slab_limits`)."""
    slabs[_ENTER_FROM * PACKET + r] = scaled_limit(t_min, scales[PACKET + r], -1.0)
    narrow_lane_slab(slabs, scales, r, best)


@inline_kernel
def narrow_lane_slab(slabs, scales, r, best):
    """Lane ``r``'s interval in ``slabs`` ending at ``best``, its ray's best hit so far."""
    slabs[_EXIT_BY * PACKET + r] = scaled_limit(best, scales[PACKET + r], 1.0)


@intrinsic
def load_lane_limits(typingctx, t_min, t_max, first, second, state):
    """Rows 6 and 7 of ``state`` (``t_min`` and the best distance so far) for the :data:`PACKET`
    rays of rows ``first`` to ``first + 3`` and ``second`` to ``second + 3``, as
    :func:`load_packet` takes them, from a batch's ``t_min`` and ``t_max`` (float64, one value
    per ray or one for all, :func:`rayaccel.rays.ray_limit`): two vector loads each, or one
    value spread over the lanes. Lane by lane, with the bounds of :func:`bound_lane_slab`, the
    set-up of a shadow packet's limits took 51 of the 240 instructions a ray that misses the
    scene's box costs (forest-small-chair, counted on AVX2 code). Loaded and bounded so (with
    :func:`bound_lane_slabs`, and :func:`load_lanes` for the rays), one thread, CPU time, medians
    of 7 alternating in one process, closest / any hit: forest shadow rays 1.06 / 1.10, camera
    rays 1.06 / 1.10; full dragon shadow rays 1.04 / 1.04, camera rays 1.05 / 1.01."""
    limits = (t_min, t_max)
    if not all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype == types.float64
               for a in limits):
        return None
    signature = types.void(t_min, t_max, first, second, state)

    def codegen(context, builder, sig, args):
        intp = context.get_value_type(types.intp)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        rows = [context.cast(builder, args[k], sig.args[k], types.intp) for k in (2, 3)]
        state_data = builder.bitcast(context.make_array(sig.args[4])(context, builder, args[4]).data,
                                     doubles.as_pointer())
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
def bound_lane_slabs(typingctx, slabs, scales, state):
    """:func:`bound_lane_slab` for every lane at once: each lane's interval from rows 6 and 7 of
    ``state`` (:func:`load_lane_limits`) into ``slabs``, on its scaled direction, in vector
    instructions (:func:`.wide_slab.scaled_limit_ir`, the scalar bound's arithmetic lane for lane,
    so to the bit what :func:`bound_lane_slab` writes)."""
    signature = types.void(slabs, scales, state)

    def codegen(context, builder, sig, args):
        intp = context.get_value_type(types.intp)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        floats = ir.VectorType(ir.FloatType(), PACKET)

        def rows(k, vector_type):
            return builder.bitcast(context.make_array(sig.args[k])(context, builder, args[k]).data,
                                   vector_type.as_pointer())

        slab_rows, scale_rows, state_rows = rows(0, floats), rows(1, doubles), rows(2, doubles)
        unscale = builder.load(builder.gep(scale_rows, [ir.Constant(intp, 1)]), align=8)
        for row, limit, side in ((_ENTER_FROM, 6, -1.0), (_EXIT_BY, 7, 1.0)):
            t = builder.load(builder.gep(state_rows, [ir.Constant(intp, limit)]), align=8)
            bound = scaled_limit_ir(builder, t, unscale, ir.Constant(doubles, [side] * PACKET))
            builder.store(bound, builder.gep(slab_rows, [ir.Constant(intp, row)]), align=4)
        return context.get_dummy_value()

    return signature, codegen


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
        bounds_data = context.make_array(sig.args[5])(context, builder, args[5]).data
        for axis in range(3):
            positive = builder.icmp_unsigned("==", _positive_lanes(builder, inverse[axis]), ir.IntType(PACKET)(-1))
            o_low, o_high = _reduce_lanes(builder, origin[axis], "<"), _reduce_lanes(builder, origin[axis], ">")
            _store_axis_bounds(builder, bounds_data, axis, positive, o_low, o_high,
                               _reduce_lanes(builder, inverse[axis], "<"), _reduce_lanes(builder, inverse[axis], ">"))
        return _mixed_signs(builder, inverse)

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
        return _mixed_signs(builder, inverse)

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
    state_data = builder.bitcast(context.make_array(sig.args[4])(context, builder, args[4]).data,
                                 doubles.as_pointer())
    for k, vector in enumerate(origin + inverse):
        builder.store(vector, builder.gep(state_data, [ir.Constant(intp, k)]), align=8)
    return origin, inverse


def _positive_lanes(builder, inverse):
    """The IR of the lanes (bit ``r`` for lane ``r``) whose inverse direction in ``inverse`` is not
    negative."""
    zero = ir.Constant(inverse.type, [0.0] * PACKET)
    return builder.bitcast(builder.fcmp_ordered(">=", inverse, zero), ir.IntType(PACKET))


def _mixed_signs(builder, inverse):
    """The IR of 1 (int64) when the lanes' inverse directions (three vectors) have both signs along
    some axis, else 0."""
    mixed = ir.IntType(1)(0)
    for axis in range(3):
        signs = _positive_lanes(builder, inverse[axis])
        shared = builder.or_(builder.icmp_unsigned("==", signs, ir.IntType(PACKET)(-1)),
                             builder.icmp_unsigned("==", signs, ir.IntType(PACKET)(0)))
        mixed = builder.or_(mixed, builder.not_(shared))
    return builder.zext(mixed, ir.IntType(64))


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


def _reduce_lanes(builder, vector, compare):
    """The smallest (``compare`` "<") or largest (">") lane of ``vector``."""
    for width in (4, 2, 1):
        mask = ir.Constant(ir.VectorType(ir.IntType(32), PACKET), [(lane + width) % PACKET for lane in range(PACKET)])
        moved = builder.shuffle_vector(vector, vector, mask)
        vector = builder.select(builder.fcmp_ordered(compare, moved, vector), moved, vector)
    return builder.extract_element(vector, ir.IntType(32)(0))


@intrinsic
def bound_span(typingctx, origins, directions, first, second, packets, bounds):
    """The interval bounds of ``PACKET * packets`` rays of ``origins`` and ``directions`` ((n, 3)
    C-contiguous float64 or float32), the first half from row ``first`` on and the second from
    row ``second`` on (the rows that follow, or the next image row's for tiles,
    :mod:`rayaccel.ray_tiles`), for :func:`enter_children_interval`: returns
    0 after writing rows 0-14 of :data:`BOUND_VALUES` into ``bounds``, or 1, leaving ``bounds``
    unfinished, when along some axis the directions are not all of one strict sign. Each
    group of eight rows is read as three vectors of eight coordinates and folded into running
    minima and maxima lane by lane, with no shuffle; the lanes of each axis are reduced once at
    the end. The inverse directions are bounded by the inverses of the extreme directions: a
    correctly rounded division is monotone, so each ray's own inverse lies between them."""
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
        running = {}
        for array in range(2):
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
            for array in range(2):
                block = builder.gep(data[array], [offset])
                for part in range(3):
                    values = load_eight(builder, sig.args[array],
                                        builder.gep(block, [ir.Constant(intp, PACKET * part)]))
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
            return _reduce_lanes(builder, combined, compare)

        bounds_data = context.make_array(sig.args[5])(context, builder, bounds_array).data
        zero = ir.Constant(double, 0.0)
        one = ir.Constant(double, 1.0)
        unsigned = ir.IntType(1)(0)
        for axis in range(3):
            o_low, o_high = extreme(0, axis, "<"), extreme(0, axis, ">")
            d_low, d_high = extreme(1, axis, "<"), extreme(1, axis, ">")
            positive = builder.fcmp_ordered(">", d_low, zero)
            signed = builder.or_(positive, builder.fcmp_ordered("<", d_high, zero))
            unsigned = builder.or_(unsigned, builder.not_(signed))
            _store_axis_bounds(builder, bounds_data, axis, positive, o_low, o_high, builder.fdiv(one, d_high),
                               builder.fdiv(one, d_low))
        return builder.zext(unsigned, ir.IntType(64))

    return signature, codegen
