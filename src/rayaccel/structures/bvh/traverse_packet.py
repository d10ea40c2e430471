"""Packets of eight rays through the eight-wide BVH (:mod:`.wide`), closest hit and any hit.

Coherent rays, such as a camera's through neighbouring pixels or the shadow rays from
their hits to one light, walk the upper tree together (Wald, Slusallek, Benthin &
Wagner, "Interactive Rendering with Coherent Ray Tracing", Eurographics 2001; on wide
nodes as Embree's packet traversal, Wald et al., ACM TOG 33(4), 2014). A packet fetches
a node once and tests its eight child boxes against the packet's bounds at once
(:func:`.packet_slab.enter_children_interval`: one test for all its rays, which culls
a box only where each ray would), so the traversal's chain of dependent loads and tests
is paid once for eight rays. A leaf the packet enters is tested against each of its
rays (:func:`.packet_slab.enter_child_lanes`), and only the rays that enter it test its
primitives, with the single-ray walk's test (the same hits, to the bit). A full packet whose
rays share the triangle test's axes may instead test each triangle of the leaf on all its rays
at once (:func:`.packet_triangle.hits_by_lane`, the rays' shear set up in vector lanes at the
packet's first leaf by :func:`.packet_triangle.set_up_shear`), lane for lane the single-ray
test's arithmetic. Closest-hit packets do so: forest camera rays on two threads, medians of 9
in alternating processes, 22.3-23.3 -> 18.5-20.4 ms, the full dragon's 42.6-44.3 -> 40.2-42.6
ms; the forest's shadow rays (one thread, medians of 5 processes each) 19.7 -> 18.7 ms, the
dragon's unchanged.
Any-hit shadow packets do so too (forest, one thread, medians of 4: 17.5 -> 15.6 ms; the
dragon's 57.0 -> 58.6 ms, within the spread of the runs), and so do any-hit camera packets
since ``occluded`` writes one byte a ray: against the lane-after-lane tests, one thread, CPU
time, medians of 9-15 in one process, forest 1.11 and 1.13, full dragon 1.02 (two threads,
alternating processes: forest 0.98 and 1.02, dragon 1.16 and 0.91, the noise of that hour;
before the change to ``occluded``: the same on the forest, up to 4 % slower on the dragon).
A leaf that only one of those rays still reaches is tested by that ray alone, with the
single-ray walk's leaf test (:func:`.traverse_wide.visit_leaf`, four triangles at once where
the leaves are in lanes) and the constants the packet's set-up left in its lanes: the eight-ray
test computes every lane. Leaves that two rays reached went ray by ray too until the eight-ray
test read its corners in one instruction each (see :mod:`.packet_triangle`); since, testing
them by triangle, time over time before (2026-12-07, one thread, settled calls, medians of 9,
three pairs of processes alternating, closest / any hit): forest camera rays 0.97-1.00 /
0.97-1.03, shadow rays 0.96-0.98 / 0.96-0.99; full dragon camera 0.96-0.99 / 0.97-0.99,
shadow 0.94-0.98 / 0.94-0.97; leaves of one ray by triangle too measured level with that.
A closest-hit packet takes the entered children nearest first and skips an entry popped
beyond the farthest best hit of its rays, which also bounds its node tests; an any-hit packet
drops each ray that found a hit, and stops when none is left. Counting and listing walks take
the packets too (:func:`wide_packet_crossings_kernel`), each ray's crossings going to its own
row.

A packet whose rays point to both sides along some axis has no single near face there:
its rays are walked as packets of one. So are those of a packet of consecutive rays that
holds two groups heading apart (:func:`_lanes_jump`), such as a camera's rays with a patch
left out, where a packet straddles the patch: its interval bounds would hold the space
between the groups (the forest's 1024^2 camera rays that meet its box, given alone, two
threads: closest hit 19.8 -> 9.9 ms, any hit 11.6 -> 6.2; those that miss it 16.6 -> 5.2
and 18.4 -> 4.0). An image's tiles cannot straddle, and skip the test: asked of them, it
cost the forest's camera rays' any hit 8-10 %.

The rays of an image given row after row (:func:`rayaccel.ray_tiles.image_row_length`)
go in packets of four pixels by two, whose directions spread 0.6 times as far as eight
of a row: the walk takes the places of the tile order as its rays, a span being eight
tiles side by side, and reads each packet in place, lanes 0-3 from one row and 4-7 from
the next (full dragon camera rays, two threads: 1.12-1.14 closest / 1.15-1.16 any hit).

Before its rays are loaded as packets, a run of :data:`SPAN` rays is bounded as a whole
(:func:`.packet_slab.bound_span`) and tested against the root's child boxes; a run that
misses them all is answered as misses at once (the "early miss exit" of Wald, Boulos &
Shirley 2007, there for a packet's frustum). Most of a camera's rays may miss the scene: on
the forest 84 % of 1024^2 rays miss its box; the 730 image rows that miss it whole (747,520
rays) took 5.4 ms of packet walk for an any-hit query on one thread, 2.1 ms with the test
(3.5 against 6.8 ms for the closest hit). Forest camera rays on two threads,
medians of 9 in alternating processes: any hit 11.6 -> 9.6 ms, closest hit 22.3 -> 20.5 ms
(the full dragon 34-36 -> 34-35 ms, unchanged). Runs of 16 to 128 rays measured alike.

Rays that start apart but head alike, such as shadow rays from neighbouring hits to one
light, would make the packet's interval bounds loose (measured on the full dragon's: 0.3
of the single walk's speed). Their packets test each ray against the eight child boxes
instead (:func:`.lane_slab.enter_children_by_lane`: for each lane the single-ray walk's
conservative float32 test, :func:`.wide_slab.enter_children`, so the boxes each ray would
enter alone; against the exact float64 test in each lane, one thread, CPU time, shadow rays,
closest / any hit: forest 1.03-1.04 / 1.05-1.06, full dragon 1.04-1.06 / 1.04-1.09), and
push each entered child with the lanes that enter it (the rays' child masks transposed,
Warren's "Hacker's Delight", section 7-3).
Eight rays' tests are independent of each other, so the processor overlaps them, where
the single walk waits for each test before the next fetch; the packet still fetches each
node once. Shadow rays from 1024^2 camera hits, packets against the single walk, closest / any
hit, several runs: one thread, forest 1.32-1.43 / 1.35-1.44, full dragon 1.24 / 1.30; two threads,
full dragon 1.12-1.24 / 1.16-1.24, forest 1.16-1.18 / 1.18-1.23; since the lanes outside a packet's
mask are branched over rather than computed, two threads, one process: full dragon 1.19 / 1.14, forest
1.42 / 1.50. On camera rays the interval bounds win (lane tests there: 0.92-1.12 of them; 0.72-0.89
since).

Batches that neither :func:`rayaccel.ray_order.packets_pay` nor
:func:`rayaccel.ray_order.lane_packets_pay` finds coherent keep the single-ray walk of
:mod:`.traverse_wide`.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..._jit import chunk_kernel, inline_kernel, unsigned
from ..._ray_lanes import splat
from ..._validate import unusable_rays
from ...geometry.gather import stored_corner
from ...geometry.kinds import TRIANGLE
from ...geometry.primitive import ray_setup
from ...ray_tiles import TILE_COLUMNS, TILE_ROWS, first_tile, lane_ray, next_tile, run_rays
from ...rays import ray_at, ray_limit, result_row
from ..actions import NEAREST, finish_misses_in_mode, finish_ray_in_mode
from .lane_slab import (
    bound_lane_slab,
    bound_lane_slabs,
    enter_children_by_lane,
    enter_children_of_lanes,
    narrow_lane_slab,
    set_up_lane_slab,
    set_up_lane_slabs,
)
from .packet_slab import (
    BOUND_BEST,
    BOUND_T_MIN,
    PACKET,
    bound_span,
    enter_child_lanes,
    enter_children_interval,
    load_lane_limits,
    load_lanes,
    load_packet,
    reduce_lanes,
)
from .packet_triangle import HIT_ROW, HIT_ROWS, NOT_SHARED, SHEAR_ROW, hits_by_lane, set_up_shear
from .traverse_wide import push_child, visit_leaf
from .wide import child_count, child_link
from .wide_slab import bit_count, box_reach, highest_bit

__all__ = ["LANE_ROWS", "wide_packet_kernel", "wide_packet_crossings_kernel", "lane_packet_kernel",
           "lane_packet_crossings_kernel"]

SPAN = 8 * PACKET
"""Rays whose common bounds an interval packet walk tests against the root before loading them as packets."""
_LANES_SHIFT = 16
_COUNT_MASK = (1 << _LANES_SHIFT) - 1
_T_MIN = 6 * PACKET
_BEST = 7 * PACKET
_U = 8 * PACKET
_V = 9 * PACKET
_JUMP = 8.0
"""How many times the mean of its other steps a step between neighbouring lanes must be for the
packet's rays to be walked one by one (:func:`_lanes_jump`)."""
_CHILD_TEST_LANES = 6
"""Rays of a lane packet (of eight) that must be walking a node for it to be tested child by child,
all the rays at once (:func:`.lane_slab.enter_children_of_lanes`), rather than ray by ray: at the
top of the tree all eight rays walk most nodes (53 % of the forest's shadow packets' node visits,
39 % of the full dragon's). Shadow rays, one thread, CPU time, medians of 7-9 alternating in one
process, closest / any hit, against ray by ray everywhere: from six rays, forest 1.03-1.05 /
1.05-1.14, full dragon 1.00 / 1.05; from five, forest 1.02 / 1.06, dragon 1.01 / 1.04; from four,
forest 1.00 / 1.06."""
_HIT_T, _HIT_U, _HIT_V = ((HIT_ROW + k) * PACKET for k in range(HIT_ROWS))
_SCALES = (HIT_ROW + HIT_ROWS) * PACKET
LANE_ROWS = HIT_ROW + HIT_ROWS + 2
"""Rows of :data:`PACKET` float64 a packet keeps per thread: the ray state
:func:`.packet_slab.enter_child_lanes` reads, its rays' best ``u`` and ``v``, their
triangle-test constants (:data:`.packet_triangle.SHEAR_ROW`), their hits on the last
triangle tested (:data:`.packet_triangle.HIT_ROW`), then the scales of their float32 box
tests (:func:`.lane_slab.set_up_lane_slab`)."""


@inline_kernel
def _transpose_lanes(word):
    """The 8 x 8 bit matrix ``word`` (byte ``r`` the children lane ``r`` enters) transposed, so
    that byte ``c`` holds the lanes that enter child ``c`` (Warren, "Hacker's Delight", 2nd ed.,
    section 7-3: three exchanges of bit blocks)."""
    x = unsigned(word)
    t = (x ^ (x >> unsigned(7))) & unsigned(0x00AA00AA00AA00AA)
    x = x ^ t ^ (t << unsigned(7))
    t = (x ^ (x >> unsigned(14))) & unsigned(0x0000CCCC0000CCCC)
    x = x ^ t ^ (t << unsigned(14))
    t = (x ^ (x >> unsigned(28))) & unsigned(0x00000000F0F0F0F0)
    x = x ^ t ^ (t << unsigned(28))
    return x


@inline_kernel
def _lanes_by_child(word, lanes):
    """Byte ``c`` the lanes among ``lanes`` that enter child ``c``, from ``word`` (byte ``r`` the
    children lane ``r`` enters): :func:`_transpose_lanes`, or, for a single lane, that lane in every
    byte, which is all a child entered needs, without the transpose. Against transposing always,
    shadow rays, one thread, CPU time, medians of 7-9 alternating in one process, closest / any
    hit: forest 1.02-1.03 / 1.02-1.03, full dragon 1.01-1.02 / 1.01-1.02."""
    if lanes & (lanes - 1) == 0:
        return unsigned(lanes) * unsigned(0x0101010101010101)
    return _transpose_lanes(word)


@inline_kernel
def _any_lane(word):
    """The children (bit ``c``) that some lane of ``word`` (byte ``r`` per lane) enters."""
    x = unsigned(word)
    x |= x >> unsigned(32)
    x |= x >> unsigned(16)
    x |= x >> unsigned(8)
    return np.int64(x & unsigned(0xFF))


@inline_kernel
def _bound_group(state, bounds, group_first, group):
    """Write the interval bounds (rows 0-14 of :data:`.packet_slab.BOUND_VALUES`) of the rays in
    lanes ``group_first`` to ``group_first + group - 1``, whose directions share their signs."""
    for axis in range(3):
        positive = state[(axis + 3) * PACKET + group_first] >= 0.0
        o_low, o_high = np.inf, -np.inf
        inv_low, inv_high = np.inf, -np.inf
        for r in range(group_first, group_first + group):
            o_low = min(o_low, state[axis * PACKET + r])
            o_high = max(o_high, state[axis * PACKET + r])
            inv_low = min(inv_low, state[(axis + 3) * PACKET + r])
            inv_high = max(inv_high, state[(axis + 3) * PACKET + r])
        bounds[5 * axis] = axis if positive else axis + 3
        bounds[5 * axis + 1] = o_high if positive else o_low
        bounds[5 * axis + 2] = o_low if positive else o_high
        bounds[5 * axis + 3] = inv_low
        bounds[5 * axis + 4] = inv_high


@inline_kernel
def _lanes_jump(directions, packet_first, packet_second):
    """Whether the directions of a full packet's rays, normalised, step from one lane to the next
    more than :data:`_JUMP` times as far, somewhere, as the mean of the other steps: two groups
    of rays heading apart, such as the ends of two rows, whose interval bounds would hold the
    space between them."""
    longest = 0.0
    total = 0.0
    px, py, pz = 0.0, 0.0, 0.0
    for r in range(PACKET):
        i = lane_ray(packet_first, r, packet_second)
        dx, dy, dz = np.float64(directions[i, 0]), np.float64(directions[i, 1]), np.float64(directions[i, 2])
        scale = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
        dx, dy, dz = dx * scale, dy * scale, dz * scale
        if r > 0:
            step = (dx - px) ** 2 + (dy - py) ** 2 + (dz - pz) ** 2
            total += step
            longest = max(longest, step)
        px, py, pz = dx, dy, dz
    return longest > _JUMP * _JUMP * (total - longest) / (PACKET - 2)


@intrinsic
def _finish_packet(typingctx, hit, prim, geom, t, u, v, first, second, state, best_prim):
    """Write a full packet's answers as :func:`..actions.finish_ray_in_mode` writes a closest or any
    hit's, lanes 0-3 to rows ``first`` to ``first + 3`` and lanes 4-7 to rows ``second`` to
    ``second + 3`` of each output array that is not empty (``hit``, ``prim``, ``geom``, ``t``,
    ``u``, ``v``: :class:`..actions.Action`'s), four rows a vector store, from the best distances
    and barycentrics in ``state`` and the primitives in ``best_prim``. Against the rays written one
    by one, the same answers, settled calls, medians of 9, processes alternating (2026-12-07, Intel
    host with AVX-512), time over time before, closest / any hit: forest camera rays one thread
    0.94-1.00 / 0.93-0.97, two threads 0.91-0.97 / 0.86-0.95; its shadow rays 0.94-1.00 / 0.95-0.99
    and 0.88-1.00 / 0.95-0.98; the full dragon's 0.98-1.02 (its packets' rays mostly end alone)."""
    arrays = (hit, prim, geom, t, u, v)
    if not all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" for a in arrays):
        return None
    signature = types.void(hit, prim, geom, t, u, v, first, second, state, best_prim)

    def codegen(context, builder, sig, args):
        intp = context.get_value_type(types.intp)
        int64 = ir.IntType(64)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        state_rows = builder.bitcast(context.make_array(sig.args[8])(context, builder, args[8]).data,
                                     doubles.as_pointer())
        best, best_u, best_v = (builder.load(builder.gep(state_rows, [ir.Constant(intp, row // PACKET)]), align=8)
                                for row in (_BEST, _U, _V))
        prim_rows = context.make_array(sig.args[9])(context, builder, args[9]).data
        prims = builder.load(builder.bitcast(prim_rows, ir.VectorType(int64, PACKET).as_pointer()), align=8)
        zero = ir.Constant(ir.VectorType(int64, PACKET), [0] * PACKET)
        hit_lanes = builder.icmp_signed(">=", prims, zero)

        def on_hit(value, otherwise):
            return builder.select(hit_lanes, value, ir.Constant(doubles, [otherwise] * PACKET))

        values = (builder.zext(hit_lanes, ir.VectorType(ir.IntType(8), PACKET)), prims,
                  builder.select(hit_lanes, zero, prims), on_hit(best, float("inf")), on_hit(best_u, float("nan")),
                  on_hit(best_v, float("nan")))
        rows = [context.cast(builder, args[k], sig.args[k], types.intp) for k in (6, 7)]
        halves = [ir.Constant(ir.VectorType(ir.IntType(32), TILE_COLUMNS), list(range(k, k + TILE_COLUMNS)))
                  for k in (0, TILE_COLUMNS)]
        for array_type, array, vector in zip(sig.args[:6], args[:6], values):
            out = context.make_array(array_type)(context, builder, array)
            four = ir.VectorType(vector.type.element, TILE_COLUMNS)
            with builder.if_then(builder.icmp_signed(">", builder.extract_value(out.shape, 0), ir.Constant(intp, 0))):
                for row, lanes in zip(rows, halves):
                    pointer = builder.bitcast(builder.gep(out.data, [row]), four.as_pointer())
                    builder.store(builder.shuffle_vector(vector, vector, lanes), pointer,
                                  align=context.get_abi_alignment(vector.type.element))
        return context.get_dummy_value()

    return signature, codegen


@intrinsic
def _keep_closer_hits(typingctx, state, best_prim, hit, prim):
    """Keep primitive ``prim``'s hits on the lanes of ``hit`` (bit ``r`` for lane ``r``; their ``t``,
    ``u`` and ``v`` in the rows from :data:`.packet_triangle.HIT_ROW` on) as each lane's best where
    :func:`..actions.is_closer` takes them, all lanes at once: the rows of the best distances and
    barycentrics in ``state`` and ``best_prim`` blended. Returns the lanes whose best changed."""
    signature = types.int64(state, best_prim, hit, prim)

    def codegen(context, builder, sig, args):
        intp = context.get_value_type(types.intp)
        int64 = ir.IntType(64)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        longs = ir.VectorType(int64, PACKET)
        state_rows = builder.bitcast(context.make_array(sig.args[0])(context, builder, args[0]).data,
                                     doubles.as_pointer())
        rows = {row: builder.gep(state_rows, [ir.Constant(intp, row // PACKET)])
                for row in (_BEST, _U, _V, _HIT_T, _HIT_U, _HIT_V)}
        values = {row: builder.load(pointer, align=8) for row, pointer in rows.items()}
        prim_pointer = builder.bitcast(context.make_array(sig.args[1])(context, builder, args[1]).data,
                                       longs.as_pointer())
        kept_prims = builder.load(prim_pointer, align=8)
        hit_bits = builder.trunc(context.cast(builder, args[2], sig.args[2], types.int64), ir.IntType(PACKET))
        hit_lanes = builder.bitcast(hit_bits, ir.VectorType(ir.IntType(1), PACKET))
        prims = splat(builder, context.cast(builder, args[3], sig.args[3], types.int64), longs)
        t, best = values[_HIT_T], values[_BEST]
        tie = builder.and_(builder.fcmp_ordered("==", t, best), builder.icmp_signed("<", prims, kept_prims))
        better = builder.or_(builder.or_(builder.icmp_signed("<", kept_prims, ir.Constant(longs, [0] * PACKET)),
                                         builder.fcmp_ordered("<", t, best)), tie)
        finite = builder.fcmp_ordered("!=", t, ir.Constant(doubles, [float("inf")] * PACKET))
        closer = builder.and_(builder.and_(hit_lanes, finite), better)
        for kept, found in ((_BEST, _HIT_T), (_U, _HIT_U), (_V, _HIT_V)):
            builder.store(builder.select(closer, values[found], values[kept]), rows[kept], align=8)
        builder.store(builder.select(closer, prims, kept_prims), prim_pointer, align=8)
        return builder.zext(builder.bitcast(closer, ir.IntType(PACKET)), int64)

    return signature, codegen


@intrinsic
def _nearest_start_farthest_best(typingctx, state):
    """The smallest ``t_min`` and the farthest best distance of a packet's eight rays (rows
    :data:`_T_MIN` and :data:`_BEST` of ``state``), each row reduced in vector instructions."""
    signature = types.UniTuple(types.float64, 2)(state)

    def codegen(context, builder, sig, args):
        intp = context.get_value_type(types.intp)
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        rows = builder.bitcast(context.make_array(sig.args[0])(context, builder, args[0]).data, doubles.as_pointer())
        t_min, best = (builder.load(builder.gep(rows, [ir.Constant(intp, row // PACKET)]), align=8)
                       for row in (_T_MIN, _BEST))
        return context.make_tuple(builder, sig.return_type,
                                  (reduce_lanes(builder, t_min, "<"), reduce_lanes(builder, best, ">")))

    return signature, codegen


@inline_kernel
def _packet_limits(state, group_first, group):
    """The smallest ``t_min`` and the farthest best distance of the rays in lanes ``group_first``
    to ``group_first + group - 1``."""
    if group == PACKET:
        return _nearest_start_farthest_best(state)
    nearest_start, farthest_best = np.inf, -np.inf
    for r in range(group_first, group_first + group):
        nearest_start = min(nearest_start, state[_T_MIN + r])
        farthest_best = max(farthest_best, state[_BEST + r])
    return nearest_start, farthest_best


@inline_kernel
def _keep_lane_hit(state, best_prim, r, best_t, prim_r, best_u, best_v):
    """Store lane ``r``'s best hit when the leaf changed it; returns whether it did."""
    if prim_r == best_prim[r] and best_t == state[_BEST + r]:
        return False
    state[_BEST + r] = best_t
    best_prim[r] = prim_r
    state[_U + r] = best_u
    state[_V + r] = best_v
    return True


@inline_kernel
def _sheared_lane(state, r, kx, ky, kz):
    """Lane ``r``'s ray as :func:`rayaccel.geometry.primitive.ray_setup` gives it to the triangle test,
    from the constants :func:`.packet_triangle.set_up_shear` wrote for a packet whose rays share the
    axes ``kx, ky, kz`` (the direction, which the triangle test does not read, left 0)."""
    return (state[r], state[PACKET + r], state[2 * PACKET + r], 0.0, 0.0, 0.0, kx, ky, kz,
            state[SHEAR_ROW * PACKET + r], state[(SHEAR_ROW + 1) * PACKET + r], state[(SHEAR_ROW + 5) * PACKET + r],
            state[(SHEAR_ROW + 2) * PACKET + r], state[(SHEAR_ROW + 3) * PACKET + r],
            state[(SHEAR_ROW + 4) * PACKET + r])


@inline_kernel
def _leaf_lane_after_lane(mode, action, hit_slot, kind, geom, prim_order, first, count, origins, directions,
                          packet_first, packet_second, lanes, done, state, best_prim, any_hit, sheared, kx, ky, kz):
    """Visit the ``count`` primitives of a leaf from row ``first`` on with each ray of ``lanes`` in
    turn, as the single-ray walk does (:func:`.traverse_wide.visit_leaf`), the packet's rays those of
    :func:`rayaccel.ray_tiles.lane_ray`, set up from the packet's state when ``sheared`` (their
    shared triangle-test axes ``kx, ky, kz``); returns ``done`` with the lanes of an any-hit walk
    that found a hit added, and whether some lane's best hit changed."""
    improved = False
    remaining = lanes
    while remaining != 0:
        r = highest_bit(remaining)
        remaining ^= 1 << r
        i = lane_ray(packet_first, r, packet_second)
        if sheared:
            ray = _sheared_lane(state, r, kx, ky, kz)
        else:
            ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
            ray = ray_setup(ox, oy, oz, dx, dy, dz)
        best_t, prim_r, best_u, best_v, _ = visit_leaf(mode, action, result_row(hit_slot, i), kind, geom, prim_order,
                                                       first, count, ray, state[_T_MIN + r], state[_BEST + r],
                                                       best_prim[r], state[_U + r], state[_V + r], any_hit)
        if any_hit and prim_r >= 0:
            done |= 1 << r
        improved |= _keep_lane_hit(state, best_prim, r, best_t, prim_r, best_u, best_v)
    return done, improved


@inline_kernel
def _leaf_by_triangle(geom, prim_order, first, count, lanes, done, kx, ky, kz, state, best_prim, any_hit):
    """:func:`_leaf_lane_after_lane` for a closest-hit or any-hit walk over triangles whose rays
    share the triangle test's axes ``kx, ky, kz`` (their constants set up by
    :func:`.packet_triangle.set_up_shear`): each triangle tested on all the live rays at once
    (:func:`.packet_triangle.hits_by_lane`), its hits kept as :func:`..actions.visit_prim_in_mode`
    keeps a hit, on all the lanes at once (:func:`_keep_closer_hits`). Against keeping them lane
    after lane, a branch and a comparison a lane that hit, time over time before (2026-12-07, settled
    calls, medians of 9, processes alternating), closest / any hit: forest camera rays one thread
    0.90-0.92 / 0.89-0.92 (three pairs), two threads 0.89-0.90 / 0.92-0.95; its shadow rays
    0.98-1.00 / 0.97-1.00; full dragon camera 0.98-0.99 / 0.99, shadow level."""
    improved = False
    for k in range(first, first + count):
        live = lanes & ~done
        if live == 0:
            break
        hit = hits_by_lane(state, live, stored_corner(geom, k, 0, kx), stored_corner(geom, k, 0, ky),
                           stored_corner(geom, k, 0, kz), stored_corner(geom, k, 1, kx), stored_corner(geom, k, 1, ky),
                           stored_corner(geom, k, 1, kz), stored_corner(geom, k, 2, kx), stored_corner(geom, k, 2, ky),
                           stored_corner(geom, k, 2, kz))
        if hit == 0:
            continue
        closer = _keep_closer_hits(state, best_prim, hit, prim_order[unsigned(k)])
        if closer != 0:
            improved = True
            if any_hit:
                done |= closer
    return done, improved


@inline_kernel
def _root_culls_span(records, t_min, t_max, span_first, span_second, bounds, child_entry):
    """Whether the :data:`SPAN` rays of the runs from ``span_first`` and ``span_second`` (half of
    them each), whose interval bounds :func:`.packet_slab.bound_span` wrote into ``bounds``, miss
    every child box of the root."""
    t_low, t_high = ray_limit(t_min, span_first), ray_limit(t_max, span_first)
    if t_min.shape[0] > 1 or t_max.shape[0] > 1:
        for run in (span_first, span_second):
            for i in range(run, run + SPAN // 2):
                t_low = min(t_low, ray_limit(t_min, i))
                t_high = max(t_high, ray_limit(t_max, i))
    bounds[BOUND_T_MIN] = t_low
    bounds[BOUND_BEST] = t_high
    return enter_children_interval(records, 0, bounds, child_entry) == 0


@inline_kernel
def _packet_walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins, directions, t_min,
                 t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry, lanes_state, lanes_slab,
                 bounds_state, lanes_prim, row_length, by_lane, mode, action):
    """Trace rays ``ray_first`` to ``ray_end - 1`` in packets of :data:`PACKET` consecutive rays
    (the last one partial), with the stacks, child entries, lane state, lane slabs and packet
    bounds of row ``tid``, each stack entry's lanes kept above its primitive count in
    ``stack_count``; ``geom`` in leaf order, ``links`` the records seen as int32 (see
    :mod:`.traverse_wide`), row 0 of ``root_box`` the whole tree's box, which bounds the boxes'
    coordinates for the float32 tests of ``by_lane`` packets (:func:`.wide_slab.box_reach`).
    With a ``row_length`` other than 0 the rays are an image's rows of that length (a multiple
    of ``SPAN // 2``), ``ray_first`` and ``ray_end`` places in its tile order
    (:func:`rayaccel.ray_tiles.tile_ray`): a span is then eight tiles side by side, two runs of
    ``SPAN // 2`` rays a row apart, and a packet one tile, read in place. Each primitive a ray
    meets gets the leaf action of ``mode`` (:mod:`..actions`). The rays of each span are checked
    first, by their interval bounds where the walk takes them (:func:`.packet_slab.bound_span`), else
    one by one (:func:`rayaccel._validate.unusable_rays`), just before the walk reads them again; a
    span holding an unusable ray is left unwalked, answered as misses. Returns how many unusable
    rays there were."""
    child_entry = entry[tid]
    state = lanes_state[tid]
    slabs = lanes_slab[tid]
    scales = state[_SCALES:]
    reach_x, reach_y, reach_z = box_reach(root_box[0, :3], root_box[0, 3:6])
    bounds = bounds_state[tid]
    best_prim = lanes_prim[tid]
    nearest_first = not any_hit and mode == NEAREST
    lane_triangles = mode == NEAREST and kind == TRIANGLE
    tiled_rays, next_tiled, column = first_tile(ray_first, row_length, directions.shape[0])
    unusable = 0
    for place in range(ray_first, ray_end, SPAN):
        span_rays = min(SPAN, ray_end - place)
        if place < tiled_rays:
            span_first = next_tiled
            span_second = span_first + row_length
            packet_step, lane_offset = TILE_COLUMNS, row_length
            next_tiled, column = next_tile(next_tiled, column, SPAN // TILE_ROWS, row_length)
        else:
            span_first = place
            span_second = place + SPAN // 2
            packet_step, lane_offset = PACKET, TILE_COLUMNS
        checked = not by_lane and span_rays == SPAN and bound_span(origins, directions, span_first, span_second,
                                                                   SPAN // PACKET, bounds) == 0
        culled = checked and _root_culls_span(records, t_min, t_max, span_first, span_second, bounds, child_entry)
        unusable_here = 0
        if not checked:
            for run in range(TILE_ROWS):
                run_first, run_end = run_rays(span_first, span_second, span_rays, SPAN // 2, run)
                unusable_here += unusable_rays(origins, directions, run_first, run_end)
        if unusable_here or culled:
            unusable += unusable_here
            for run in range(TILE_ROWS):
                run_first, run_end = run_rays(span_first, span_second, span_rays, SPAN // 2, run)
                finish_misses_in_mode(mode, action, hit_slot, run_first, run_end)
            continue
        for packet in range(0, span_rays, PACKET):
            packet_first = span_first + (packet // PACKET) * packet_step
            packet_second = packet_first + lane_offset
            n_lanes = min(PACKET, span_rays - packet)
            loaded = n_lanes == PACKET
            if loaded and by_lane:
                mixed = load_lanes(origins, directions, packet_first, packet_second, state) != 0
            elif loaded:
                mixed = load_packet(origins, directions, packet_first, packet_second, state, bounds) != 0
                mixed = mixed or (packet_step == PACKET and _lanes_jump(directions, packet_first, packet_second))
            else:
                mixed = False
                for r in range(PACKET):
                    ray = ray_at(origins, directions, lane_ray(packet_first, min(r, n_lanes - 1), packet_second))
                    for axis in range(3):
                        inverse = 1.0 / ray[axis + 3]
                        state[axis * PACKET + r] = ray[axis]
                        state[(axis + 3) * PACKET + r] = inverse
                        mixed |= (inverse >= 0.0) != (state[(axis + 3) * PACKET] >= 0.0)
            if loaded:
                load_lane_limits(t_min, t_max, packet_first, packet_second, state)
                if by_lane:
                    set_up_lane_slabs(origins, directions, packet_first, packet_second, state, slabs, scales,
                                      reach_x, reach_y, reach_z)
                    bound_lane_slabs(slabs, scales, state)
            for r in range(PACKET):
                best_prim[r] = -1
                state[_U + r] = 0.0
                state[_V + r] = 0.0
                if not loaded:
                    i = lane_ray(packet_first, min(r, n_lanes - 1), packet_second)
                    state[_T_MIN + r] = ray_limit(t_min, i)
                    state[_BEST + r] = ray_limit(t_max, i)
                    if by_lane:
                        ox, oy, oz, dx, dy, dz = ray_at(origins, directions, i)
                        set_up_lane_slab(slabs, scales, r, ox, oy, oz, dx, dy, dz, state[3 * PACKET + r],
                                         state[4 * PACKET + r], state[5 * PACKET + r], reach_x, reach_y, reach_z)
                        bound_lane_slab(slabs, scales, r, state[_T_MIN + r], state[_BEST + r])
            lanes_set_up = False
            shared_axes, kx, ky, kz = False, 0, 0, 0
            near_x = 0 if state[3 * PACKET] >= 0.0 else 3
            near_y = 1 if state[4 * PACKET] >= 0.0 else 4
            near_z = 2 if state[5 * PACKET] >= 0.0 else 5
            group = 1 if mixed and not by_lane else n_lanes
            for group_first in range(0, n_lanes, group):
                active = ((1 << group) - 1) << group_first
                if not (by_lane or (loaded and not mixed)):
                    _bound_group(state, bounds, group_first, group)
                packet_t_min, farthest_best = _packet_limits(state, group_first, group)
                bounds[BOUND_T_MIN] = packet_t_min
                bounds[BOUND_BEST] = farthest_best
                done = 0
                node = 0
                lanes = active
                sp = 0
                while True:
                    if node >= 0:
                        if by_lane and not mixed and bit_count(lanes) >= _CHILD_TEST_LANES:
                            children, lanes_by_child = enter_children_of_lanes(records, node, slabs, scales, lanes,
                                                                               child_entry, not any_hit, near_x,
                                                                               near_y, near_z)
                        elif by_lane:
                            lane_children = enter_children_by_lane(records, node, slabs, scales, lanes, child_entry)
                            children = _any_lane(lane_children)
                            lanes_by_child = _lanes_by_child(lane_children, lanes)
                        else:
                            children = enter_children_interval(records, node, bounds, child_entry)
                            lanes_by_child = unsigned(0)
                        base = sp
                        descend = -1
                        while children != 0:
                            c = highest_bit(children)
                            children ^= 1 << c
                            link = child_link(links, node, c)
                            count = child_count(links, node, c)
                            child_lanes = lanes
                            if by_lane:
                                child_lanes = np.int64((lanes_by_child >> unsigned(8 * c)) & unsigned(0xFF))
                            if count == 0:
                                if children == 0 and sp == base:
                                    descend = link
                                    lanes = child_lanes
                                    break
                            elif not by_lane:
                                child_lanes = enter_child_lanes(records, node, c, state, lanes)
                                if child_lanes == 0:
                                    continue
                            sp = push_child(records, geom, stack_link, stack_count, stack_t, tid, base, sp,
                                            child_entry[c], link, count, count | (child_lanes << _LANES_SHIFT),
                                            nearest_first)
                        if descend >= 0:
                            node = descend
                            continue
                    node = -1
                    while sp > 0:
                        sp -= 1
                        word = stack_count[tid, sp]
                        lanes = (word >> _LANES_SHIFT) & ~done
                        if lanes == 0 or stack_t[tid, sp] > bounds[BOUND_BEST]:
                            continue
                        count = word & _COUNT_MASK
                        if count == 0:
                            node = stack_link[tid, sp]
                            break
                        first = stack_link[tid, sp]
                        if lane_triangles and not lanes_set_up:
                            axes = set_up_shear(origins, directions, packet_first, packet_second, state) if loaded \
                                else NOT_SHARED
                            shared_axes = axes != NOT_SHARED
                            kx, ky, kz = axes & 3, (axes >> 2) & 3, axes >> 4
                            lanes_set_up = True
                        if lane_triangles and shared_axes and lanes & (lanes - 1) != 0:
                            done, improved = _leaf_by_triangle(geom, prim_order, first, count, lanes, done, kx, ky,
                                                               kz, state, best_prim, any_hit)
                        else:
                            done, improved = _leaf_lane_after_lane(mode, action, hit_slot, kind, geom, prim_order,
                                                                   first, count, origins, directions, packet_first,
                                                                   packet_second, lanes, done, state, best_prim,
                                                                   any_hit, lane_triangles and shared_axes, kx, ky, kz)
                        if any_hit and done == active:
                            sp = 0
                            break
                        if improved and not any_hit:
                            farthest_best = _packet_limits(state, group_first, group)[1]
                            if by_lane:
                                for r in range(group_first, group_first + group):
                                    narrow_lane_slab(slabs, scales, r, state[_BEST + r])
                            bounds[BOUND_BEST] = farthest_best
                    if node < 0:
                        break
            if loaded and mode == NEAREST and hit_slot.shape[0] == 0:
                _finish_packet(action.hit, action.prim, action.geom, action.t, action.u, action.v, packet_first,
                               packet_second, state, best_prim)
                continue
            for r in range(n_lanes):
                finish_ray_in_mode(mode, action, result_row(hit_slot, lane_ray(packet_first, r, packet_second)),
                                   state[_BEST + r],
                                   best_prim[r], state[_U + r], state[_V + r])
    return unusable


@chunk_kernel
def wide_packet_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                       directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                       lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, action):
    """The closest-hit and any-hit packet walk (an action of mode ``NEAREST``; the other modes'
    code is pruned before it is compiled, as in :func:`.traverse_wide.wide_nearest_kernel`)."""
    return _packet_walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                        directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                        lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, False, NEAREST, action)


@chunk_kernel
def wide_packet_crossings_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                                 directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                                 lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, action):
    """The packet walk for the other actions (counting, listing), compiled at their first use."""
    return _packet_walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                        directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                        lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, False, action.mode, action)


@chunk_kernel
def lane_packet_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                       directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                       lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, action):
    """The closest-hit and any-hit walk of packets whose rays are tested lane by lane (the other
    modes' code pruned, as in :func:`wide_packet_kernel`)."""
    return _packet_walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                        directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                        lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, True, NEAREST, action)


@chunk_kernel
def lane_packet_crossings_kernel(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                                 directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                                 lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, action):
    """The walk of packets tested lane by lane for the other actions (counting, listing), compiled
    at their first use."""
    return _packet_walk(ray_first, ray_end, tid, root_box, records, links, prim_order, kind, geom, origins,
                        directions, t_min, t_max, hit_slot, any_hit, stack_link, stack_count, stack_t, entry,
                        lanes_state, lanes_slab, bounds_state, lanes_prim, row_length, True, action.mode, action)
