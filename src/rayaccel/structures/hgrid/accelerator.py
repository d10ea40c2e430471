"""``hgrid``: the hierarchical grid as an :class:`~rayaccel.structures.base.Accelerator`."""

from __future__ import annotations

import time

import numba
import numpy as np

from ..._jit import lent_rows, thread_rows
from ..._validate import check_number
from ...stats import box_area, surface_area_stats
from ..actions import NEAREST
from ..base import Accelerator, walk_rays
from ..grid.mailbox import MailboxPool
from ..grid.nearest import grid_nearest
from .build_nested import build_hierarchical_grid
from .traverse import hgrid_closest_kernel, hgrid_crossings_kernel

__all__ = ["HierarchicalGrid"]

_INSERT_MODES = ("bbox", "exact")


def _walk_scratch(rows: int, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """The walk's per-thread scratch: each level's saved DDA state, integers and floats."""
    return thread_rows((rows, levels, 7), np.int64), thread_rows((rows, levels, 7))


class HierarchicalGrid(Accelerator):
    """``hgrid``: uniform grids nested in the dense cells of uniform grids
    (Jevans & Wyvill 1989; Klimaszewski & Sederberg 1997).

    Parameters
    ----------
    density : float, default 0.5
        Cells per primitive in every grid: the top grid has ``density * n``
        cells, a grid nested in a cell with ``m`` primitives ``density * m``.
    threshold : int, default 4
        A cell holding more references than this gets a nested grid.
    max_levels : int, default 3
        Levels of grids, the top grid included.
    insert : "bbox" or "exact"
        As for ``grid``.
    mailbox : bool, default True
        As for ``grid``: test each primitive at most once per ray.
    """

    _walk_takes_shared_origin = True

    method = "hgrid"
    build_bytes_per_primitive = 700

    def __init__(self, scene, *, density=0.5, threshold=4, max_levels=3, insert="bbox", mailbox=True):
        if insert not in _INSERT_MODES:
            raise ValueError(f"insert must be one of {_INSERT_MODES}, got {insert!r}")
        options = {
            "density": check_number("density", density),
            "threshold": check_number("threshold", threshold, integer=True, minimum=1, inclusive=True),
            "max_levels": check_number("max_levels", max_levels, integer=True, minimum=1, inclusive=True,
                                       maximum=16),
            "insert": insert,
            "mailbox": bool(mailbox),
        }
        super().__init__(scene, options)
        start = time.perf_counter()
        self.hgrid = build_hierarchical_grid(self._primitive_bounds(), scene.kind, scene.geometry, options["density"],
                                             options["threshold"], options["max_levels"], insert == "exact")
        self.build_seconds = time.perf_counter() - start
        self.mailboxes = MailboxPool(len(scene), enabled=options["mailbox"])

    def _trace(self, batch, any_hit, action, work):
        h = self.hgrid
        rows = numba.config.NUMBA_NUM_THREADS
        levels = int(h.grid_level.max()) + 1
        scratch = lent_rows(_walk_scratch, rows, levels)
        with self._mailboxes_for(action).lend(batch.size) as (mailbox, base), scratch as (saved_int, saved_float):
            walk = hgrid_closest_kernel if action.mode == NEAREST else hgrid_crossings_kernel
            walk_rays(walk, batch.size, h.lo, h.hi, h.grid_lo, h.grid_res, h.grid_cell_size, h.grid_cell_base,
                      h.cell_child, h.cell_first, h.cell_prims, self.scene.kind, self.scene.geometry, *batch, any_hit,
                      mailbox, base, saved_int, saved_float, action, work)

    def _nearest(self, points, limit_d2, out_d2, out_prim):
        """The top grid searched outward in shells, nested grids scanned with pruning (:mod:`..grid.nearest`)."""
        h = self.hgrid
        top_hi = h.grid_lo[0] + h.grid_res[0] * h.grid_cell_size[0]
        grid_nearest(h.grid_lo[0], top_hi, h.grid_res[0], h.grid_cell_size[0], h.cell_first, h.cell_prims,
                     self.scene.kind, self.scene.geometry, points, limit_d2, out_d2, out_prim,
                     nested=(h.cell_child, h.grid_lo, h.grid_res, h.grid_cell_size, h.grid_cell_base))

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the structure, the primitives and mailboxes."""
        return int(self.hgrid.nbytes + self.scene.geometry.nbytes + self.mailboxes.nbytes)

    def _structure_stats(self) -> dict:
        h = self.hgrid
        cells_per_grid = h.grid_res.prod(axis=1)
        cell_grid = np.repeat(np.arange(h.n_grids), cells_per_grid)
        cell_area = box_area(np.zeros(3), h.grid_cell_size)[cell_grid]
        counts = np.diff(h.cell_first)
        leaf = h.cell_child < 0
        nonempty = int(np.count_nonzero(counts))
        result = {
            "grids": h.n_grids,
            "levels": int(h.grid_level.max()) + 1,
            "nodes": h.n_cells,
            "leaves": int(leaf.sum()),
            "nonempty_leaves": nonempty,
            "max_depth": int(h.grid_level.max()) + 1,
            "references": int(h.cell_first[-1]),
            "avg_prims_per_nonempty_leaf": float(h.cell_first[-1]) / max(nonempty, 1),
            "bytes": self.nbytes,
        }
        # every cell entered, at any level, is one DDA step
        result.update(surface_area_stats(box_area(h.lo, h.hi), step_areas=cell_area, leaf_areas=cell_area[leaf],
                                         leaf_counts=counts[leaf]))
        return result
