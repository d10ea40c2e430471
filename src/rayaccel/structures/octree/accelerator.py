"""``octree``: the adaptive octree as an :class:`~rayaccel.structures.base.Accelerator`."""

from __future__ import annotations

import math
import time

import numba
import numpy as np

from ..._jit import lent_rows
from ..._validate import check_number
from ...stats import box_area, surface_area_stats
from ..actions import NEAREST
from ..base import Accelerator, interval_stacks, walk_rays
from ..grid.build_uniform import grid_box
from ..point_queries import nearest_walk_scratch
from .build_adaptive import build_octree
from .layout import OctreeArrays
from .nearest import octree_nearest_kernel
from .traverse import octree_closest_kernel, octree_crossings_kernel

__all__ = ["Octree"]

_INSERT_MODES = ("bbox", "exact")
_PAD = 1e-9  # octant boxes are grown by this fraction of their size when inserting
_COORDINATE_PAD = 1e-11  # and by this fraction of the largest coordinate of the root cell


class Octree(Accelerator):
    """``octree``: adaptive octree (Glassner 1984) with parametric front-to-back traversal
    (Revelles et al. 2000).

    Parameters
    ----------
    leaf_size : int, default 8
        A cell with more primitives than this is split into octants.
    max_depth : int, optional
        Depth limit; default ``ceil(log2(n) / 2) + 4``, enough for surfaces
        (whose occupied cells grow 4x per level) to reach ``leaf_size``.
    insert : "exact" or "bbox"
        Put a primitive into the octants it really overlaps (default) or into
        every octant its bounding box overlaps (faster build, more references).
    """

    method = "octree"
    build_bytes_per_primitive = 1000

    def __init__(self, scene, *, leaf_size=8, max_depth=None, insert="exact"):
        if insert not in _INSERT_MODES:
            raise ValueError(f"insert must be one of {_INSERT_MODES}, got {insert!r}")
        n = len(scene)
        if max_depth is None:
            max_depth = math.ceil(math.log2(max(n, 2)) / 2) + 4
        options = {
            "leaf_size": check_number("leaf_size", leaf_size, integer=True, minimum=1, inclusive=True),
            "max_depth": check_number("max_depth", max_depth, integer=True, inclusive=True, maximum=30),
            "insert": insert,
        }
        super().__init__(scene, options)
        start = time.perf_counter()
        bounds = self._primitive_bounds()
        lo, hi = grid_box(bounds.scene_lo, bounds.scene_hi)
        center, link, leaf_prims, depth = build_octree(bounds.lo, bounds.hi, scene.kind, scene.geometry,
                                                       insert == "exact", lo, hi, options["leaf_size"],
                                                       options["max_depth"], _PAD,
                                                       _COORDINATE_PAD * float(max(np.abs(lo).max(), np.abs(hi).max())))
        self.tree = OctreeArrays(lo, hi, center, link, leaf_prims)
        self.max_depth = int(depth)
        self.build_seconds = time.perf_counter() - start

    def _trace(self, batch, any_hit, action, work):
        o = self.tree
        rows = numba.config.NUMBA_NUM_THREADS
        scratch = lent_rows(interval_stacks, rows, 3 * self.max_depth + 4)
        with self._mailboxes_for(action).lend(batch.size) as (mailbox, base), scratch as (stack_node, stack_t):
            walk = octree_closest_kernel if action.mode == NEAREST else octree_crossings_kernel
            walk_rays(walk, batch.size, o.lo, o.hi, o.node_center, o.node_link, o.leaf_prims, self.scene.kind,
                      self.scene.geometry, *batch, any_hit, mailbox, base, stack_node, stack_t, action, work)

    def _nearest(self, points, limit_d2, out_d2, out_prim):
        """Children nearest first by the distance to their cells (:mod:`.nearest`)."""
        o = self.tree
        rows, depth = numba.config.NUMBA_NUM_THREADS, 7 * self.max_depth + 9
        pad = 1e-9 * float(np.abs(o.lo).max() + np.abs(o.hi).max() + (o.hi - o.lo).max())
        with lent_rows(nearest_walk_scratch, rows, depth) as stacks:
            octree_nearest_kernel(o.lo, o.hi, o.node_center, o.node_link, o.leaf_prims, self.scene.kind,
                                  self.scene.geometry, pad, points, limit_d2, *stacks, out_d2, out_prim)

    def node_cells(self) -> np.ndarray:
        """(n_nodes, 6) cell of every node, lo and hi."""
        o = self.tree
        half = np.empty((o.n_nodes, 3))
        half[0] = 0.5 * (o.hi - o.lo)
        frontier = np.zeros(1, dtype=np.int64)
        while len(frontier):  # level by level: each octant has half its parent's size
            frontier = frontier[~o.leaf[frontier]]
            children = (o.node_link[frontier, 0][:, None] + np.arange(8)).ravel()
            half[children] = np.repeat(0.5 * half[frontier], 8, axis=0)
            frontier = children
        return np.concatenate((o.node_center - half, o.node_center + half), axis=1)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the tree and the primitives."""
        return int(self.tree.nbytes + self.scene.geometry.nbytes)

    def _structure_stats(self) -> dict:
        o = self.tree
        leaf = o.leaf
        counts = o.node_link[leaf, 1]
        cells = self.node_cells()
        areas = box_area(cells[:, :3], cells[:, 3:])
        nonempty = int(np.count_nonzero(counts))
        result = {
            "nodes": o.n_nodes,
            "leaves": int(leaf.sum()),
            "nonempty_leaves": nonempty,
            "max_depth": self.max_depth,
            "references": len(o.leaf_prims),
            "avg_prims_per_nonempty_leaf": float(counts.sum()) / max(nonempty, 1),
            "bytes": self.nbytes,
        }
        result.update(surface_area_stats(areas[0], step_areas=areas[~leaf], leaf_areas=areas[leaf],
                                         leaf_counts=counts))
        return result
