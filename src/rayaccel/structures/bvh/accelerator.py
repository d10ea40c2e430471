"""The BVH methods as :class:`~rayaccel.structures.base.Accelerator` classes, one per builder."""

from __future__ import annotations

import time

import numba
import numpy as np

from ..._jit import lent_rows, thread_count, thread_rows
from ..._validate import check_flag, check_number
from ...geometry.gather import layout_nbytes, layout_rows
from ...geometry.kdop import KDOP_NORMALS, kdop_surface_areas
from ...geometry.kinds import TRIANGLE
from ...ray_order import MIN_PACKET_RAYS, interleaving_pays, lane_packets_pay, packets_pay, sample_neighbours
from ...ray_tiles import TILE_ROWS, image_row_length
from ...stats import surface_area_stats
from ..actions import COUNT, NEAREST
from ..base import Accelerator, walk_rays
from .binary_from_wide import binary_from_wide, slot_depths
from .build_ploc import build_ploc
from .build_top_down import MORTON, OBJECT_MEDIAN, SAH_BINNED, SAH_SWEEP, SPATIAL_MEDIAN, build_top_down
from .fast_winding import winding_moments
from .lane_slab import LANE_SLAB_ROWS
from .layout import BvhArrays, node_rows, pack_nodes
from .nearest import binary_walk_stacks, bvh_nearest_kernel
from .nodes import box_surface_areas, grow_by_rounding_margin, node_depths, sah_cost
from .packet_slab import BOUND_VALUES, PACKET
from .refit import refit_bvh, refit_geometry_boxes
from .reinsertion import reinsert_subtrees
from .split_morton import morton_codes
from .traverse import BOX, KDOP, SPHERE_VOLUME, bvh_closest_kernel, bvh_crossings_kernel
from .traverse_interleaved import (
    SLOT_FLOATS,
    SLOT_INTS,
    SLOTS,
    interleaved_count_kernel,
    interleaved_crossings_kernel,
    interleaved_nearest_kernel,
)
from .traverse_packet import (
    LANE_ROWS,
    SPAN,
    lane_packet_crossings_kernel,
    lane_packet_kernel,
    wide_packet_crossings_kernel,
    wide_packet_kernel,
)
from .traverse_wide import wide_count_kernel, wide_crossings_kernel, wide_nearest_kernel
from .volumes import fit_kdops, fit_spheres
from .wide import WIDTH, wide_records, wide_tree
from .wide_slab import child_entry_rows

__all__ = ["BVH_CLASSES", "trace_wide", "wide_stacks", "single_walk_scratch"]

_BOUNDS = {"aabb": BOX, "sphere": SPHERE_VOLUME, "kdop": KDOP}

# The eight-wide walks compiled for one action mode, its constant pruning the others' code; any
# other mode takes the walk compiled for every mode.
_PACKET_WALKS = {NEAREST: wide_packet_kernel}
_LANE_PACKET_WALKS = {NEAREST: lane_packet_kernel}
_INTERLEAVED_WALKS = {NEAREST: interleaved_nearest_kernel, COUNT: interleaved_count_kernel}
_WIDE_WALKS = {NEAREST: wide_nearest_kernel, COUNT: wide_count_kernel}

# The eight-wide BVH keeps rays in flight only in a tree beyond this many second-level caches (the
# kd-tree, whose every step waits for the one before, beyond four). Against one ray at a time, two
# threads, 2^20 incoherent rays, closest / any hit, on a 1 MiB second level (2026-11-28):
# forest-small-chair in float32 rows (4.1 MiB) 0.79 / 0.77; armadillo (5.5 MiB) 0.92 / 0.91 and
# 0.83 / 0.87; dragon-203k's first 100,000, 140,000 and 170,000 triangles (6.6, 9.9 and 12.1 MiB)
# 0.95 / 0.97, 0.92 / 0.98 and 0.94 / 0.98; the whole of dragon-203k (14.5 MiB) 1.15 / 1.18 and
# 1.11 / 1.05; the full dragon (58 MiB) 1.35 / 1.40 (README, "Library").
_INTERLEAVE_CACHES = 13


def wide_stacks(rows: int, depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``rows`` stacks deep enough for the eight-wide walks of a binary tree ``depth`` deep (each
    wide node pushes at most seven entries): the entries' links, primitive counts and entry
    distances."""
    size = (WIDTH - 1) * depth + 2
    return thread_rows((rows, size), np.int32), thread_rows((rows, size), np.int32), thread_rows((rows, size))


def single_walk_scratch(rows: int, depth: int) -> tuple:
    """The per-thread scratch of the eight-wide walk of one ray at a time (:mod:`.traverse_wide`; the
    grid-BVH's cells walk it too): :func:`wide_stacks` and the children's entry distances."""
    return *wide_stacks(rows, depth), child_entry_rows(rows)


def _packet_scratch(rows: int, depth: int) -> tuple:
    """The per-thread scratch of the packet walks (:mod:`.traverse_packet`)."""
    return (*wide_stacks(rows, depth), thread_rows((rows, WIDTH)), thread_rows((rows, LANE_ROWS * PACKET)),
            thread_rows((rows, LANE_SLAB_ROWS * PACKET), np.float32), thread_rows((rows, BOUND_VALUES)),
            thread_rows((rows, PACKET), np.int64))


def _interleaved_scratch(rows: int, depth: int) -> tuple:
    """The per-thread scratch of the eight-wide walk with :data:`SLOTS` rays in flight
    (:mod:`.traverse_interleaved`): a stack per ray in flight, the child entry rows, the rays' slots."""
    return (*wide_stacks(rows * SLOTS, depth), child_entry_rows(rows), thread_rows((rows, SLOTS, SLOT_INTS), np.int64),
            thread_rows((rows, SLOTS, SLOT_FLOATS)))


def trace_wide(records, root_record, prim_order, kind, geometry, depth, batch, any_hit, action, work, *, packets,
               interleave, scene_box, nbytes):
    """Trace ``batch`` through eight-wide ``records`` (:mod:`.wide`) over ``geometry`` in leaf order
    (``prim_order``), collapsed from a binary tree ``depth`` deep whose root box is row 0 of
    ``root_record``: in packets when ``packets`` and the batch is coherent (a camera's rays, shadow
    rays to one light), with several rays in flight per thread when ``interleave`` and the
    structure (``nbytes``) outgrows the caches, else one ray at a time; each walk compiled for the
    action's mode where there is one. A batch sharing one origin
    (:attr:`rayaccel.rays.RayBatch.shares_origin`) keeps it so in the interval packets only, which
    read it once per packet (:func:`.packet_slab.bound_span`, :func:`.packet_slab.load_packet`);
    the other walks get it copied to every ray. Returns what the walk returns (the unusable rays
    met)."""
    rows = numba.config.NUMBA_NUM_THREADS
    n_rays = batch.size
    tree = (records, records.view(np.int32), prim_order, kind, geometry)

    def in_packets(walk, batch):
        with lent_rows(_packet_scratch, rows, depth) as scratch:
            return walk_rays(walk, n_rays, root_record, *tree, *batch, any_hit, *scratch,
                             image_row_length(batch.directions, SPAN // TILE_ROWS), action, align=SPAN)

    sampled = None
    if work is None and packets and n_rays >= MIN_PACKET_RAYS:
        sampled = sample_neighbours(batch, *scene_box)
        if packets_pay(batch, *scene_box, sampled):
            return in_packets(_PACKET_WALKS.get(action.mode, wide_packet_crossings_kernel), batch)
    batch = batch.with_origin_per_ray()
    if sampled is not None and lane_packets_pay(batch, *scene_box, sampled):
        return in_packets(_LANE_PACKET_WALKS.get(action.mode, lane_packet_crossings_kernel), batch)
    if interleave and interleaving_pays(batch, *scene_box, nbytes, sampled, caches=_INTERLEAVE_CACHES):
        walk = _INTERLEAVED_WALKS.get(action.mode, interleaved_crossings_kernel)
        with lent_rows(_interleaved_scratch, rows, depth) as (*stacks, entry, slot_ints, slot_floats):
            return walk_rays(walk, n_rays, root_record, *tree, *batch, any_hit, *stacks, entry, SLOTS, slot_ints,
                             slot_floats, action, work)
    walk = _WIDE_WALKS.get(action.mode, wide_crossings_kernel)
    with lent_rows(single_walk_scratch, rows, depth) as scratch:
        return walk_rays(walk, n_rays, root_record, *tree, *batch, any_hit, *scratch, action, work)


class BoundingVolumeHierarchy(Accelerator):
    """Common part of every BVH: options, volume fitting, traversal and statistics.

    Options shared by all builders
    ------------------------------
    max_leaf_size : int
        Largest number of primitives in a leaf (SAH builders make smaller
        leaves where splitting is cheaper).
    traversal_cost, intersection_cost : float, default 2 (3 without the wide traversal), 1
        ``C_t`` and ``C_i`` of the SAH, used by the SAH and agglomerative
        builders to decide splits and leaves, and by ``stats()``. A binary
        step tests two child volumes and fetches a node pair; measured on the
        full dragon, C_t = 3 against C_t = C_i: build 1.54 -> 1.33 s, primary
        rays 4.4 -> 5.3 Mrays/s. A wide traversal tests several boxes per
        prefetched fetch, so a step costs less against a primitive test: on the
        four-wide layout C_t = 2 against 3 gave incoherent rays +8 to +11 % in two interleaved
        runs (primary -5 to +6 %, any hit +2 to +7 %, within the noise).
    bounds : "aabb", "sphere" or "kdop"
        The node volume the traversal tests: boxes (cheapest test), spheres
        (rotation invariant, usually looser) or 14-DOPs (7 slabs, tightest,
        dearest). The tree is always built on boxes.
    sphere_fit : "primitives" or "children"
        With ``bounds="sphere"``: Ritter's sphere over all primitives below the
        node, or the exact sphere around the two child spheres.
    width : 2 or 8, default 8
        With ``bounds="aabb"``, traverse the binary tree collapsed into eight-wide
        nodes (:mod:`rayaccel.structures.bvh.wide`): full dragon, 6.8 nodes and leaves
        visited per incoherent ray against the binary walk's 17.3 (camera rays 2.9
        against 7.4); 2 walks the binary tree. Statistics always
        describe the binary tree; the node counter counts the nodes walked.
        (Files saved with the former ``width=4`` load as ``width=8``.)
    packets : bool, default True
        With the eight-wide walk, trace a coherent batch in packets of eight consecutive
        rays (:mod:`rayaccel.structures.bvh.traverse_packet`): rays that share an origin and
        head alike, as a pinhole camera's do (:func:`rayaccel.ray_order.packets_pay`), against
        bounds of the whole packet; rays that start near each other and head alike, as shadow
        rays from neighbouring hits to one light do (:func:`rayaccel.ray_order.lane_packets_pay`),
        lane by lane. An image's rays given row after row go in packets of four pixels by two
        (:mod:`rayaccel.ray_tiles`). ``False`` walks every ray on its own. The answers are the
        same either way.
    interleave : bool, default True
        With the eight-wide walk, trace a batch of incoherent rays through a tree larger
        than the caches (:func:`rayaccel.ray_order.interleaving_pays`) with several rays
        in flight per thread, taking steps in turn, so that one ray's wait for memory
        overlaps the others' work (:mod:`rayaccel.structures.bvh.traverse_interleaved`);
        ``False`` walks the rays one after the other. The answers are the same either way.
    reinsertion : bool, default True for ``bvh-binned``, False for the other builders
        After the build, move the subtrees that bound their children worst to where they
        add the least area (:mod:`rayaccel.structures.bvh.reinsertion`, Bittner et al.
        2013), while a round of moves lowers the inner nodes' total area by 1 % or more;
        a tree it would improve by less is kept as built. The other builders default to
        their trees as published; the builders' experiment runs every one as published.
    """

    default_leaf_size = 4
    default_reinsertion = False
    _large_primitives_first = False
    """A BVH meets a large primitive near its root: testing the large ones first cost ``bvh-binned``
    on forest-small-chair's incoherent rays more than it saved (any hit, one thread: 0.90 of the
    speed without)."""

    def __init__(self, scene, *, max_leaf_size=None, traversal_cost=None, intersection_cost=1.0, bounds="aabb",
                 sphere_fit="primitives", width=WIDTH, packets=True, interleave=True, reinsertion=None,
                 **builder_options):
        max_leaf_size = self.default_leaf_size if max_leaf_size is None else max_leaf_size
        reinsertion = self.default_reinsertion if reinsertion is None else reinsertion
        wide = bounds == "aabb" and width == WIDTH
        if traversal_cost is None:
            traversal_cost = 2.0 if wide else 3.0
        max_leaf_size = check_number("max_leaf_size", max_leaf_size, integer=True)
        traversal_cost = check_number("traversal_cost", traversal_cost)
        intersection_cost = check_number("intersection_cost", intersection_cost)
        if bounds not in _BOUNDS:
            raise ValueError(f"bounds must be one of {tuple(_BOUNDS)}, got {bounds!r}")
        if sphere_fit not in ("primitives", "children"):
            raise ValueError(f"sphere_fit must be 'primitives' or 'children', got {sphere_fit!r}")
        if width not in (2, WIDTH) or isinstance(width, bool):
            raise ValueError(f"width must be 2 or {WIDTH}, got {width!r}")
        check_flag("reinsertion", reinsertion)
        options = {"max_leaf_size": max_leaf_size, "traversal_cost": traversal_cost,
                   "intersection_cost": intersection_cost, "bounds": bounds, "reinsertion": reinsertion,
                   **builder_options}
        if bounds == "sphere":
            options["sphere_fit"] = sphere_fit
        if bounds == "aabb":
            options["width"] = width
        if wide:
            options["packets"] = check_flag("packets", packets)
            options["interleave"] = check_flag("interleave", interleave)
        super().__init__(scene, options)
        start = time.perf_counter()
        prim_bounds = self._primitive_bounds()
        box, first, count, order = self._build(prim_bounds, max_leaf_size, traversal_cost, intersection_cost,
                                               **builder_options)
        if reinsertion:
            box, first, count, order = reinsert_subtrees(box, first, count, order)
        pad = grow_by_rounding_margin(box)
        self.geometry = scene.gather(order)
        self.bounds_kind = _BOUNDS[bounds]
        self._pack_for_traversal(box, first, count, order, pad)
        self.build_seconds = time.perf_counter() - start

    def _pack_for_traversal(self, box, first, count, order, pad, same_tree=False, keep_binary=False):
        """Derive from the binary tree (boxes already grown by ``pad``) and :attr:`geometry`
        every array the traversal reads, and the tree's depth. The build, :meth:`refit` and
        :func:`rayaccel.load_accelerator` all go through here; ``same_tree`` (a refit, or a load
        that read the collapse from the file) keeps the wide collapse in ``_wide_tree`` and
        packs only its boxes. A BVH walked eight-wide then keeps no binary tree unless
        ``keep_binary`` (a refit, whose tree the next refit reuses): :attr:`bvh` recovers it
        when asked (:mod:`.binary_from_wide`)."""
        self.pad = pad
        depths = node_depths(first, count)
        self.max_depth = int(depths.max())
        self._winding_cache = None
        self._caps_cache = None
        bounds = self.options["bounds"]
        wide = bounds == "aabb" and self.options["width"] == WIDTH
        records = pack_nodes(box[:1], first[:1], count[:1]) if wide else pack_nodes(box, first, count)
        self.prim_order = order
        self.root_record = records
        self._binary = BvhArrays(box, first, count, order, records)
        if bounds == "kdop":
            self.volume = fit_kdops(self.scene.kind, layout_rows(self.geometry), first, count, KDOP_NORMALS)
            self.volume[:, :7] -= 2.0 * pad
            self.volume[:, 7:] += 2.0 * pad
        elif bounds == "sphere":
            self.volume = fit_spheres(self.scene.kind, layout_rows(self.geometry), first, count,
                                      self.options["sphere_fit"] == "children")
        else:
            self.volume = np.zeros((0, 1))
        self._volume_rows = node_rows(self.volume) if len(self.volume) else self.volume
        if wide and not same_tree:
            self._wide_tree = wide_tree(box, first, count)
        self.wide = wide_records(box, first, count, self._wide_tree) if wide else None
        if wide:
            self._slot_depths = slot_depths(*self._wide_tree, depths)
            if not keep_binary:
                self._binary = self._wide_tree = None

    @property
    def bvh(self) -> BvhArrays:
        """The binary tree (:mod:`.layout`): kept by a BVH walked two-wide; for one walked eight-wide,
        recovered from the wide records on first use (point queries, statistics, refit, saving)
        and kept from then on, together with the wide collapse in ``_wide_tree``."""
        if self._binary is None:
            first, count, slots, child_wide = binary_from_wide(self.wide.view(np.int32), self._slot_depths)
            box = np.empty((len(first), 6))
            refit_geometry_boxes(self.scene.kind, self.geometry, first, count, box)
            box[:, :3] -= self.pad
            box[:, 3:] += self.pad
            self._binary = BvhArrays(box, first, count, self.prim_order, self.root_record)
            self._wide_tree = slots, child_wide
        return self._binary

    def refit(self, vertices):
        """Move the primitives to new positions and refit the tree's volumes bottom-up
        (:mod:`.refit`), keeping its topology: an animated or deformed mesh (same faces,
        new ``vertices`` (V, 3)), or spheres (same radii, new centres (N, 3)).
        ``stats()`` then shows ``sah_cost`` beside ``sah_cost_at_build``; when it has grown
        much, a fresh ``ra.build`` traces faster."""
        refit_bvh(self, vertices)

    def _build(self, prim_bounds, max_leaf_size, traversal_cost, intersection_cost, **options):
        raise NotImplementedError

    @property
    def _walk_gains_from_sorting(self) -> bool:
        """The eight-wide walk traces incoherent rays slower sorted, even on a structure eleven times
        the last-level cache (:mod:`rayaccel.ray_order`); the binary walks are sorted."""
        return self.wide is None

    @property
    def _walk_checks_rays(self) -> bool:
        """The eight-wide walks test the rays themselves (the single walk each ray as it reads it,
        the packet walks span by span, the interleaved walk chunk by chunk). Against checking
        them up front, 2**20 rays on two threads, time before over time after, medians of
        processes alternating with the commit before (4 forest, 3 dragon): forest-small-chair
        camera rays 1.17 closest / 1.29 any hit, incoherent 1.15 / 1.15, shadow 0.99 / 1.03; full
        dragon camera 1.12 / 1.19, incoherent 0.99 / 1.13, shadow 1.00 / 1.14."""
        return self.wide is not None

    @property
    def _walk_takes_float32(self) -> bool:
        """The eight-wide BVH walks over triangles read float32 rays as they are, widening each
        coordinate to float64 as they load it (the same hits, to the bit, as the rays' float64
        copy): a user's float32 rays are not copied, and the walks read half the bytes."""
        return self.wide is not None and self.scene.kind == TRIANGLE

    @property
    def _walk_takes_shared_origin(self) -> bool:
        """The eight-wide BVH's packet walk over triangles reads a camera's one origin once
        (:func:`trace_wide`), rather than a copy of it per ray: half the bytes a float64 camera ray
        costs, and no copy to make; the binary walk reads its rays through
        :func:`rayaccel.rays.ray_at`, which takes one origin for all as it takes one per ray."""
        return self.wide is None or self._walk_takes_float32

    def _trace(self, batch, any_hit, action, work):
        rows = numba.config.NUMBA_NUM_THREADS
        if self.wide is None:
            b = self.bvh
            walk = bvh_closest_kernel if action.mode == NEAREST else bvh_crossings_kernel
            with lent_rows(binary_walk_stacks, rows, self.max_depth) as (stack_node, stack_t):
                walk_rays(walk, batch.size, self.bounds_kind, b.node_records, self._volume_rows,
                          b.node_records.view(np.int32), b.prim_order, self.scene.kind, self.geometry, KDOP_NORMALS,
                          *batch, any_hit, stack_node, stack_t, action, work)
            return
        return trace_wide(self.wide, self.root_record, self.prim_order, self.scene.kind, self.geometry, self.max_depth,
                          batch, any_hit, action, work, packets=self.options.get("packets", True),
                          interleave=self.options.get("interleave", True), scene_box=self.scene_box,
                          nbytes=self.nbytes)

    def _nearest(self, points, limit_d2, out_d2, out_prim):
        """The walk by distance of :mod:`.nearest` over the binary tree."""
        b = self.bvh
        rows = numba.config.NUMBA_NUM_THREADS
        with lent_rows(binary_walk_stacks, rows, self.max_depth) as (stack_node, stack_d2):
            bvh_nearest_kernel(b.node_box, b.node_first, b.node_count, b.prim_order, self.scene.kind, self.geometry,
                               points, limit_d2, stack_node, stack_d2, out_d2, out_prim)

    def _winding_tree(self):
        """The fast winding number runs on this BVH's own binary tree (moments cached until a refit)."""
        if self._winding_cache is None:
            b = self.bvh
            moments = winding_moments(self.scene.kind, self.geometry, b.node_box, b.node_first, b.node_count)
            self._winding_cache = (b.node_box, b.node_first, b.node_count, self.geometry, moments, self.max_depth)
        return self._winding_cache

    def volume_areas(self) -> np.ndarray:
        """Surface area of each node's volume (the one the traversal tests)."""
        if self.bounds_kind == SPHERE_VOLUME:
            return 4.0 * np.pi * self.volume[:, 3] ** 2
        if self.bounds_kind == KDOP:
            return kdop_surface_areas(self.volume, KDOP_NORMALS)
        return box_surface_areas(self.bvh.node_box)

    def sah_cost(self, areas=None) -> float:
        """The SAH cost of the tree's volumes (``areas``: :meth:`volume_areas`, when known)."""
        areas = self.volume_areas() if areas is None else areas
        return sah_cost(areas, self.bvh.node_count, self.options["traversal_cost"], self.options["intersection_cost"])

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays that queries read: the tree, its bounding volumes and the primitives."""
        if self.wide is None:
            return int(self.bvh.traversal_bytes + self._volume_rows.nbytes + layout_nbytes(self.geometry))
        return int(self.root_record.nbytes + self.wide.nbytes + self.prim_order.nbytes + layout_nbytes(self.geometry))

    def _structure_stats(self) -> dict:
        b = self.bvh
        leaf = b.node_count > 0
        areas = self.volume_areas()
        result = {
            "nodes": b.n_nodes,
            "leaves": int(leaf.sum()),
            "nonempty_leaves": int(leaf.sum()),
            "max_depth": self.max_depth,
            "references": int(b.node_count.sum()),
            "avg_prims_per_nonempty_leaf": float(b.node_count[leaf].mean()),
            "bytes": self.nbytes,
        }
        sa = surface_area_stats(areas[0], step_areas=areas[~leaf], leaf_areas=areas[leaf],
                                leaf_counts=b.node_count[leaf],
                                traversal_cost=self.options["traversal_cost"],
                                intersection_cost=self.options["intersection_cost"])
        result.update(sa)
        result["sah_cost"] = self.sah_cost(areas)
        result["sah_cost_at_build"] = getattr(self, "sah_cost_at_build", result["sah_cost"])
        return result


def _top_down(pb, strategy, max_leaf_size, c_t, c_i, bins=0, order=None, sorted_codes=None):
    """Run the top-down builder with a split strategy; returns the layout arrays and leaf order."""
    identity = order is None
    order = np.arange(len(pb.lo), dtype=np.int64) if identity else order
    codes = np.zeros(0, np.int64) if sorted_codes is None else sorted_codes
    box, first, count = build_top_down(pb.lo, pb.hi, pb.centroid, order, codes, strategy, max_leaf_size, bins,
                                       c_t, c_i, thread_count(), identity_order=identity)
    return box, first, count, order


class BinnedSah(BoundingVolumeHierarchy):
    """``bvh-binned``: top-down binned SAH (Wald 2007), the default BVH.

    Extra option: ``bins`` (default 32), centroid intervals per axis; more bins
    get closer to the full sweep. A build bins each primitive once per axis whatever
    their number, so 32 bins cost no more than 16 (full dragon, 2 threads, medians of 5
    interleaved builds: 490 against 493 ms) and gave a tree of lower SAH cost (forest
    49.9 against 54.7, full dragon 91.0 against 92.1) that traced 1.00-1.05 times as
    fast in every column (camera, incoherent and shadow rays, closest and any hit; 2
    threads, medians of 5). A node of n primitives uses at most n / 2 bins
    (:func:`.split_sah_binned.split_sah_binned`). Leaves up to 8 primitives.
    """

    method = "bvh-binned"
    default_leaf_size = 8
    default_reinsertion = True

    def __init__(self, scene, *, bins: int = 32, **options):
        bins = check_number("bins", bins, integer=True)
        if bins < 2:
            raise ValueError(f"bins must be at least 2, got {bins}")
        super().__init__(scene, bins=bins, **options)

    def _build(self, pb, max_leaf_size, c_t, c_i, bins):
        return _top_down(pb, SAH_BINNED, max_leaf_size, c_t, c_i, bins=bins)


class SweepSah(BoundingVolumeHierarchy):
    """``bvh-sah``: top-down SAH evaluated at every sorted centroid position on all three axes
    (Goldsmith & Salmon 1987; MacDonald & Booth 1990). Best SAH quality of the object-split
    builders; O(n log^2 n) build. Leaves up to 8 primitives."""

    method = "bvh-sah"
    default_leaf_size = 8

    def _build(self, pb, max_leaf_size, c_t, c_i):
        return _top_down(pb, SAH_SWEEP, max_leaf_size, c_t, c_i)


class SpatialMedian(BoundingVolumeHierarchy):
    """``bvh-median-space``: top-down, split at the middle of the centroid box's longest axis
    (Kay & Kajiya 1986). Leaves up to 4 primitives."""

    method = "bvh-median-space"

    def _build(self, pb, max_leaf_size, c_t, c_i):
        return _top_down(pb, SPATIAL_MEDIAN, max_leaf_size, c_t, c_i)


class ObjectMedian(BoundingVolumeHierarchy):
    """``bvh-median-object``: top-down, half of the primitives (sorted along the longest
    centroid axis) on each side; a balanced tree. Leaves up to 4 primitives."""

    method = "bvh-median-object"

    def _build(self, pb, max_leaf_size, c_t, c_i):
        return _top_down(pb, OBJECT_MEDIAN, max_leaf_size, c_t, c_i)


class LinearBvh(BoundingVolumeHierarchy):
    """``bvh-lbvh``: Morton-code linear BVH (Lauterbach et al. 2009; Karras 2012): one sort
    along a Z-order curve, then splits at the codes' highest differing bit. Fastest build,
    lowest quality. Leaves up to 4 primitives."""

    method = "bvh-lbvh"

    def _build(self, pb, max_leaf_size, c_t, c_i):
        codes = morton_codes(pb.centroid)
        order = np.argsort(codes, kind="stable").astype(np.int64)
        return _top_down(pb, MORTON, max_leaf_size, c_t, c_i, order=order, sorted_codes=codes[order])


class Agglomerative(BoundingVolumeHierarchy):
    """``bvh-agglomerative``: bottom-up clustering, PLOC (Meister & Bittner 2018).

    Extra option: ``radius`` (default 16), how many neighbours along the Morton
    order each cluster considers; larger is slower and closer to exact
    agglomerative clustering (Walter et al. 2008). Subtrees of up to
    ``max_leaf_size`` (default 4) primitives collapse into leaves where the SAH prefers it.
    """

    method = "bvh-agglomerative"

    def __init__(self, scene, *, radius: int = 16, **options):
        super().__init__(scene, radius=check_number("radius", radius, integer=True), **options)

    def _build(self, pb, max_leaf_size, c_t, c_i, radius):
        codes = morton_codes(pb.centroid)
        order = np.argsort(codes, kind="stable").astype(np.int64)
        return build_ploc(pb.lo, pb.hi, order, radius, max_leaf_size, c_t, c_i)


BVH_CLASSES = (Agglomerative, SpatialMedian, ObjectMedian, SweepSah, BinnedSah, LinearBvh)
