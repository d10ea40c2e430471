"""One description per structure: the arrays saved, their checks, and what is derived again on load.

Each entry of :data:`LAYOUTS` is a pair of functions for one accelerator
class (and its subclasses):

* ``save(accel) -> (meta, arrays)``: the structure's own arrays (the
  canonical ones its build produced) and a few scalars;
* ``load(accel, meta, arrays)``: check every array a kernel will read
  (:mod:`.checks`), then set them on ``accel`` (whose ``scene`` and ``options``
  are already restored) and derive the rest -- packed traversal records,
  per-thread mailboxes, stack depths -- with the same functions the build uses.

Only canonical arrays are stored: derived layouts (the BVH's packed and
wide records, the sorted geometry) are rebuilt on load, so a file stays
valid when a traversal layout changes. One derived array is stored as well,
because deriving it is most of a load's time: the wide BVH's choice of
binary nodes per wide node (:func:`..structures.bvh.wide.wide_tree`; full dragon:
27 ms of random reads over the whole tree). It is
optional: a file without it gets it derived again.
"""

from __future__ import annotations

import numpy as np

from ..structures.bvh.accelerator import _BOUNDS, BoundingVolumeHierarchy
from ..structures.bvh.nodes import node_depths
from ..structures.bvh.wide import WIDTH, wide_depth
from ..structures.grid.accelerator import UniformGrid
from ..structures.grid.layout import GridArrays
from ..structures.grid.mailbox import MailboxPool
from ..structures.hgrid.accelerator import HierarchicalGrid
from ..structures.hgrid.layout import HierarchicalGridArrays
from ..structures.hybrid.accelerator import GridBvh
from ..structures.hybrid.layout import GridBvhArrays
from ..structures.kdtree.accelerator import KdTree, width_problem
from ..structures.kdtree.layout import LEAF, KdTreeArrays
from ..structures.none import BruteForce
from ..structures.octree.accelerator import Octree
from ..structures.octree.layout import OctreeArrays
from . import checks as c

__all__ = ["LAYOUTS", "layout_of", "tree_checks"]

_INT32_MAX = np.iinfo(np.int32).max


def _named(tuple_value, prefix: str) -> dict:
    return {f"{prefix}.{field}": getattr(tuple_value, field) for field in tuple_value._fields}


def _box3(arrays, prefix):
    lo = c.finite(f"{prefix}.lo", c.array(arrays, f"{prefix}.lo", np.float64, (3,)))
    hi = c.finite(f"{prefix}.hi", c.array(arrays, f"{prefix}.hi", np.float64, (3,)))
    c.require(bool((lo < hi).all()), f"{prefix}: box lo must lie below hi")
    return lo, hi


def _cells(arrays, prefix, res_shape):
    res = c.array(arrays, f"{prefix}.res", np.int64, res_shape)
    c.require(bool((res >= 1).all()) and bool((res <= 1 << 20).all()), f"{prefix}.res must lie in 1 .. 2**20")
    return res


def _positive(name, a):
    c.finite(name, a)
    c.require(bool((a > 0).all()), f"{name} must be positive")
    return a


def _references(arrays, prefix, n_cells, n_prims, first_dtype):
    prims = c.array(arrays, f"{prefix}.cell_prims", np.int32, (None,))
    c.index_range(f"{prefix}.cell_prims", prims, 0, n_prims)
    first = c.array(arrays, f"{prefix}.cell_first", first_dtype, (n_cells + 1,))
    c.offsets(f"{prefix}.cell_first", first, len(prims))
    return first, prims


def _mailbox(accel):
    c.require(isinstance(accel.options.get("mailbox"), bool), "option mailbox must be true or false")
    accel.mailboxes = MailboxPool(len(accel.scene), enabled=accel.options["mailbox"])


# --- none ---------------------------------------------------------------------------------

def _save_none(accel):
    return {}, {}


def _load_none(accel, meta, arrays):
    pass


# --- grid ---------------------------------------------------------------------------------

def _save_grid(accel):
    return {}, _named(accel.grid, "grid")


def _uniform_cells(arrays, prefix, n_prims, what):
    """The checked uniform-grid part of a grid or grid-bvh: box, cells per axis, cell size and
    references, ``(lo, hi, res, cell_size, cell_first, cell_prims)``."""
    lo, hi = _box3(arrays, prefix)
    res = _cells(arrays, prefix, (3,))
    n_cells = int(np.prod(res))
    c.require(n_cells <= 1 << 27, f"{what} has more than 2**27 cells")
    cell_size = _positive(f"{prefix}.cell_size", c.array(arrays, f"{prefix}.cell_size", np.float64, (3,)))
    first, prims = _references(arrays, prefix, n_cells, n_prims, np.int32)
    return lo, hi, res, cell_size, first, prims


def _load_grid(accel, meta, arrays):
    accel.grid = GridArrays(*_uniform_cells(arrays, "grid", len(accel.scene), "grid"))
    _mailbox(accel)


# --- hgrid --------------------------------------------------------------------------------

def _save_hgrid(accel):
    return {}, _named(accel.hgrid, "hgrid")


def _load_hgrid(accel, meta, arrays):
    lo, hi = _box3(arrays, "hgrid")
    grid_res = c.array(arrays, "hgrid.grid_res", np.int64, (None, 3))
    n_grids = len(grid_res)
    c.require(n_grids >= 1 and bool((grid_res >= 1).all()) and bool((grid_res <= 1 << 20).all()),
              "hgrid.grid_res must hold at least one grid of 1 .. 2**20 cells per axis")
    grid_lo = c.finite("hgrid.grid_lo", c.array(arrays, "hgrid.grid_lo", np.float64, (n_grids, 3)))
    size = _positive("hgrid.grid_cell_size", c.array(arrays, "hgrid.grid_cell_size", np.float64, (n_grids, 3)))
    cells = grid_res.prod(axis=1)
    n_cells = int(cells.sum())
    c.require(n_cells <= 1 << 28, "hgrid has more than 2**28 cells")
    base = c.array(arrays, "hgrid.grid_cell_base", np.int64, (n_grids,))
    c.require(np.array_equal(base, np.cumsum(cells) - cells), "hgrid.grid_cell_base does not follow the grids")
    level = c.array(arrays, "hgrid.grid_level", np.int64, (n_grids,))
    child = c.array(arrays, "hgrid.cell_child", np.int32, (n_cells,))
    c.index_range("hgrid.cell_child", child, -1, n_grids)
    nested = np.flatnonzero(child >= 0)
    owner = np.repeat(np.arange(n_grids), cells)
    c.single_parents("hgrid nesting", owner[nested], child[nested].astype(np.int64), n_grids)
    c.require(int(level[0]) == 0 and bool((level[child[nested]] == level[owner[nested]] + 1).all())
              and len(nested) == n_grids - 1, "hgrid levels do not follow the nesting")
    first, prims = _references(arrays, "hgrid", n_cells, len(accel.scene), np.int64)
    accel.hgrid = HierarchicalGridArrays(lo, hi, grid_lo, grid_res, size, base, level, child, first, prims)
    _mailbox(accel)


# --- binary trees shared by the BVH and the grid-BVH hybrid --------------------------------

def binary_tree(arrays, prefix, what, name, n_prims):
    """The checked binary BVH saved under ``prefix`` (boxes, child links, leaf ranges and a
    permutation of the ``n_prims`` primitives), ``what`` and ``name`` naming it in errors:
    ``(node_box, node_first, node_count, prim_order, node_depths)``."""
    box = c.boxes(f"{prefix}.node_box", c.array(arrays, f"{prefix}.node_box", np.float64, (None, 6)))
    n = len(box)
    c.require(n >= 1, f"{what} has no node")
    first = c.array(arrays, f"{prefix}.node_first", np.int32, (n,))
    count = c.array(arrays, f"{prefix}.node_count", np.int32, (n,))
    order = c.permutation(f"{prefix}.prim_order", c.array(arrays, f"{prefix}.prim_order", np.int64, (None,)),
                          n_prims)
    return box, first, count, order, tree_checks(name, first, count, n_prims, (0,))


def tree_checks(name, node_first, node_count, n_refs, roots):
    """Inner nodes (count 0) link forward to two children; leaves (count >= 1) hold a range
    of ``n_refs`` references. Returns the depth of every node below the ``roots``."""
    n = len(node_first)
    inner = node_count == 0
    parents = np.flatnonzero(inner)
    children = np.concatenate((node_first[inner], node_first[inner] + 1)).astype(np.int64)
    c.single_parents(name, np.concatenate((parents, parents)), children, n, roots)
    c.leaf_ranges(name, node_first[~inner], node_count[~inner], n_refs)
    c.require(bool((node_count[~inner] >= 1).all()), f"{name} has a negative count")
    return node_depths(node_first, node_count)


# --- bvh ----------------------------------------------------------------------------------

def _save_bvh(accel):
    meta = {"pad": accel.pad}
    if hasattr(accel, "sah_cost_at_build"):
        meta["sah_cost_at_build"] = accel.sah_cost_at_build
    b = accel.bvh
    arrays = {"bvh.node_box": b.node_box, "bvh.node_first": b.node_first, "bvh.node_count": b.node_count,
              "bvh.prim_order": b.prim_order}
    if accel.wide is not None:
        arrays["bvh.wide_slots"], arrays["bvh.wide_children"] = accel._wide_tree
    return meta, arrays


def _wide_tree(arrays, node_count, max_depth):
    """The saved collapse of the checked binary tree into the wide one, checked: slots
    hold binary nodes or -1 (slot 0 always used), inner slots link forward to wide nodes
    with one parent each, and the wide tree is no deeper than the binary one (whose depth
    sizes the traversal stack). None when the file has none, or one of another width (a
    file from before the eight-wide layout), which is then derived again."""
    if "bvh.wide_slots" not in arrays or np.ndim(arrays["bvh.wide_slots"]) != 2 \
            or np.shape(arrays["bvh.wide_slots"])[1] != WIDTH:
        return None
    slots = c.array(arrays, "bvh.wide_slots", np.int32, (None, WIDTH))
    children = c.array(arrays, "bvh.wide_children", np.int32, (len(slots), WIDTH))
    c.require(len(slots) >= 1, "the wide BVH has no node")
    c.index_range("bvh.wide_slots", slots, -1, len(node_count))
    c.require(bool((slots[:, 0] >= 0).all()), "a wide BVH node has no first child")
    inner = slots >= 0
    inner[inner] = node_count[slots[inner]] == 0
    parents = np.nonzero(inner)[0]
    c.single_parents("the wide BVH", parents, children[inner].astype(np.int64), len(slots))
    c.require(wide_depth(slots, children, node_count) <= max_depth, "the wide BVH is deeper than its binary tree")
    return slots, children


def _load_bvh(accel, meta, arrays):
    options = accel.options
    c.require(options.get("bounds") in _BOUNDS, "option bounds is not one the BVH knows")
    c.require(options["bounds"] != "aabb" or options.get("width") in (2, 4, WIDTH),
              f"option width must be 2 or {WIDTH}")
    if options["bounds"] == "aabb" and options["width"] == 4:
        options["width"] = WIDTH
    c.require(options["bounds"] != "sphere" or options.get("sphere_fit") in ("primitives", "children"),
              "option sphere_fit must be 'primitives' or 'children'")
    pad = meta.get("pad")
    c.require(isinstance(pad, float) and np.isfinite(pad) and pad >= 0, "pad must be a finite float >= 0")
    n_prims = len(accel.scene)
    box, first, count, order, depth = binary_tree(arrays, "bvh", "the BVH", "bvh", n_prims)
    if "sah_cost_at_build" in meta:
        c.require(isinstance(meta["sah_cost_at_build"], float), "sah_cost_at_build must be a float")
        accel.sah_cost_at_build = meta["sah_cost_at_build"]
    accel.bounds_kind = _BOUNDS[options["bounds"]]
    accel.geometry = accel.scene.gather(order)
    wide_tree = _wide_tree(arrays, count, int(depth.max()))
    if wide_tree is not None:
        c.require(options["bounds"] == "aabb" and options["width"] == WIDTH, "a wide tree saved with a binary BVH")
        accel._wide_tree = wide_tree
    accel._pack_for_traversal(box, first, count, order, pad, same_tree=wide_tree is not None)


# --- grid-bvh -----------------------------------------------------------------------------

def _save_hybrid(accel):
    return {}, _named(accel.hybrid, "hybrid")


def _load_hybrid(accel, meta, arrays):
    lo, hi, res, size, first, prims = _uniform_cells(arrays, "hybrid", len(accel.scene), "hybrid grid")
    n_cells = int(np.prod(res))
    root = c.array(arrays, "hybrid.cell_root", np.int32, (n_cells,))
    node_box = c.finite("hybrid.node_box", c.array(arrays, "hybrid.node_box", np.float32, (None, 6)))
    n_nodes = len(node_box)
    node_first = c.array(arrays, "hybrid.node_first", np.int32, (n_nodes,))
    node_count = c.array(arrays, "hybrid.node_count", np.int32, (n_nodes,))
    c.index_range("hybrid.cell_root", root, -1, n_nodes)
    roots = root[root >= 0].astype(np.int64)
    c.require(len(np.unique(roots)) == len(roots), "two hybrid cells share one BVH root")
    depth = tree_checks("hybrid BVHs", node_first, node_count, len(prims), roots)
    accel.hybrid = GridBvhArrays(lo, hi, res, size, first, prims, root, node_box, node_first, node_count)
    accel.bvh_depth = int(depth.max()) if n_nodes else 0
    _mailbox(accel)
    accel._derive_from_layout()


# --- kdtree -------------------------------------------------------------------------------

def _save_kdtree(accel):
    kd = accel.kd
    return {}, {"kd.lo": kd.lo, "kd.hi": kd.hi, "kd.node_split": np.ascontiguousarray(kd.node_split),
                "kd.node_link": np.ascontiguousarray(kd.node_link), "kd.leaf_prims": kd.leaf_prims,
                "kd.apart_prims": accel.apart_prims}


def _load_kdtree(accel, meta, arrays):
    options = accel.options
    if "width" not in options:  # a file from before the option: eight-wide, unless it walks into empty leaves
        options["width"] = WIDTH if options.get("skip_empty", True) else 2
    problem = width_problem(options["width"], options.get("skip_empty", True))
    c.require(problem is None, f"option {problem}")
    lo, hi = _box3(arrays, "kd")
    split = c.array(arrays, "kd.node_split", np.float64, (None,))
    n = len(split)
    c.require(n >= 1, "the kd-tree has no node")
    link = c.array(arrays, "kd.node_link", np.int32, (n, 2))
    leaf_prims = c.array(arrays, "kd.leaf_prims", np.int32, (None,))
    c.index_range("kd.leaf_prims", leaf_prims, 0, len(accel.scene))
    axis, count = link[:, 1] & 3, link[:, 1] >> 2
    inner = axis != LEAF
    c.require(not count[inner].any(), "kd-tree inner nodes must hold no references")
    c.finite("kd.node_split", split[inner])  # a leaf's entry is unused
    below = link[inner, 0].astype(np.int64)
    parents = np.flatnonzero(inner)
    c.single_parents("kd-tree", np.concatenate((parents, parents)), np.concatenate((below, below + 1)), n)
    c.leaf_ranges("kd-tree", link[~inner, 0], count[~inner], len(leaf_prims))
    apart = np.zeros(0, dtype=np.int64)
    if "kd.apart_prims" in arrays:  # files written before the kd-tree kept large primitives apart lack it
        apart = c.index_range("kd.apart_prims", c.array(arrays, "kd.apart_prims", np.int64, (None,)), 0,
                              len(accel.scene))
        c.require(len(np.unique(apart)) == len(apart) and not np.isin(apart, leaf_prims).any(),
                  "the kd-tree's primitives kept apart must be distinct and absent from its leaves")
    accel.kd = KdTreeArrays.pack(lo, hi, split, link, leaf_prims)
    accel.apart_prims = apart
    accel._derive_from_tree()


# --- octree -------------------------------------------------------------------------------

def _save_octree(accel):
    return {}, _named(accel.tree, "octree")


def _load_octree(accel, meta, arrays):
    lo, hi = _box3(arrays, "octree")
    center = c.finite("octree.node_center", c.array(arrays, "octree.node_center", np.float64, (None, 3)))
    n = len(center)
    c.require(n >= 1, "the octree has no node")
    link = c.array(arrays, "octree.node_link", np.int32, (n, 2))
    leaf_prims = c.array(arrays, "octree.leaf_prims", np.int32, (None,))
    c.index_range("octree.leaf_prims", leaf_prims, 0, len(accel.scene))
    inner = link[:, 1] == -1
    c.require(bool((link[:, 1] >= -1).all()), "octree counts below -1")
    parents = np.flatnonzero(inner)
    children = (link[inner, 0].astype(np.int64)[:, None] + np.arange(8)).ravel()
    c.single_parents("octree", np.repeat(parents, 8), children, n)
    c.leaf_ranges("octree", link[~inner, 0], link[~inner, 1], len(leaf_prims))
    max_depth, frontier = 0, np.zeros(1, dtype=np.int64)
    while True:  # level by level from the root; every node has one parent, so this ends
        frontier = frontier[inner[frontier]]
        if not len(frontier):
            break
        frontier = (link[frontier, 0].astype(np.int64)[:, None] + np.arange(8)).ravel()
        max_depth += 1
    accel.tree = OctreeArrays(lo, hi, center, link, leaf_prims)
    accel.max_depth = max_depth


LAYOUTS = {
    BruteForce: (_save_none, _load_none),
    UniformGrid: (_save_grid, _load_grid),
    HierarchicalGrid: (_save_hgrid, _load_hgrid),
    GridBvh: (_save_hybrid, _load_hybrid),
    BoundingVolumeHierarchy: (_save_bvh, _load_bvh),
    KdTree: (_save_kdtree, _load_kdtree),
    Octree: (_save_octree, _load_octree),
}


def layout_of(cls):
    """The ``(save, load)`` pair describing ``cls``'s arrays."""
    for base in cls.__mro__:
        if base in LAYOUTS:
            return LAYOUTS[base]
    raise TypeError(f"{cls.__name__} has no saved layout")
