"""``kdtree``: the SAH kd-tree as an :class:`~rayaccel.structures.base.Accelerator`."""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from ..._jit import kernel, lent_rows, thread_count, thread_rows
from ..._validate import check_flag, check_number
from ...geometry.gather import layout_nbytes
from ...geometry.kinds import TRIANGLE
from ...ray_order import MIN_PACKET_RAYS, interleaving_pays, lane_packets_pay, packets_pay, sample_neighbours
from ...ray_tiles import image_row_length
from ...stats import box_area, surface_area_stats
from ..actions import NEAREST
from ..base import Accelerator, interval_stacks, walk_rays
from ..bvh.accelerator import trace_wide
from ..bvh.wide import WIDTH
from ..grid.build_uniform import grid_box
from ..large_primitives import large_primitives
from ..point_queries import nearest_walk_scratch
from .build_sah_binned import build_binned_top
from .build_sah_events import build_subtrees
from .layout import CHILD_SHIFT, LEAF, MAX_NODES, KdTreeArrays, node_cells
from .nearest import kdtree_nearest_kernel
from .traverse import RAY_ROW, kdtree_closest_kernel, kdtree_crossings_kernel
from .traverse_interleaved import SLOT_FLOATS, SLOT_INTS, SLOTS, interleaved_closest_kernel
from .traverse_packet import PACKET, PACKET_ROWS, kdtree_packet_kernel
from .wide_cells import cell_hierarchy

__all__ = ["KdTree", "ROWS_BYTES_PER_TRIANGLE", "width_problem"]

_MAX_PRIMS = 1 << 28  # leaf counts are stored as count << 2 in an int32
_ROW_BYTES = 9 * 4  # a triangle's three corners in float32
ROWS_BYTES_PER_TRIANGLE = 90.0
"""The most bytes a triangle the kd-tree spends to keep its triangles in float32 (the lanes layout
of :mod:`rayaccel.geometry.gather`), under the
91.9 that Embree's BVH holds on the full dragon (measured here): the budget of every layout."""
_BATCHES_PER_THREAD = 4


@kernel
def _graft_nodes(node_split, node_link, placeholders, roots, splits, links, counts, refs, n_refs, out_split,
                 out_link):
    """The node arrays of :func:`_graft`: the tree's nodes, then each forest's nodes but its
    roots (which go to their placeholders), with links moved to the new numbering."""
    n_tree = node_split.shape[0]
    out_split[:n_tree] = node_split
    out_link[:n_tree] = node_link
    source = 0
    target = n_tree
    ref_first = n_refs
    placeholder = 0
    for f in range(counts.shape[0]):
        for j in range(counts[f]):
            row = placeholders[placeholder + j] if j < roots[f] else target + j - roots[f]
            out_split[row] = splits[source + j]
            leaf = (links[source + j, 1] & 3) == LEAF
            out_link[row, 0] = links[source + j, 0] + (ref_first if leaf else target - roots[f])
            out_link[row, 1] = links[source + j, 1]
        source += counts[f]
        target += counts[f] - roots[f]
        ref_first += refs[f]
        placeholder += roots[f]


def _graft(tree, placeholders, forests):
    """Put the roots of each forest ``(node_split, node_link, leaf_prims, roots)`` -- its first
    ``roots`` nodes, grown by :func:`build_subtrees` or :func:`build_binned_top` -- in place
    of their placeholder leaves in ``tree`` (node_split, node_link, leaf_prims), in the
    order of ``placeholders``, and append their other nodes and their leaf references.
    Returns the new tree and, per forest, the index its node ``roots`` got (its node
    ``k >= roots`` is at that index + k - roots)."""
    node_split, node_link, leaf_prims = tree
    if not forests:
        return tree, np.zeros(0, dtype=np.int64)
    counts = np.array([len(split) for split, _, _, _ in forests], dtype=np.int64)
    roots = np.array([root_count for _, _, _, root_count in forests], dtype=np.int64)
    refs = np.array([len(leaves) for _, _, leaves, _ in forests], dtype=np.int64)
    n_nodes = len(node_split) + int(counts.sum() - roots.sum())
    out_split = np.empty(n_nodes)
    out_link = np.empty((n_nodes, 2), dtype=np.int32)
    _graft_nodes(node_split, node_link, np.asarray(placeholders, dtype=np.int64), roots,
                 np.concatenate([forest[0] for forest in forests]), np.concatenate([forest[1] for forest in forests]),
                 counts, refs, len(leaf_prims), out_split, out_link)
    firsts = len(node_split) + np.cumsum(counts - roots) - (counts - roots)
    leaves = np.concatenate([leaf_prims] + [forest[2] for forest in forests])
    return (out_split, out_link, leaves), firsts


def _balanced_batches(tasks, batches):
    """``tasks`` (node, ids, boxes, cell, depth) dealt into ``batches`` groups of about equal
    primitive counts, largest task first."""
    groups = [[] for _ in range(batches)]
    loads = [0] * batches
    for task in sorted(tasks, key=lambda task: -len(task[1])):
        lightest = loads.index(min(loads))
        groups[lightest].append(task)
        loads[lightest] += len(task[1])
    return [group for group in groups if group]


def _exact_batch(tasks, params, defer_below=0):
    """:func:`build_subtrees` over ``tasks`` (node, ids, boxes, cell, depth): the forest
    ``(node_split, node_link, leaf_prims, roots)``, the placeholders of its roots, and the
    deferred tasks."""
    sizes = [len(task[1]) for task in tasks]
    *forest, deferred = build_subtrees(np.concatenate([task[1] for task in tasks]),
                                       np.concatenate([task[2] for task in tasks]),
                                       np.concatenate(([0], np.cumsum(sizes))), np.array([task[3] for task in tasks]),
                                       np.array([task[4] for task in tasks], dtype=np.int64), *params, defer_below)
    return (*forest, len(tasks)), [task[0] for task in tasks], list(deferred)


def width_problem(width, skip_empty) -> str | None:
    """Why a kd-tree cannot be walked at ``width`` with ``skip_empty`` (the build's and a file's
    check), or ``None`` when it can."""
    if width not in (2, WIDTH) or isinstance(width, bool):
        return f"width must be 2 or {WIDTH}, got {width!r}"
    if width == WIDTH and not skip_empty:
        return (f"skip_empty=False walks into empty leaves, which only the binary walks have: pass width=2 with it "
                f"(the width {WIDTH} walk never enters an empty leaf)")
    return None


def _tree_depth(kd: KdTreeArrays) -> int:
    """The depth of the deepest node, found level by level (children sit side by side), without
    the cells :func:`.layout.node_cells` would compute beside the depths."""
    inner = kd.axis != LEAF
    links = kd.node_records[:, 1] >> CHILD_SHIFT
    level = np.zeros(1, dtype=np.int64)
    depth = 0
    while True:
        parents = level[inner[level]]
        if len(parents) == 0:
            return depth
        level = np.concatenate((links[parents], links[parents] + 1))
        depth += 1


def _single_scratch(rows: int, depth: int) -> tuple[np.ndarray, ...]:
    """The per-thread scratch of the binary walk of one ray at a time: its stacks and the ray's row."""
    return (*interval_stacks(rows, depth + 2), thread_rows((rows, RAY_ROW)))


def _packet_scratch(rows: int, depth: int) -> tuple[np.ndarray, ...]:
    """The per-thread scratch of the binary packet walk (:mod:`.traverse_packet`)."""
    return (*_single_scratch(rows, depth), thread_rows((rows, depth + 2), np.int64),
            thread_rows((rows, depth + 2, 2 * PACKET)), thread_rows((rows, PACKET_ROWS * PACKET)),
            thread_rows((rows, PACKET), np.int64))


def _interleaved_scratch(rows: int, depth: int) -> tuple[np.ndarray, ...]:
    """The per-thread scratch of the walk with :data:`SLOTS` rays in flight: a stack per ray in
    flight, then the rays' slots."""
    return (*interval_stacks(rows * SLOTS, depth + 2), thread_rows((rows, SLOTS, SLOT_INTS), np.int64),
            thread_rows((rows, SLOTS, SLOT_FLOATS)))


class KdTree(Accelerator):
    """``kdtree``: SAH kd-tree with perfect splits, built in O(N log N) (Wald & Havran 2006).

    Nodes of at least ``exact_below`` primitives are split by binned SAH (Popov et
    al. 2006), the rest by the exact event sweep of Wald & Havran; ``exact_below=0``
    uses the sweep throughout.

    Parameters
    ----------
    traversal_cost, intersection_cost : float, default 1 and 1.33
        ``C_t`` and ``C_i`` of the cost model ``C_t + C_i (S_L N_L + S_R N_R) / S``,
        in the proportion of Wald & Havran's K_T = 15, K_I = 20. A larger
        ``C_i / C_t`` splits deeper: fewer tests per ray, more nodes.
    empty_bonus : float in [0, 1), default 0.2
        Discount on the cost of a split with one empty side (Wald & Havran's
        lambda = 0.8); larger values cut off more empty space.
    leaf_size : int, default 12
        Nodes with at most this many primitives become leaves without trying
        a split; the SAH makes larger leaves where splitting does not pay.
        The cost model prices a node step below a test, but on a CPU a step
        waits for the load of the node before it, while a leaf's triangles lie
        next to each other: against leaf size 4 (one thread, camera, incoherent
        and shadow rays, closest and any hit, medians of 5-9 interleaved rounds,
        2026-11-27), 12 traced the full dragon 1.13-1.23 times as fast (85.2 ->
        59.9 bytes a triangle), dragon-203k 1.16-1.26, dragon-48k 1.07-1.33, the
        bunny 1.08-1.35, the armadillo 1.16-1.27, and the forests about level
        (forest-small-chair 0.96-1.04 in two runs, 0.89-1.02 in a first one on a
        slower minute; forest-large-chair 0.96-1.09); a first dragon-48k run, in
        which leaf size 4 traced at a third of its usual speed, gave 0.89-1.18. 8
        and 16 fell between or below (full dragon 16: 0.89-1.00 of 12). Raising
        ``traversal_cost`` to 2 or 3 instead gained less (0.83-0.92 of 12).
        The lecture's trees (``rayaccel experiment kdtree-table``) keep 2.
    max_depth : int, optional
        Depth limit; default ``round(8 + 1.3 log2 n)`` (pbrt's rule).
    bins : int, default 64
        Bins per axis of the binned splits.
    exact_below : int, default 4096
        Nodes with fewer primitives get the exact sweep. On the full dragon
        (871k triangles) the binned levels raise the expected cost by 0.5 %
        (90.2 against 89.7) and cut the build's median of five from 4.24 s to
        2.86 s (one run, in a slow spell of the machine).
    threads : int, optional
        Build threads (default: the parallel kernels' thread count). The top
        of the tree is built on one thread down to nodes of fewer than
        ``n / (4 threads)`` primitives; those subtrees are then built
        concurrently (the builders release the GIL) and grafted on. The
        exact sweep's cells go in four batches of about equal primitive
        counts per thread, one builder call each, which sorts its cells'
        events itself: on the full dragon this measured 8 % less CPU time
        than a call per cell with the events sorted by numpy (median of 12
        builds, 5.25 against 5.69 s).
    width : 2 or 8, default 8
        Walk the tree's cells collapsed eight to a node (:mod:`.wide_cells`) with the
        eight-wide walks of the BVH: the same cells in the same order as the binary walk,
        three levels of planes a step. Against the binary walks of the same tree, same
        answers (2026-12-06, medians of 7 interleaved rounds): forest-small-chair (one
        thread) incoherent rays 1.54 / 1.50 times as fast (closest / any hit), camera
        rays 2.08 / 3.02, shadow rays 1.44 / 1.51; the full dragon (two threads) 1.54 /
        1.74, 1.59 / 1.81 and 1.49 / 1.46. 2 walks the binary tree one plane a step, as
        the lecture's traversal does (:mod:`.traverse`); the counting and collecting
        queries, which must meet each primitive once per ray, always do. Statistics
        describe the binary tree; the node counter counts the nodes walked.
    packets : bool, default True
        With either width, trace a coherent batch (:func:`rayaccel.ray_order.packets_pay` or
        :func:`rayaccel.ray_order.lane_packets_pay`: a camera's rays, shadow rays
        from their hits to one light) in packets of eight consecutive rays that
        walk the tree together (:mod:`rayaccel.structures.kdtree.traverse_packet`), an
        image's rays in packets of four pixels by two (:mod:`rayaccel.ray_tiles`).
        ``False`` walks every ray on its own. The answers are the same either way.
    interleave : bool, default True
        With either width, trace an incoherent batch through a tree larger than the caches
        (:func:`rayaccel.ray_order.interleaving_pays`) with several rays in
        flight per thread, each ray's wait for its next node overlapping the
        others' steps (:mod:`rayaccel.structures.kdtree.traverse_interleaved`;
        closest and any hit; the counting and collecting queries walk one ray
        at a time). ``False`` walks one ray at a time. Same answers either way.
    large_apart : bool, default True
        Build the tree without the scene's few large primitives
        (:func:`rayaccel.structures.large_primitives.large_primitives`: a ground, the
        walls of a room), which every ray then tests first, as a leaf before the
        root (:mod:`rayaccel.structures.kdtree.traverse`). ``False`` keeps them in
        the leaves they cross. Same answers either way.
    skip_empty : bool, default True
        Neither enter nor push a child that is an empty leaf: the single walk and
        the packets read which children of a node are empty in its record
        (:func:`.layout.empty_flags`), so an empty leaf costs them neither a step
        nor a pop (the rays-in-flight walk enters it, uncounted), and the work
        counters count only the leaves a ray tests. ``False`` walks into empty
        leaves, as the lecture's traversal does, and counts them (``rayaccel
        experiment kdtree-table``); it needs ``width=2``, since the cells walked
        eight-wide hold no empty leaf. Same answers either way.
    """

    method = "kdtree"
    build_bytes_per_primitive = 1200

    def __init__(self, scene, *, traversal_cost=1.0, intersection_cost=1.33, empty_bonus=0.2, leaf_size=12,
                 max_depth=None, bins=64, exact_below=4096, threads=None, width=WIDTH, packets=True, interleave=True,
                 large_apart=True, skip_empty=True):
        n = len(scene)
        if n > _MAX_PRIMS:
            raise ValueError(f"the kd-tree holds at most {_MAX_PRIMS:,} primitives, got {n:,}")
        if max_depth is None:
            max_depth = int(round(8 + 1.3 * math.log2(max(n, 1))))
        options = {
            "traversal_cost": check_number("traversal_cost", traversal_cost),
            "intersection_cost": check_number("intersection_cost", intersection_cost),
            "empty_bonus": check_number("empty_bonus", empty_bonus, inclusive=True, maximum=0.99),
            "leaf_size": check_number("leaf_size", leaf_size, integer=True, minimum=1, inclusive=True),
            "max_depth": check_number("max_depth", max_depth, integer=True, inclusive=True, maximum=200),
            "bins": check_number("bins", bins, integer=True, minimum=2, inclusive=True, maximum=4096),
            "exact_below": check_number("exact_below", exact_below, integer=True, inclusive=True),
        }
        skip_empty = check_flag("skip_empty", skip_empty)
        problem = width_problem(width, skip_empty)
        if problem:
            raise ValueError(problem)
        threads = thread_count() if threads is None else check_number("threads", threads, integer=True, minimum=1,
                                                                       inclusive=True)
        super().__init__(scene, {**options, "width": width, "packets": check_flag("packets", packets),
                                 "interleave": check_flag("interleave", interleave),
                                 "large_apart": check_flag("large_apart", large_apart),
                                 "skip_empty": skip_empty})
        start = time.perf_counter()
        self.kd, self.apart_prims = self._build(scene, threads, large_apart, **options)
        self.build_seconds = time.perf_counter() - start
        self._derive_from_tree()

    def _derive_from_tree(self) -> None:
        """What the queries read besides the built (or loaded) tree: the primitives in reference
        order, read one after the other at a leaf (:meth:`~rayaccel.scene.TriangleMesh.gather`),
        and the tree's depth, which sizes the walks' stacks. Triangles are float32 lanes, 36 bytes
        a reference, when the mesh is exact in float32 and the structure then stays within
        :data:`ROWS_BYTES_PER_TRIANGLE`, else indexed: rows spare a leaf's test the dependent
        load of its vertices. On the full dragon (leaf size 4 then, 1.75 references a
        triangle), 85.2 bytes a triangle instead of 55.3 (59.9 with the leaves of 12 since),
        and incoherent rays 1.10-1.12 / 1.12-1.18 times as fast (closest / any hit), shadow
        rays 0.99-1.06, camera rays 0.96-1.09 (one thread, separate processes, two runs each,
        medians of 5 rounds, 2026-11-27). Where the tree fits the caches they gain nothing: a
        float32 copy of forest-small-chair, incoherent rays 0.92-1.07; dragon-48k, 0.95-1.07
        for 202.6 bytes a triangle instead of 114.4, over the limit. The walks read the tree's
        references followed by the primitives kept apart (``refs``, from ``apart_first`` on, in the
        box ``apart_box``; :mod:`.traverse`), and, walked eight-wide, the cells collapsed eight to a
        node (:mod:`.wide_cells`; ``cells``, ``None`` for the binary walks)."""
        self.apart_first = len(self.kd.leaf_prims)
        self.apart_box = self._box_of(self.apart_prims)
        wide = self.options.get("width", WIDTH) == WIDTH
        self.cells = cell_hierarchy(self.kd, self.apart_first, len(self.apart_prims), self.apart_box) if wide else None
        self.refs = np.concatenate((self.kd.leaf_prims, self.apart_prims.astype(np.int32)))
        self.geometry = self.scene.gather(self.refs, indexed=not self._rows_fit())
        self.max_depth = _tree_depth(self.kd)

    def _box_of(self, prims) -> np.ndarray:
        """(2, 3) lo and hi of the box around the primitives ``prims``, padded as the tree's own box
        (:func:`..grid.build_uniform.grid_box`), so that the slab test of a ray that meets one of
        them cannot round to a miss; zeros when there are none."""
        if not len(prims):
            return np.zeros((2, 3))
        scene = self.scene
        if scene.kind == TRIANGLE:
            corners = scene.vertices[scene.faces[prims]].reshape(-1, 3).astype(np.float64)
            lo, hi = corners.min(axis=0), corners.max(axis=0)
        else:
            radius = scene.radii[prims, None]
            lo, hi = (scene.centers[prims] - radius).min(axis=0), (scene.centers[prims] + radius).max(axis=0)
        return np.array(grid_box(lo, hi))

    def _build(self, scene, threads, large_apart, traversal_cost, intersection_cost, empty_bonus, leaf_size,
               max_depth, bins, exact_below):
        """``(tree, apart_prims)``: the tree over the scene's primitives but its large ones, when
        ``large_apart`` and some others remain, and the indices of those (int64)."""
        bounds = self._primitive_bounds()
        n = len(scene)
        boxes = np.hstack((bounds.lo, bounds.hi))
        ids_none = np.zeros(0, dtype=np.int64)
        apart = large_primitives(scene, bounds.scene_lo, bounds.scene_hi).prims if large_apart else ids_none
        ids = np.arange(n, dtype=np.int64)
        lo, hi = grid_box(bounds.scene_lo, bounds.scene_hi)
        if 0 < len(apart) < n:
            ids = np.delete(ids, apart)
            boxes = boxes[ids]
            lo, hi = grid_box(boxes[:, :3].min(axis=0), boxes[:, 3:].max(axis=0))
        else:
            apart = apart[:0]
        root_cell = np.concatenate((lo, hi))
        slack = 1e-11 * float(np.abs(root_cell).max() + (hi - lo).max())
        params = (scene.kind, scene.geometry, traversal_cost, intersection_cost, empty_bonus, leaf_size,
                  max_depth, slack)
        with ThreadPoolExecutor(max(threads, 1)) as pool:
            if exact_below > 0:
                tree, tasks = self._binned_top(pool, scene, ids, boxes, root_cell, threads, slack, traversal_cost,
                                               intersection_cost, empty_bonus, leaf_size, max_depth, bins, exact_below)
            else:
                root = [(0, ids, boxes, root_cell, 0)]
                defer_below = max(n // (4 * threads), 4096) if threads > 1 and n >= 8192 else 0
                forest, _, tasks = _exact_batch(root, params, defer_below)
                tree = forest[:3]
            batches = list(pool.map(lambda batch: _exact_batch(batch, params),
                                    _balanced_batches(tasks, _BATCHES_PER_THREAD * threads)))
        tree, _ = _graft(tree, [node for _, placeholders, _ in batches for node in placeholders],
                         [forest for forest, _, _ in batches])
        node_split, node_link, leaf_prims = tree
        if len(node_split) >= MAX_NODES or len(leaf_prims) >= np.iinfo(np.int32).max:
            raise ValueError(f"the kd-tree outgrew its indices ({MAX_NODES:,} nodes, int32 references); raise "
                             "leaf_size or lower max_depth")
        return KdTreeArrays.pack(lo, hi, node_split, node_link, leaf_prims), apart

    @staticmethod
    def _binned_top(pool, scene, ids, boxes, root_cell, threads, slack, traversal_cost, intersection_cost,
                    empty_bonus, leaf_size, max_depth, bins, exact_below):
        """The binned upper levels over the primitives ``ids`` with their ``boxes``: serially down to
        nodes of ``n / (4 threads)`` primitives, then those subtrees concurrently. Returns the tree
        so far and the exact sweep's tasks."""
        top = (scene.kind, scene.geometry, traversal_cost, intersection_cost, empty_bonus, leaf_size, max_depth, slack,
               bins)
        n = len(ids)
        *tree, tasks = build_binned_top(ids, boxes, root_cell, 0, *top, max(exact_below, n // (4 * threads)))
        upper = [task for task in tasks if len(task[1]) >= exact_below]
        tasks = [task for task in tasks if len(task[1]) < exact_below]
        results = list(pool.map(lambda task: build_binned_top(*task[1:], *top, exact_below), upper))
        tree, firsts = _graft(tree, [task[0] for task in upper], [(*result[:3], 1) for result in results])
        for placeholder, first, result in zip([task[0] for task in upper], firsts, results):
            tasks += [(first + node - 1 if node else placeholder, *task) for node, *task in result[3]]
        return tree, tasks

    def _rows_fit(self) -> bool:
        """Whether the triangles can be float32 lanes in reference order (:meth:`_derive_from_tree`):
        exact in float32, and the tree, its references and the rows within
        :data:`ROWS_BYTES_PER_TRIANGLE`."""
        scene = self.scene
        if scene.kind != TRIANGLE or not scene.float32_exact:
            return False
        k = self.kd
        rows_bytes = k.nbytes + self._cells_nbytes + (len(k.leaf_prims) + len(self.apart_prims)) * _ROW_BYTES
        return rows_bytes <= ROWS_BYTES_PER_TRIANGLE * len(scene)

    def node_cells(self) -> np.ndarray:
        """(n_nodes, 6) cell of every node, lo and hi, derived from the planes at each call: kept
        beside the tree, with each node's depth, they held 93.5 bytes a triangle of the full
        dragon, more than the 55.3 of the tree and its primitives that the queries read."""
        return node_cells(self.kd.lo, self.kd.hi, *self.kd.walk_records)[0]

    @property
    def _cells_nbytes(self) -> int:
        return self.cells.nbytes if self.cells is not None else 0

    @property
    def _large_primitives_first(self) -> bool:
        """Whether :meth:`Accelerator._walk_prepared` tests the large primitives first: not when the
        tree keeps them apart, which every walk visits first (:func:`.traverse.visit_apart`; walked
        eight-wide, the first child of the root an any-hit walk takes, :mod:`.wide_cells`)."""
        return not len(self.apart_prims)

    @property
    def _walk_checks_rays(self) -> bool:
        """The eight-wide walks test the rays themselves (see the BVH's)."""
        return self.cells is not None

    @property
    def _walk_takes_float32(self) -> bool:
        """The eight-wide walks over triangles read float32 rays as they are (see the BVH's)."""
        return self.cells is not None and self.scene.kind == TRIANGLE

    @property
    def _walk_takes_shared_origin(self) -> bool:
        """The eight-wide walks over triangles take a camera's one origin as one (see the BVH's)."""
        return self._walk_takes_float32

    def _trace(self, batch, any_hit, action, work):
        if self.cells is not None and action.mode == NEAREST:
            cells = self.cells
            return trace_wide(cells.records, cells.root_record, self.refs, self.scene.kind, self.geometry, cells.depth,
                              batch, any_hit, action, work, packets=self.options.get("packets", True),
                              interleave=self.options.get("interleave", True), scene_box=self.scene_box,
                              nbytes=cells.nbytes + self.refs.nbytes + layout_nbytes(self.geometry))
        k = self.kd
        rows = numba.config.NUMBA_NUM_THREADS
        n_rays = len(batch.origins)
        walk = self._nearest_walk(batch, work) if action.mode == NEAREST else kdtree_crossings_kernel
        with self._mailboxes_for(action).lend(n_rays) as (mailbox, base):
            apart_box = self.apart_box if len(self.apart_prims) else None
            skip_empty = True if self.options.get("skip_empty", True) else None
            rays = (k.lo, k.hi, *k.walk_records, skip_empty, self.refs, self.apart_first, apart_box,
                    self.scene.kind, self.geometry, *batch, any_hit, mailbox if mailbox.shape[0] else None, base)
            if walk is kdtree_packet_kernel:
                with lent_rows(_packet_scratch, rows, self.max_depth) as scratch:
                    walk_rays(walk, n_rays, *rays, *scratch, image_row_length(batch.directions), action, work,
                              align=PACKET)
            elif walk is interleaved_closest_kernel:
                with lent_rows(_interleaved_scratch, rows, self.max_depth) as (stack_node, stack_t, *slots):
                    walk_rays(walk, n_rays, *rays, stack_node, stack_t, SLOTS, *slots, action, work)
            else:
                with lent_rows(_single_scratch, rows, self.max_depth) as scratch:
                    walk_rays(walk, n_rays, *rays, *scratch, action, work)

    @property
    def _walk_gains_from_sorting(self) -> bool:
        """The eight-wide walks trace incoherent rays slower sorted (see the BVH's). For the binary
        walks, sorting an incoherent batch (:mod:`rayaccel.ray_order`) and keeping rays in flight
        hide the same waits, and the interleaved walk does better with the rays as given: full dragon,
        2**20 incoherent rays, two threads, closest / any hit, 3.16 / 3.34 Mrays/s as given
        against 2.88 / 2.97 sorted, and 2.71 / 2.78 and 2.77 / 2.86 for the single walk
        (medians of 7 interleaved rounds). So the binary walks' rays are sorted only without
        ``interleave``."""
        return self.cells is None and not self.options.get("interleave", True)

    def _nearest_walk(self, batch, work):
        """The closest-hit and any-hit walk for ``batch``: packets for a coherent batch (the
        ``packets`` option; :func:`rayaccel.ray_order.packets_pay` or
        :func:`rayaccel.ray_order.lane_packets_pay`: a camera's rays, shadow rays from their hits
        to one light) when no counters are asked for, several rays in flight per thread for an
        incoherent batch through a tree larger than the caches (the ``interleave`` option;
        :func:`rayaccel.ray_order.interleaving_pays`), else one ray at a time."""
        sampled = None
        if work is None and self.options.get("packets", True) and len(batch.origins) >= MIN_PACKET_RAYS:
            sampled = sample_neighbours(batch, *self.scene_box)
            if packets_pay(batch, *self.scene_box, sampled) or lane_packets_pay(batch, *self.scene_box, sampled):
                return kdtree_packet_kernel
        if self.options.get("interleave", True) and interleaving_pays(batch, *self.scene_box, self.nbytes, sampled):
            return interleaved_closest_kernel
        return kdtree_closest_kernel

    def _nearest(self, points, limit_d2, out_d2, out_prim):
        """Near side of each plane first (:mod:`.nearest`)."""
        k = self.kd
        rows, depth = numba.config.NUMBA_NUM_THREADS, self.max_depth + 2
        pad = 1e-9 * float(np.abs(k.lo).max() + np.abs(k.hi).max() + (k.hi - k.lo).max())
        with lent_rows(nearest_walk_scratch, rows, depth) as stacks:
            kdtree_nearest_kernel(k.lo, k.hi, *k.walk_records, self.refs, self.apart_first, self.scene.kind,
                                  self.geometry, pad, points, limit_d2, *stacks, out_d2, out_prim)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the tree, its cells walked eight-wide, and the
        primitives in reference order, those kept apart last."""
        return int(self.kd.nbytes + self._cells_nbytes + 4 * len(self.apart_prims) + layout_nbytes(self.geometry))

    def _structure_stats(self) -> dict:
        k = self.kd
        leaf = k.axis == LEAF
        counts = k.count[leaf]
        cells, depth = node_cells(k.lo, k.hi, *k.walk_records)
        areas = box_area(cells[:, :3], cells[:, 3:])
        nonempty = int(np.count_nonzero(counts))
        over_leaf_size = counts > self.options["leaf_size"]
        at_depth_limit = over_leaf_size & (depth[leaf] >= self.options["max_depth"])
        result = {
            "nodes": k.n_nodes,
            "leaves": int(leaf.sum()),
            "nonempty_leaves": nonempty,
            "max_depth": self.max_depth,
            "references": len(k.leaf_prims),
            "primitives_apart": len(self.apart_prims),
            "avg_prims_per_nonempty_leaf": float(counts.sum()) / max(nonempty, 1),
            "leaves_at_leaf_size": int(np.count_nonzero(counts[~over_leaf_size])),
            "leaves_at_depth_limit": int(at_depth_limit.sum()),
            "leaves_by_cost": int(over_leaf_size.sum() - at_depth_limit.sum()),
            "wide_nodes": len(self.cells.records) if self.cells is not None else 0,
            "bytes": self.nbytes,
        }
        sa = surface_area_stats(areas[0], step_areas=areas[~leaf], leaf_areas=areas[leaf], leaf_counts=counts,
                                traversal_cost=self.options["traversal_cost"],
                                intersection_cost=self.options["intersection_cost"])
        apart = len(self.apart_prims)
        sa["expected_intersections"] += apart
        sa["expected_cost"] += apart * self.options["intersection_cost"]
        result.update(sa)
        result["sah_cost"] = sa["expected_cost"]
        return result
