"""The binary tree inside an eight-wide BVH, recovered from the wide records and a few bits.

The collapse (:mod:`.wide`) fills a wide node's slots with the leaves of a binary
subtree of at most eight leaves, in their left-to-right order (opening a slot puts
the two children in its place). A full binary tree is fixed by its leaves' depths
read in that order, as a canonical Huffman code is by its code lengths: the left
subtree of a node at depth ``d`` is the shortest run of leaves whose weights
``2**-depth`` add up to ``2**-(d + 1)`` (Kraft's equality). So each wide node keeps
the depth of each slot within its subtree (at most 7: three bits a slot, 24 bits a
node), and the binary tree, which the ray walk does not read, need not be kept
beside the wide one: the point queries, the statistics, :meth:`refit` and saving
recover it on first use, with boxes recomputed from the leaves' primitives. Those
boxes are the build's to the bit (unions of the same primitive extents, grown by the
same padding), so what the point queries prune and the SAH cost the statistics
report do not change; only the numbering of the binary nodes does.

Full dragon, ``bvh-binned``: the binary tree's boxes, links and collapse take
44 bytes per triangle; the depths 0.4.
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel
from .wide import COUNT, LINK, UNUSED, WIDTH

__all__ = ["slot_depths", "binary_from_wide"]

_DEPTH_BITS = 3
_DEEPEST = 2 ** _DEPTH_BITS - 1


@kernel
def slot_depths(slots, child_wide, node_depth):
    """(n_wide,) int32: for each wide node of a collapse ``(slots, child_wide)`` the depth of
    each used slot's binary node below the binary node the wide node stands for, three bits
    a slot (slot ``c`` in bits ``3 c`` to ``3 c + 2``); ``node_depth``: each binary node's
    depth in the binary tree."""
    n_wide = slots.shape[0]
    top = np.zeros(n_wide, dtype=np.int64)
    depths = np.zeros(n_wide, dtype=np.int32)
    for wide in range(n_wide):
        for c in range(WIDTH):
            if child_wide[wide, c] > 0:
                top[child_wide[wide, c]] = slots[wide, c]
        packed = 0
        for c in range(WIDTH):
            if slots[wide, c] >= 0:
                relative = node_depth[slots[wide, c]] - node_depth[top[wide]]
                if relative > _DEEPEST:
                    raise ValueError("a wide node's binary subtree is deeper than its eight slots allow")
                packed |= relative << (_DEPTH_BITS * c)
        depths[wide] = packed
    return depths


@kernel
def _depth(depths, wide, slot):
    return (depths[wide] >> (_DEPTH_BITS * slot)) & _DEEPEST


@kernel
def binary_from_wide(links, depths):
    """The binary tree of the wide records (``links``: the records seen as int32) whose slots
    lie at ``depths`` (:func:`slot_depths`): ``(node_first, node_count, slots, child_wide)``,
    the binary layout of :mod:`.layout` (children side by side, after their parent) and the
    collapse of :func:`.wide.wide_tree` that maps it onto the same wide nodes."""
    n_wide = links.shape[0]
    n_nodes = 1
    for wide in range(n_wide):
        for c in range(WIDTH):
            if c > 0 and links[wide, COUNT + c] != UNUSED:
                n_nodes += 2
    node_first = np.zeros(n_nodes, dtype=np.int32)
    node_count = np.zeros(n_nodes, dtype=np.int32)
    slots = np.full((n_wide, WIDTH), -1, dtype=np.int32)
    child_wide = np.zeros((n_wide, WIDTH), dtype=np.int32)
    next_free = 1
    pending = [(0, 0)]
    ranges = [(0, 0, 0, 0)]
    while len(pending) > 0:
        wide, top = pending.pop()
        used = 0
        while used < WIDTH and links[wide, COUNT + used] != UNUSED:
            used += 1
        ranges.clear()
        ranges.append((0, used, 0, top))
        while len(ranges) > 0:
            start, end, depth, node = ranges.pop()
            if end - start == 1:
                slots[wide, start] = node
                count = links[wide, COUNT + start]
                if count > 0:
                    node_first[node] = links[wide, LINK + start]
                    node_count[node] = count
                else:
                    child_wide[wide, start] = links[wide, LINK + start]
                    pending.append((links[wide, LINK + start], node))
                continue
            half = 1 << (_DEEPEST - depth - 1)
            weight = 0
            split = start
            while weight < half:
                weight += 1 << (_DEEPEST - _depth(depths, wide, split))
                split += 1
            node_first[node] = next_free
            ranges.append((split, end, depth + 1, next_free + 1))
            ranges.append((start, split, depth + 1, next_free))
            next_free += 2
    return node_first, node_count, slots, child_wide
