"""``grid-bvh``: the grid-BVH hybrid as an :class:`~rayaccel.structures.base.Accelerator`."""

from __future__ import annotations

import time

import numba
import numpy as np

from ..._jit import lent_rows
from ..._validate import check_number
from ...geometry.gather import layout_nbytes
from ...geometry.kinds import TRIANGLE
from ...stats import box_area, surface_area_stats
from ..actions import NEAREST
from ..base import Accelerator, walk_rays
from ..bvh.accelerator import single_walk_scratch
from ..bvh.nodes import rounding_margin
from ..bvh.wide import wide_records, wide_tree
from ..grid.mailbox import MailboxPool
from ..grid.nearest import grid_nearest
from .build_grid_bvh import build_grid_bvh
from .traverse import grid_bvh_crossings_kernel, grid_bvh_nearest_kernel

__all__ = ["GridBvh"]

_INSERT_MODES = ("bbox", "exact")


class GridBvh(Accelerator):
    """``grid-bvh``: a coarse uniform grid whose dense cells hold binned-SAH BVHs, walked eight-wide.

    Parameters
    ----------
    density : float, default 0.001
        Grid cells per primitive: about one cell for each thousand primitives,
        so that the grid skips the large empty regions and each dense cell's
        BVH does the fine search. Finer grids cost more cell steps and more
        references; ``density=0.5`` (the default before 2026-11-27) traced
        0.36-0.50 times as fast as ``bvh-binned`` on the full dragon, one
        thread, where 0.001 reaches 0.59-0.89 (see the README).
    threshold : int, default 8
        Cells with more references than this get a BVH; the others are
        tested one by one.
    max_leaf_size, bins, traversal_cost, intersection_cost
        Of the cells' BVHs, as for ``bvh-binned`` (defaults 4, 16, 3, 1).
    insert : "bbox" or "exact"
        As for ``grid``.
    mailbox : bool, default False
        As for ``grid``. With cells this coarse a primitive lies in one cell
        (1.07 references a triangle on the full dragon), so the mailbox's
        reads cost more than the repeated tests it saves; it is on for
        counting and listing queries regardless, which must see each
        primitive once.
    """

    method = "grid-bvh"
    build_bytes_per_primitive = 700

    def __init__(self, scene, *, density=0.001, threshold=8, max_leaf_size=4, bins=16, traversal_cost=3.0,
                 intersection_cost=1.0, insert="bbox", mailbox=False):
        if insert not in _INSERT_MODES:
            raise ValueError(f"insert must be one of {_INSERT_MODES}, got {insert!r}")
        options = {
            "density": check_number("density", density),
            "threshold": check_number("threshold", threshold, integer=True, minimum=1, inclusive=True),
            "max_leaf_size": check_number("max_leaf_size", max_leaf_size, integer=True, minimum=1, inclusive=True),
            "bins": check_number("bins", bins, integer=True, minimum=2, inclusive=True),
            "traversal_cost": check_number("traversal_cost", traversal_cost),
            "intersection_cost": check_number("intersection_cost", intersection_cost),
            "insert": insert,
            "mailbox": bool(mailbox),
        }
        super().__init__(scene, options)
        start = time.perf_counter()
        bounds = self._primitive_bounds()
        pad = rounding_margin(bounds.scene_lo, bounds.scene_hi)
        self.hybrid, self.bvh_depth = build_grid_bvh(
            bounds, scene.kind, scene.geometry, options["density"], options["threshold"], options["max_leaf_size"],
            options["bins"], options["traversal_cost"], options["intersection_cost"], insert == "exact", pad)
        self.build_seconds = time.perf_counter() - start
        self.mailboxes = MailboxPool(len(scene), enabled=options["mailbox"])
        self._derive_from_layout()

    def _derive_from_layout(self) -> None:
        """What the queries read besides the built (or loaded) arrays: the primitives in the order
        of ``cell_prims``, read one after the other in a cell or a leaf, triangles in the indexed
        layout (:meth:`~rayaccel.scene.TriangleMesh.gather`), as the kd-tree's: float32 rows, 36
        bytes a reference, held 59.4 bytes a triangle of the full dragon (1.65 references each)
        and put the hybrid at 111.2 bytes a triangle, over Embree's 91.9; indexed, 83.7, and
        0.91-1.07 times as fast (alternating processes, camera, incoherent and shadow rays,
        closest and any hit, two threads). And the cells' BVHs collapsed eight-wide
        (:func:`_wide_forest`), which the ray walk reads instead of the binary forest."""
        self.geometry = self.scene.gather(self.hybrid.cell_prims, indexed=True)
        self.wide_root, self.wide = _wide_forest(self.hybrid)

    def _trace(self, batch, any_hit, action, work):
        h = self.hybrid
        scratch = lent_rows(single_walk_scratch, numba.config.NUMBA_NUM_THREADS, self.bvh_depth)
        with self._mailboxes_for(action).lend(batch.size) as (mailbox, base), scratch as stacks:
            walk = grid_bvh_nearest_kernel if action.mode == NEAREST else grid_bvh_crossings_kernel
            return walk_rays(walk, batch.size, h.lo, h.hi, h.res, h.cell_size, h.cell_first, h.cell_prims,
                             self.wide_root, self.wide, self.wide.view(np.int32), self.scene.kind, self.geometry,
                             *batch, any_hit, mailbox if len(mailbox) else None, base, *stacks, action, work)

    @property
    def _walk_checks_rays(self) -> bool:
        """The walk tests each ray as it reads it, as the eight-wide BVH's does."""
        return True

    @property
    def _walk_takes_float32(self) -> bool:
        """The walk reads float32 rays as they are, as the eight-wide BVH's does."""
        return self.scene.kind == TRIANGLE

    @property
    def _walk_takes_shared_origin(self) -> bool:
        """Over triangles, as for float32 rays: its walk reads rays through :func:`rayaccel.rays.ray_at`."""
        return self._walk_takes_float32

    def _nearest(self, points, limit_d2, out_d2, out_prim):
        """Grid cells searched outward in shells, a dense cell's BVH walked by distance (:mod:`..grid.nearest`)."""
        h = self.hybrid
        grid_nearest(h.lo, h.hi, h.res, h.cell_size, h.cell_first, h.cell_prims, self.scene.kind, self.geometry,
                     points, limit_d2, out_d2, out_prim, cell_root=h.cell_root,
                     forest=(h.node_box, h.node_first, h.node_count), bvh_depth=self.bvh_depth, in_leaf_order=True)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the structure (the binary forest, which the point
        queries and the statistics read, and its eight-wide collapse, which the ray walk reads), the
        primitives in reference order and the mailboxes."""
        return int(self.hybrid.nbytes + self.wide.nbytes + self.wide_root.nbytes + layout_nbytes(self.geometry)
                   + self.mailboxes.nbytes)

    def _structure_stats(self) -> dict:
        h = self.hybrid
        counts = np.diff(h.cell_first)
        n_cells = len(counts)
        node_cell = self._node_cells()
        used = node_cell >= 0
        leaf = h.node_count[used] > 0
        in_bvh = h.cell_root >= 0
        leaf_counts = np.concatenate((counts[~in_bvh], h.node_count[used][leaf]))
        nonempty = int(np.count_nonzero(leaf_counts))
        cell_area = float(box_area(np.zeros(3), h.cell_size))
        # a node is reached only by rays through its cell, and tested only on their stretch in it
        cell = node_cell[used]
        cell_xyz = np.stack(np.unravel_index(cell, tuple(h.res[::-1]))[::-1], axis=1)
        cell_lo = h.lo + cell_xyz * h.cell_size
        clipped_lo = np.maximum(h.node_box[used, :3], cell_lo)
        clipped_hi = np.minimum(h.node_box[used, 3:], cell_lo + h.cell_size)
        node_areas = box_area(clipped_lo, clipped_hi)
        result = {
            "resolution": tuple(int(r) for r in h.res),
            "bvh_cells": int(in_bvh.sum()),
            "nodes": n_cells + int(used.sum()),
            "leaves": len(leaf_counts),
            "nonempty_leaves": nonempty,
            "max_depth": 1 + self.bvh_depth,
            "references": int(h.cell_first[-1]),
            "avg_prims_per_nonempty_leaf": float(leaf_counts.sum()) / max(nonempty, 1),
            "bytes": self.nbytes,
        }
        steps = np.concatenate((np.full(n_cells, cell_area), node_areas))
        leaf_areas = np.concatenate((np.full(int((~in_bvh).sum()), cell_area), node_areas[leaf]))
        result.update(surface_area_stats(box_area(h.lo, h.hi), step_areas=steps, leaf_areas=leaf_areas,
                                         leaf_counts=leaf_counts))
        return result

    def _node_cells(self) -> np.ndarray:
        """The grid cell whose BVH each node slot belongs to; -1 for unused slots."""
        h = self.hybrid
        node_cell = np.full(len(h.node_count), -1, dtype=np.int64)
        cells = np.flatnonzero(h.cell_root >= 0)
        frontier = h.cell_root[cells].astype(np.int64)
        node_cell[frontier] = cells
        while len(frontier):
            frontier = frontier[h.node_count[frontier] == 0]
            left = h.node_first[frontier].astype(np.int64)
            node_cell[left] = node_cell[frontier]
            node_cell[left + 1] = node_cell[frontier]
            frontier = np.concatenate((left, left + 1))
        return node_cell


def _wide_forest(hybrid) -> tuple[np.ndarray, np.ndarray]:
    """``(wide_root, records)``: the cells' binary BVHs collapsed into eight-wide records
    (:func:`..bvh.wide.wide_tree`, as ``bvh-binned``'s tree), and each cell's root among them,
    -1 for a cell without a BVH. The hybrid's walk over them (:func:`..bvh.traverse_wide.walk_tree`
    in each cell, rays checked as they are read, the closest-hit kernel pruned of the other
    modes) against its binary walk before, both on one cell for every thousand primitives
    without a mailbox, one thread, CPU time, medians of 5 interleaved rounds, camera /
    incoherent / shadow rays, closest and any hit: full dragon 1.23-1.30 times as fast,
    forest-small-chair 1.33-1.69 (ratios of the two walks' speed-ups over the old default
    in one run)."""
    cells = np.flatnonzero(hybrid.cell_root >= 0)
    tree = wide_tree(hybrid.node_box, hybrid.node_first, hybrid.node_count, hybrid.cell_root[cells])
    wide_root = np.full(len(hybrid.cell_root), -1, dtype=np.int32)
    wide_root[cells] = np.arange(len(cells), dtype=np.int32)
    return wide_root, wide_records(hybrid.node_box, hybrid.node_first, hybrid.node_count, tree)
