"""Packets of eight rays through the kd-tree, closest hit and any hit.

Wald, Slusallek, Benthin & Wagner, "Interactive Rendering with Coherent Ray
Tracing" (Eurographics 2001), trace coherent rays through a kd-tree in packets:
rays whose directions share their signs meet every split plane from the same
side, so they agree on which child is near. The packet then walks one path
through the tree, each ray (lane) with its own interval ``[t0, t1]`` inside
the current cell and a mask of the lanes still inside it. At an inner node each
lane computes its plane distance, as the single-ray walk
(:mod:`.traverse`) does with the same margins; the lanes that reach the far
side go on the stack with their far intervals, the others follow the packet to
the near side, and the packet goes far only if no lane goes near. A leaf tests
its primitives with each of its live lanes in turn, with the single-ray test,
so every ray gets the single walk's hits; a stacked cell is entered by the
lanes whose best hit does not already lie before it (:func:`..base.settled_before`).
One node fetch and one branch per step serve all eight rays, where the single
walk pays a dependent fetch and a hard-to-predict branch per ray and step.
Against the single walk, one thread, medians of 5, closest / any hit: full
dragon camera rays 1.26 / 1.28, shadow rays 1.25 / 1.28; forest-small-chair
1.19 / 1.20 and 1.25 / 1.26. With the split in scalar code, a loop over the
lanes, the packets gained only 1.00-1.10 on camera and shadow rays (bunny,
forest); passing empty leaves without visiting the lanes raised the bunny's
1.26-1.30 to 1.39-1.48.

A packet whose rays head to both sides along some axis, or lie parallel to an
axis, has no common near side: its rays take the single-ray walk.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..._jit import chunk_kernel, inline_kernel, unsigned
from ..._ray_lanes import LANES, splat
from ...geometry.box import clip_to_box
from ...geometry.primitive import ray_setup
from ...ray_tiles import TILE_COLUMNS, TILE_ROWS, first_tile, lane_ray, next_tile, run_rays
from ...rays import ray_limit, result_row
from ..actions import NEAREST, finish_ray_in_mode
from ..base import EXIT_MARGIN, settled_before
from ..bvh.wide_slab import highest_bit
from .layout import LEAF, PLANE_FLOOR, PLANE_STEP, leaf_first, node_child, node_plane, node_word
from .traverse import empty_children_of, is_empty_child, meets_apart, visit_references, walk_singly

__all__ = ["PACKET", "PACKET_ROWS", "kdtree_packet_kernel"]

PACKET = LANES
"""Rays per packet, one per vector lane."""
_O = 0
_INV = 3 * PACKET
_T0 = 6 * PACKET
_T1 = 7 * PACKET
_T_MIN = 8 * PACKET
_BEST = 9 * PACKET
_U = 10 * PACKET
_V = 11 * PACKET
PACKET_ROWS = 12
"""Rows of :data:`PACKET` float64 a packet keeps per thread: its rays' origins and reciprocal
directions by axis, their intervals in the current cell, their ``t_min`` and best hits."""


@inline_kernel
def _load_packet(lo, hi, origins, directions, t_min, t_max, packet_first, packet_second, n_lanes, state, best_prim):
    """Load the rays of a packet (:func:`rayaccel.ray_tiles.lane_ray`) into ``state`` and clip them
    to the tree's box: ``(lanes, positive, coherent)``, the lanes whose ray meets the box, the
    sign of each axis's direction (bit ``axis`` set where positive) and whether all rays share
    those signs, each direction component with a finite reciprocal (no zero or subnormal one)."""
    lanes = 0
    positive = 0
    coherent = True
    for r in range(PACKET):
        state[_T0 + r] = 0.0
        state[_T1 + r] = 0.0
        best_prim[r] = -1
        state[_U + r] = 0.0
        state[_V + r] = 0.0
    for r in range(n_lanes):
        i = lane_ray(packet_first, r, packet_second)
        ray_t_min, ray_t_max = ray_limit(t_min, i), ray_limit(t_max, i)
        state[_T_MIN + r] = ray_t_min
        state[_BEST + r] = ray_t_max
        signs = 0
        for axis in range(3):
            d = directions[i, axis]
            inverse = 1.0 / d
            state[_O + axis * PACKET + r] = origins[i, axis]
            state[_INV + axis * PACKET + r] = inverse
            coherent &= abs(inverse) < np.inf
            signs |= (d > 0.0) << axis
        if r == 0:
            positive = signs
        coherent &= signs == positive
        t0, t1 = clip_to_box(lo, hi, origins[i, 0], origins[i, 1], origins[i, 2], directions[i, 0],
                             directions[i, 1], directions[i, 2], ray_t_min, ray_t_max)
        if t0 <= t1:
            lanes |= 1 << r
            state[_T0 + r] = t0
            state[_T1 + r] = t1
    return lanes, positive, coherent


@intrinsic
def _split_lanes(typingctx, state, axis, plane, slot_t):
    """Cut the eight lanes' intervals at a node's ``plane`` on ``axis`` (the bottom of the plane's
    bracket, :func:`.layout.plane_bracket`), in vector lanes: the far intervals go to ``slot_t``
    (a stack slot: the eight ``t0``, then the eight ``t1``), and each lane keeps the near part
    as its current interval in ``state``. Returns the lanes that reach the near side in bits
    0-7 and those that reach the far side in bits 8-15: the single walk's choice
    (:func:`.traverse.cross_split`) with its arithmetic, lane by lane."""
    signature = types.int64(state, axis, plane, slot_t)

    def codegen(context, builder, sig, args):
        state_value, axis_value, plane_value, slot_value = args
        doubles = ir.VectorType(ir.DoubleType(), PACKET)
        intp = context.get_value_type(types.intp)
        state_data = context.make_array(sig.args[0])(context, builder, state_value).data
        slot_data = context.make_array(sig.args[3])(context, builder, slot_value).data
        row = context.cast(builder, axis_value, sig.args[1], types.intp)

        def lanes_at(data, offset):
            return builder.bitcast(builder.gep(data, [offset]), doubles.as_pointer())

        def row_at(first):
            return ir.Constant(intp, first)

        origin = builder.load(lanes_at(state_data, builder.add(row_at(_O), builder.mul(row, row_at(PACKET)))), align=8)
        inverse = builder.load(lanes_at(state_data, builder.add(row_at(_INV), builder.mul(row, row_at(PACKET)))),
                               align=8)
        t0 = builder.load(lanes_at(state_data, row_at(_T0)), align=8)
        t1 = builder.load(lanes_at(state_data, row_at(_T1)), align=8)
        fabs = cgutils.get_or_insert_function(builder.module, ir.FunctionType(doubles, [doubles]), "llvm.fabs.v8f64")

        def constant(value):
            return splat(builder, ir.Constant(ir.DoubleType(), value), doubles)

        margin = constant(EXIT_MARGIN)
        plane = splat(builder, plane_value, doubles)
        t_plane = builder.fmul(builder.fsub(plane, origin), inverse)
        step = builder.fmul(constant(PLANE_STEP), builder.call(fabs, [inverse]))
        width = builder.fmul(builder.fadd(builder.call(fabs, [plane]), constant(PLANE_FLOOR)), step)
        positive = builder.fcmp_ordered(">", inverse, constant(0.0))
        t_exit = builder.select(positive, builder.fadd(t_plane, width), t_plane)
        t_entry = builder.select(positive, t_plane, builder.fsub(t_plane, width))
        low = builder.fsub(t0, builder.fmul(margin, builder.call(fabs, [t0])))
        high = builder.fadd(t1, builder.fmul(margin, builder.call(fabs, [t1])))
        goes_near = builder.fcmp_unordered(">=", t_exit, low)
        goes_far = builder.fcmp_unordered("<=", t_entry, high)

        def clamped(t):
            above_t0 = builder.select(builder.fcmp_ordered(">", t, t0), t, t0)
            return builder.select(builder.fcmp_ordered("<", above_t0, t1), above_t0, t1)

        builder.store(builder.select(goes_near, clamped(t_entry), t0), lanes_at(slot_data, row_at(0)), align=8)
        builder.store(t1, lanes_at(slot_data, row_at(PACKET)), align=8)
        builder.store(builder.select(goes_far, clamped(t_exit), t1), lanes_at(state_data, row_at(_T1)), align=8)
        int64 = ir.IntType(64)
        near_bits = builder.zext(builder.bitcast(goes_near, ir.IntType(PACKET)), int64)
        far_bits = builder.zext(builder.bitcast(goes_far, ir.IntType(PACKET)), int64)
        return builder.or_(near_bits, builder.shl(far_bits, int64(PACKET)))

    return signature, codegen


@inline_kernel
def _pop_lanes(state, best_prim, stack_node, stack_lanes, stack_t, tid, sp, done):
    """The next stacked cell some lane must still enter: ``(node, lanes, sp)``, its intervals
    restored into ``state``; ``node = -1`` when none is left. A lane drops out of a cell
    that starts after its best hit, or once an any-hit walk has its hit (``done``)."""
    row = unsigned(tid)
    while sp > 0:
        sp -= 1
        slot = unsigned(sp)
        lanes = stack_lanes[row, slot] & ~done
        remaining = lanes
        while remaining != 0:
            r = highest_bit(remaining)
            remaining ^= 1 << r
            if settled_before(best_prim[r], state[_BEST + r], stack_t[row, slot, r]):
                lanes ^= 1 << r
        if lanes != 0:
            for r in range(PACKET):
                state[_T0 + r] = stack_t[row, slot, r]
                state[_T1 + r] = stack_t[row, slot, PACKET + r]
            return stack_node[row, slot], lanes, sp
    return -1, 0, sp


@inline_kernel
def _visit_leaf_lanes(action, hit_slot, first, end, leaf_prims, mailbox, tid, ray_id_base, kind, geom, origins,
                      directions, packet_first, packet_second, lanes, done, state, best_prim, any_hit):
    """Test the leaf's references ``first`` to ``end - 1`` with each ray of ``lanes`` in turn, as
    the single-ray walk does (each ray its own mailbox stamp, where there is a mailbox); returns
    ``done`` with the lanes of an any-hit walk that found a hit."""
    remaining = lanes
    while remaining != 0:
        r = highest_bit(remaining)
        remaining ^= 1 << r
        i = lane_ray(packet_first, r, packet_second)
        ray = ray_setup(origins[i, 0], origins[i, 1], origins[i, 2], directions[i, 0], directions[i, 1],
                        directions[i, 2])
        best_t, prim, best_u, best_v, _ = visit_references(
            NEAREST, action, result_row(hit_slot, i), first, end, leaf_prims, mailbox, tid, ray_id_base + i, kind,
            geom, ray, state[_T_MIN + r], state[_BEST + r], best_prim[r], state[_U + r], state[_V + r], any_hit)
        state[_BEST + r] = best_t
        best_prim[r] = prim
        state[_U + r] = best_u
        state[_V + r] = best_v
        if any_hit and prim >= 0:
            done |= 1 << r
    return done


@inline_kernel
def _visit_apart_lanes(action, hit_slot, apart_first, apart_box, leaf_prims, mailbox, tid, ray_id_base, kind, geom,
                       origins, directions, packet_first, packet_second, n_lanes, lanes, state, best_prim, any_hit):
    """Visit the primitives kept apart from the tree (:func:`.traverse.visit_apart`) with each of the
    packet's ``n_lanes`` rays that meets their box, and end each ray's interval in the tree at its
    hit: returns the lanes of ``lanes`` still to walk, without those whose hit lies before their
    cell and those an any-hit walk has settled."""
    meeting = 0
    for r in range(n_lanes):
        i = lane_ray(packet_first, r, packet_second)
        if meets_apart(apart_box, origins[i, 0], origins[i, 1], origins[i, 2], directions[i, 0], directions[i, 1],
                       directions[i, 2], state[_T_MIN + r], state[_BEST + r]):
            meeting |= 1 << r
    if meeting == 0:
        return lanes
    done = _visit_leaf_lanes(action, hit_slot, apart_first, leaf_prims.shape[0], leaf_prims, mailbox, tid,
                             ray_id_base, kind, geom, origins, directions, packet_first, packet_second, meeting, 0,
                             state, best_prim, any_hit)
    lanes &= ~done
    remaining = lanes
    while remaining != 0:
        r = highest_bit(remaining)
        remaining ^= 1 << r
        state[_T1 + r] = min(state[_T1 + r], state[_BEST + r])
        if state[_T0 + r] > state[_T1 + r]:
            lanes ^= 1 << r
    return lanes


@chunk_kernel
def kdtree_packet_kernel(ray_first, ray_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims,
                         apart_first, apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                         mailbox, ray_id_base, stack_node, stack_t, inv_dir, packet_lanes, packet_t, lanes_state,
                         lanes_prim, row_length, action, work):
    """The closest-hit and any-hit walk (an action of mode ``NEAREST``) of rays ``ray_first`` to
    ``ray_end - 1`` in packets of :data:`PACKET` consecutive rays, the last one partial, or, with a
    ``row_length`` other than 0, of the places ``ray_first`` to ``ray_end - 1`` of the tile order of
    an image with rows of that length (:func:`rayaccel.ray_tiles.tile_ray`), a packet a tile; a
    packet without a common near side takes the single walk (:func:`.traverse.walk_singly`, with
    ``stack_node``, ``stack_t`` and ``inv_dir``). A packet's stack is ``stack_node``, ``packet_lanes``
    (threads, depth) int64 and ``packet_t`` (threads, depth, 2 * PACKET), its rays' state
    ``lanes_state`` (threads, PACKET_ROWS * PACKET) and ``lanes_prim`` (threads, PACKET) int64."""
    state = lanes_state[tid]
    best_prim = lanes_prim[tid]
    tiled_rays, next_tiled, column = first_tile(ray_first, row_length, origins.shape[0])
    for place in range(ray_first, ray_end, PACKET):
        n_lanes = min(PACKET, ray_end - place)
        packet_first, packet_second = place, place + TILE_COLUMNS
        if place < tiled_rays:
            packet_first, packet_second = next_tiled, next_tiled + row_length
            next_tiled, column = next_tile(next_tiled, column, TILE_COLUMNS, row_length)
        lanes, positive, coherent = _load_packet(lo, hi, origins, directions, t_min, t_max, packet_first,
                                                 packet_second, n_lanes, state, best_prim)
        if not coherent:
            for run in range(TILE_ROWS):
                run_first, run_end = run_rays(packet_first, packet_second, n_lanes, TILE_COLUMNS, run)
                walk_singly(run_first, run_end, tid, lo, hi, node_planes, node_links, skip_empty, leaf_prims,
                            apart_first, apart_box, kind, geom, origins, directions, t_min, t_max, hit_slot, any_hit,
                            mailbox, ray_id_base, stack_node, stack_t, inv_dir, NEAREST, action, work)
            continue
        if apart_box is not None:
            lanes = _visit_apart_lanes(action, hit_slot, apart_first, apart_box, leaf_prims, mailbox, tid,
                                       ray_id_base, kind, geom, origins, directions, packet_first, packet_second,
                                       n_lanes, lanes, state, best_prim, any_hit)
        live = lanes
        done = 0
        node = 0 if lanes != 0 else -1
        sp = 0
        while node >= 0:
            word = node_word(node_links, node)
            axis = word & 3
            if axis != LEAF:
                below = node_child(word)
                empty = empty_children_of(skip_empty, word)
                near = below if (positive >> axis) & 1 else below + 1
                far = 2 * below + 1 - near
                sides = _split_lanes(state, axis, np.float64(node_plane(node_planes, node)), packet_t[tid, sp])
                near_lanes = sides & lanes
                far_lanes = (sides >> PACKET) & lanes
                if far_lanes != 0 and not is_empty_child(empty, below, far):
                    stack_node[tid, sp] = far
                    packet_lanes[tid, sp] = far_lanes
                    sp += 1
                if near_lanes != 0 and not is_empty_child(empty, below, near):
                    node = near
                    lanes = near_lanes
                    continue
            elif word >> 2 != 0:
                first = leaf_first(node_links, node)
                done = _visit_leaf_lanes(action, hit_slot, first, first + (word >> 2), leaf_prims, mailbox, tid,
                                         ray_id_base, kind, geom, origins, directions, packet_first, packet_second,
                                         lanes & ~done, done, state, best_prim, any_hit)
                if any_hit and done == live:
                    break
            node, lanes, sp = _pop_lanes(state, best_prim, stack_node, packet_lanes, packet_t, tid, sp, done)
        for r in range(n_lanes):
            finish_ray_in_mode(NEAREST, action, result_row(hit_slot, lane_ray(packet_first, r, packet_second)),
                               state[_BEST + r], best_prim[r], state[_U + r], state[_V + r])
