"""Box tests of a packet whose rays start apart, as shadow rays from neighbouring hits to one
light do, in vector instructions: each ray keeps the single-ray walk's conservative float32 test
(:mod:`.wide_slab`), where the interval bounds of the whole packet (:mod:`.packet_slab`) would cull
little.

* :func:`enter_children_by_lane`: each ray of the packet in turn against the node's eight child
  boxes at once, for nodes that few of the packet's rays walk;
* :func:`enter_children_of_lanes`: each child box in turn against all the packet's rays at once,
  one vector lane a ray, for nodes that most of them walk (at the top of the tree, before they
  part ways), as Wald, Slusallek, Benthin & Wagner's packets do ("Interactive Rendering with
  Coherent Ray Tracing", Eurographics 2001).

Both compute, lane for lane, what the single-ray test computes for that ray, so every ray enters
the children it would enter alone. :func:`set_up_lane_slabs` and :func:`bound_lane_slabs` write
each ray's constants and interval into its lane.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..._jit import inline_kernel
from ..._ray_lanes import rays_by_axis, rays_readable, splat
from .packet_slab import PACKET, reduce_lanes, vector_rows
from .wide import WIDTH, record_row
from .wide_slab import scaled_limit, scaled_limit_ir, slab_ray, slab_ray_ir, tighten_to_slab

__all__ = ["LANE_SLAB_ROWS", "enter_children_by_lane", "enter_children_of_lanes", "set_up_lane_slab",
           "set_up_lane_slabs", "bound_lane_slab", "bound_lane_slabs", "narrow_lane_slab"]

LANE_SLAB_ROWS = 11
"""Rows of :data:`.packet_slab.PACKET` float32 that the lane tests read, each ray's in its lane: the
origin moved for the near faces (x, y, z), moved for the far faces, the scaled inverse direction
(the first nine numbers of :func:`.wide_slab.slab_ray`), then the two ends of its interval
(:func:`.wide_slab.slab_limits`)."""
_NEAR_ORIGIN, _FAR_ORIGIN, _INVERSE, _ENTER_FROM, _EXIT_BY = 0, 3, 6, 9, 10


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
        builder.store(nearest, vector_rows(context, builder, sig.args[5], entry_array, doubles), align=8)
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
    enter the same children. Two children are tested at once, the packet's eight rays in one half of
    a vector of sixteen float32 and in the other (one 512-bit register where the processor has
    them), each child's faces spread over its half from the node's rows by a shuffle: against a
    child a vector of eight, the same answers, shadow rays from 1024^2 camera hits, settled calls,
    medians of 9, processes alternating with the code before, closest / any hit: one thread, forest
    0.92 / 0.97 of the time (three pairs), full dragon 0.91 / 0.96 (two); two threads, forest 0.89 /
    0.96, dragon 0.94 / 0.98 (two pairs each; 2026-12-07, Intel host with AVX-512). Nodes that fewer
    rays walk keep the lane test: from four or five rays on, the paired test measured level with it.

    ``entry[c]`` gets a distance no greater than the nearest entry into child ``c`` of those rays,
    as from :func:`enter_children_by_lane`, for a walk that orders or culls children by it
    (``read_entries``: a closest hit, a listing): the nearest of the rays' float32 entries, times
    the smallest of their scales (the largest, for a negative entry), which is the exact nearest
    when the rays share their scale, as rays to one light from nearby points mostly do. An any hit
    neither orders children nor narrows its rays' intervals, so its walk culls nothing an entered
    child holds: it gets ``-inf``. A first version, which took each child's exact nearest distance
    (eight float64 products, reduced) for every walk and chose each lane's near faces, ran at 1.00 /
    1.01 of the lane test (forest-small-chair shadow rays, closest / any hit, nodes walked by all
    eight rays, one thread, CPU time, medians of 7)."""
    signature = types.Tuple((types.int64, types.uint64))(records, node, slabs, scales, lanes, entry, read_entries,
                                                        near_x, near_y, near_z)

    def codegen(context, builder, sig, args):
        array, node_index, slab_array, scale_array, lane_bits, entry_array, read_flag = args[:7]
        intp = context.get_value_type(types.intp)
        int64 = ir.IntType(64)
        floats = ir.VectorType(ir.FloatType(), PACKET)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        row = record_row(context, builder, sig.args[0], array, node_index, sig.args[1])
        box_values = builder.bitcast(row, ir.FloatType().as_pointer())
        slab_rows = vector_rows(context, builder, sig.args[2], slab_array, floats)
        slab = [builder.load(builder.gep(slab_rows, [ir.Constant(intp, k)]), align=4) for k in range(LANE_SLAB_ROWS)]
        active = builder.trunc(context.cast(builder, lane_bits, sig.args[4], types.int64), ir.IntType(PACKET))
        nears = [context.cast(builder, value, sig.args[7 + axis], types.intp) for axis, value in enumerate(args[7:])]
        blocks = nears + [builder.sub(ir.Constant(intp, 2 * axis + 3), near) for axis, near in enumerate(nears)]
        face_rows = [builder.gep(box_values, [builder.mul(block, ir.Constant(intp, WIDTH))]) for block in blocks]
        pair = ir.VectorType(ir.FloatType(), 2 * PACKET)
        both_halves = ir.Constant(ir.VectorType(ir.IntType(32), 2 * PACKET), list(range(PACKET)) * 2)
        slab = [builder.shuffle_vector(row, row, both_halves) for row in slab]
        active_pair = builder.zext(active, ir.IntType(2 * PACKET))
        active_pair = builder.or_(active_pair, builder.shl(active_pair, ir.Constant(ir.IntType(2 * PACKET), PACKET)))
        in_lanes = builder.bitcast(active_pair, ir.VectorType(ir.IntType(1), 2 * PACKET))
        face_blocks = [builder.load(builder.bitcast(face_row, floats.as_pointer()), align=32) for face_row in face_rows]
        missed = ir.Constant(pair, [float("inf")] * 2 * PACKET)
        lane_byte = int64((1 << PACKET) - 1)
        children = int64(0)
        by_child = int64(0)
        entries = []
        for child in range(0, WIDTH, 2):
            spread = ir.Constant(ir.VectorType(ir.IntType(32), 2 * PACKET), [child] * PACKET + [child + 1] * PACKET)
            faces = [builder.shuffle_vector(block, block, spread) for block in face_blocks]
            enter, exit_ = slab[_ENTER_FROM], slab[_EXIT_BY]
            for axis in range(3):
                enter, exit_ = tighten_to_slab(builder, faces[axis], faces[axis + 3], slab[_NEAR_ORIGIN + axis],
                                               slab[_INVERSE + axis], enter, exit_,
                                               far_origin=slab[_FAR_ORIGIN + axis])
            used = builder.fadd(faces[0], faces[3])
            entered = builder.and_(builder.and_(builder.fcmp_ordered("<=", enter, exit_), in_lanes),
                                   builder.fcmp_ordered("ord", used, used))
            rays = builder.zext(builder.bitcast(entered, ir.IntType(2 * PACKET)), int64)
            by_child = builder.or_(by_child, builder.shl(rays, int64(8 * child)))
            for half in range(2):
                some = builder.zext(builder.icmp_unsigned("!=", builder.and_(builder.lshr(rays, int64(PACKET * half)),
                                                                            lane_byte), int64(0)), int64)
                children = builder.or_(children, builder.shl(some, int64(child + half)))
            chosen = builder.select(entered, enter, missed)
            for half in range(2):
                lanes_of_half = ir.Constant(ir.VectorType(ir.IntType(32), PACKET),
                                            list(range(PACKET * half, PACKET * (half + 1))))
                entries.append(builder.shuffle_vector(chosen, chosen, lanes_of_half))
        entry_rows = vector_rows(context, builder, sig.args[5], entry_array, doubles)
        reading = context.cast(builder, read_flag, sig.args[6], types.boolean)
        with builder.if_else(reading) as (read, unread):
            with read:
                scale = builder.load(vector_rows(context, builder, sig.args[3], scale_array, doubles), align=8)
                nearest = builder.fpext(_smallest_of_each(builder, entries), doubles)
                factor = builder.select(builder.fcmp_ordered(">=", nearest, ir.Constant(doubles, [0.0] * PACKET)),
                                        splat(builder, reduce_lanes(builder, scale, "<"), doubles),
                                        splat(builder, reduce_lanes(builder, scale, ">"), doubles))
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
    """:func:`set_up_lane_slab` for the eight rays of rows ``first`` to ``first + 3`` and ``second``
    to ``second + 3`` of ``origins`` and ``directions`` (as :func:`.packet_slab.load_packet` takes
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
        state_data = vector_rows(context, builder, sig.args[4], state_array, doubles)
        inverse = [builder.load(builder.gep(state_data, [ir.Constant(intp, 3 + axis)]), align=8) for axis in range(3)]
        reach = [splat(builder, context.cast(builder, value, sig.args[7 + axis], types.float64), doubles)
                 for axis, value in enumerate(args[7:10])]
        values = slab_ray_ir(builder, origin, direction, inverse, reach)
        slab_data = vector_rows(context, builder, sig.args[5], slab_array, floats)
        for k, vector in enumerate(values[:9]):
            builder.store(vector, builder.gep(slab_data, [ir.Constant(intp, k)]), align=4)
        scale_data = vector_rows(context, builder, sig.args[6], scale_array, doubles)
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
def bound_lane_slabs(typingctx, slabs, scales, state):
    """:func:`bound_lane_slab` for every lane at once: each lane's interval from rows 6 and 7 of
    ``state`` (:func:`.packet_slab.load_lane_limits`) into ``slabs``, on its scaled direction, in
    vector instructions (:func:`.wide_slab.scaled_limit_ir`, the scalar bound's arithmetic lane for
    lane, so to the bit what :func:`bound_lane_slab` writes)."""
    signature = types.void(slabs, scales, state)

    def codegen(context, builder, sig, args):
        intp = context.get_value_type(types.intp)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        floats = ir.VectorType(ir.FloatType(), PACKET)

        slab_rows, scale_rows, state_rows = (vector_rows(context, builder, sig.args[k], args[k], vector_type)
                                             for k, vector_type in enumerate((floats, doubles, doubles)))
        unscale = builder.load(builder.gep(scale_rows, [ir.Constant(intp, 1)]), align=8)
        for row, limit, side in ((_ENTER_FROM, 6, -1.0), (_EXIT_BY, 7, 1.0)):
            t = builder.load(builder.gep(state_rows, [ir.Constant(intp, limit)]), align=8)
            bound = scaled_limit_ir(builder, t, unscale, ir.Constant(doubles, [side] * PACKET))
            builder.store(bound, builder.gep(slab_rows, [ir.Constant(intp, row)]), align=4)
        return context.get_dummy_value()

    return signature, codegen
