"""``grid``: the uniform grid as an :class:`~rayaccel.structures.base.Accelerator`."""

from __future__ import annotations

import time

import numpy as np

from ...stats import box_area, surface_area_stats
from ..actions import NEAREST
from ..base import Accelerator, walk_rays
from .build_uniform import build_grid, capped_resolution, grid_box, resolution_for
from .mailbox import MailboxPool
from .nearest import grid_nearest
from .traverse import grid_closest_kernel, grid_crossings_kernel

__all__ = ["UniformGrid"]

_INSERT_MODES = ("bbox", "exact")


class UniformGrid(Accelerator):
    """``grid``: a uniform grid traversed by 3D-DDA (Amanatides & Woo 1987).

    Parameters
    ----------
    density : float, default 8
        Cells per primitive: the grid has about ``density * n`` cells (the
        lecture's lambda). More cells mean fewer tests per cell but more steps.
        A resolution from ``density`` or ``"cost"`` is made coarser where it
        would store more than 64 references per primitive (primitives that
        span much of the scene), which would make the build blow up.
    resolution : None, "cost", int or (3,) ints
        None uses ``density``; ``"cost"`` uses the cost model's optimum
        ``2 n C_i / C_c`` cells with costs calibrated on this machine
        (:func:`rayaccel.structures.grid.calibrate.cost_ratio`); an int or a
        triple fixes the cells per axis.
    insert : "bbox" or "exact"
        Put a primitive into every cell its bounding box overlaps (fast build,
        more references) or only into cells it really overlaps (slower build,
        fewer tests per ray, mostly for long thin triangles).
    mailbox : bool, default True
        Test each primitive at most once per ray even where it spans several
        cells; False shows what that saves. The mailboxes (one int64 per
        primitive and thread) are allocated on the first query and reused;
        concurrent queries from several Python threads each get their own.
    """

    _walk_takes_shared_origin = True

    method = "grid"

    def __init__(self, scene, *, density: float = 8.0, resolution=None, insert: str = "bbox", mailbox: bool = True):
        if insert not in _INSERT_MODES:
            raise ValueError(f"insert must be one of {_INSERT_MODES}, got {insert!r}")
        if not (isinstance(density, (int, float)) and np.isfinite(density) and density > 0):
            raise ValueError(f"density must be a positive number, got {density!r}")
        super().__init__(scene, {"density": density, "resolution": resolution, "insert": insert,
                                 "mailbox": bool(mailbox)})
        start = time.perf_counter()
        bounds = self._primitive_bounds()
        lo, hi = grid_box(bounds.scene_lo, bounds.scene_hi)
        res = self._resolution(resolution, density, hi - lo, len(scene))
        if resolution is None or isinstance(resolution, str):
            res = capped_resolution(bounds, lo, hi, res)
        self.grid = build_grid(bounds, lo, hi, scene.kind, scene.geometry, res, insert == "exact")
        self.build_seconds = time.perf_counter() - start
        self.mailboxes = MailboxPool(len(scene), enabled=bool(mailbox))

    def _resolution(self, resolution, density, extent, n):
        if resolution is None:
            return resolution_for(extent, density * n)
        if isinstance(resolution, str):
            if resolution != "cost":
                raise ValueError(f"resolution must be None, 'cost', an int or three ints, got {resolution!r}")
            from .calibrate import cost_ratio

            return resolution_for(extent, 2.0 * n * cost_ratio(self.scene.kind))
        res = np.broadcast_to(np.asarray(resolution), (3,))
        if not np.issubdtype(res.dtype, np.integer) or (res < 1).any():
            raise ValueError(f"resolution must be positive integers, got {resolution!r}")
        if int(np.prod(res.astype(np.float64))) > (1 << 27):
            raise ValueError(f"resolution {tuple(res)} has more than 2**27 cells")
        return res.astype(np.int64)

    def _trace(self, batch, any_hit, action, work):
        g = self.grid
        with self._mailboxes_for(action).lend(batch.size) as (mailbox, base):
            walk = grid_closest_kernel if action.mode == NEAREST else grid_crossings_kernel
            walk_rays(walk, batch.size, g.lo, g.hi, g.res, g.cell_size, g.cell_first, g.cell_prims,
                      self.scene.kind, self.scene.geometry, *batch, any_hit, mailbox, base, action, work)

    def _nearest(self, points, limit_d2, out_d2, out_prim):
        """Cells searched outward in shells (:mod:`.nearest`)."""
        g = self.grid
        grid_nearest(g.lo, g.hi, g.res, g.cell_size, g.cell_first, g.cell_prims, self.scene.kind, self.scene.geometry,
                     points, limit_d2, out_d2, out_prim)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the structure, the primitives and mailboxes."""
        return int(self.grid.nbytes + self.scene.geometry.nbytes + self.mailboxes.nbytes)

    def _structure_stats(self) -> dict:
        g = self.grid
        counts = np.diff(g.cell_first)
        nonempty = int(np.count_nonzero(counts))
        n_cells = g.n_cells
        result = {
            "resolution": tuple(int(r) for r in g.res),
            "nodes": n_cells,
            "leaves": n_cells,
            "nonempty_leaves": nonempty,
            "max_depth": 1,
            "references": int(g.cell_first[-1]),
            "avg_prims_per_nonempty_leaf": float(g.cell_first[-1]) / max(nonempty, 1),
            "bytes": self.nbytes,
        }
        cell_areas = np.full(n_cells, box_area(np.zeros(3), g.cell_size))
        # Every cell entered is one DDA step, so cells count as traversal steps too.
        result.update(surface_area_stats(box_area(g.lo, g.hi), step_areas=cell_areas,
                                         leaf_areas=cell_areas, leaf_counts=counts))
        return result
