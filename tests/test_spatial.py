"""kd-tree, octree, hierarchical grid and grid-BVH against the brute-force oracle, and their invariants."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    assert_one_and_twin_triangles_hit,
    assert_same_hits,
    axis_parallel_rays,
    camera_rays,
    examples,
    ground_and_clutter,
    random_rays,
    vertex_and_edge_rays,
)
from hypothesis import given, settings
from hypothesis import strategies as st

import rayaccel as ra
from rayaccel.geometry.gather import layout_rows
from rayaccel.geometry.overlap import prim_overlaps_box
from rayaccel.geometry.rounding import float32_below
from rayaccel.structures.bvh import accelerator as bvh_accelerator
from rayaccel.structures.bvh.wide import COUNT, LINK, WIDTH
from rayaccel.structures.kdtree import accelerator as kdtree_accelerator
from rayaccel.structures.kdtree.accelerator import ROWS_BYTES_PER_TRIANGLE
from rayaccel.structures.kdtree.events import END, PLANAR, START, write_node_events
from rayaccel.structures.kdtree.layout import LEAF

SPATIAL = ["kdtree", "octree", "hgrid", "grid-bvh"]
VARIANTS = {
    "kdtree": [{}, {"leaf_size": 1, "empty_bonus": 0.0, "threads": 1, "exact_below": 0},
               {"exact_below": 64, "bins": 8}, {"max_depth": 12}, {"width": 2}],
    "octree": [{}, {"insert": "bbox", "leaf_size": 2}],
    "hgrid": [{}, {"insert": "exact", "mailbox": False, "threshold": 2}],
    "grid-bvh": [{}, {"threshold": 1, "density": 2.0}, {"density": 0.5, "mailbox": True}],
}
CASES = [(m, options) for m in SPATIAL for options in VARIANTS[m]]


def test_methods_are_registered():
    assert set(SPATIAL) <= set(ra.methods())


def _check(reference, accel, origins, directions, t_min=0.0, t_max=np.inf):
    assert_same_hits(reference.intersect(origins, directions, t_min, t_max),
                     accel.intersect(origins, directions, t_min, t_max))
    np.testing.assert_array_equal(accel.occluded(origins, directions, t_min, t_max),
                                  reference.occluded(origins, directions, t_min, t_max))


@pytest.mark.parametrize("method,options", CASES)
@pytest.mark.parametrize("scene_name", ["small_dragon", "spheres"])
def test_agrees_with_brute_force(scene_name, method, options, request):
    scene = request.getfixturevalue(scene_name)
    reference = ra.build(scene, "none")
    accel = ra.build(scene, method, **options)
    for origins, directions in (camera_rays(scene, 40), random_rays(scene, 1500), axis_parallel_rays(scene, 600)):
        _check(reference, accel, origins, directions)


@pytest.mark.parametrize(("method", "options"), [("kdtree", {}), ("kdtree", {"max_depth": 12}), ("grid-bvh", {})])
@pytest.mark.parametrize("scene_name", ["small_dragon", "bunny", "spheres"])
def test_references_read_their_primitives_in_reference_order(method, options, scene_name, request):
    """The kd-tree and the grid-BVH hybrid test a leaf's or a cell's primitives from a copy laid
    out in the order of their references: spheres as rows; triangles, which their references
    repeat, in vertex indices, except in a kd-tree over a mesh exact in float32 whose float32
    rows keep it within ``ROWS_BYTES_PER_TRIANGLE`` (the small dragon's tree cut at depth 12:
    65 bytes a triangle; its default tree would take 105). Each counts that copy instead of the
    scene's float64 rows among the bytes a query reads."""
    scene = request.getfixturevalue(scene_name)
    accel = ra.build(scene, method, **options)
    refs = accel.kd.leaf_prims if method == "kdtree" else accel.hybrid.cell_prims
    structure = (accel.kd.nbytes + accel.cells.nbytes if method == "kdtree" else accel.hybrid.nbytes + accel.wide.nbytes
                 + accel.wide_root.nbytes + accel.mailboxes.nbytes)
    rows_fit = (method == "kdtree" and scene_name != "spheres" and scene.float32_exact
                and structure + 36 * len(refs) <= ROWS_BYTES_PER_TRIANGLE * len(scene))
    assert rows_fit == (scene_name == "small_dragon" and options == {"max_depth": 12})
    expected = scene.geometry[refs]
    if scene_name == "spheres" or rows_fit:
        corners = layout_rows(accel.geometry)[:len(refs)]
        assert accel.geometry.dtype == (np.float64 if scene_name == "spheres" else np.float32)
        geometry_bytes = accel.geometry.nbytes
    else:
        corner_ids, leaf_vertices = accel.geometry
        corners = leaf_vertices[corner_ids].reshape(-1, 9)
        geometry_bytes = sum(a.nbytes for a in accel.geometry)
    np.testing.assert_array_equal(corners, expected)
    assert accel.stats()["bytes"] == structure + geometry_bytes


@pytest.mark.parametrize("method", SPATIAL)
def test_bunny_and_rays_through_vertices_edges_and_surfaces(bunny, small_dragon, method):
    reference = ra.build(bunny, "none")
    _check(reference, ra.build(bunny, method), *camera_rays(bunny, 32))
    reference = ra.build(small_dragon, "none")
    accel = ra.build(small_dragon, method)
    _check(reference, accel, *vertex_and_edge_rays(small_dragon, 3000))
    rng = np.random.default_rng(11)
    faces = rng.integers(0, len(small_dragon), 1000)
    corners = small_dragon.geometry[faces].reshape(-1, 3, 3)
    on_surface = np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], 1000), corners)
    directions = rng.normal(size=(1000, 3))
    _check(reference, accel, on_surface, directions, 0.0, rng.uniform(0.0, 0.05, 1000))


def _kdtree_planes(accel, n, rng):
    """(axis, position) of ``n`` random split planes of the kd-tree."""
    inner = np.flatnonzero(accel.kd.axis != LEAF)
    chosen = rng.choice(inner, n)
    return accel.kd.axis[chosen], accel.kd.node_split[chosen]


def _rays_in_planes(scene, axes, positions, rng):
    """Rays lying in the given axis-aligned planes (their direction has a zero there)."""
    n = len(axes)
    b = scene.bounds()
    origins = rng.uniform(b.scene_lo - 0.1, b.scene_hi + 0.1, size=(n, 3))
    origins[np.arange(n), axes] = positions
    directions = rng.normal(size=(n, 3))
    directions[np.arange(n), axes] = rng.choice([0.0, -0.0], n)
    return origins, directions


def test_kdtree_rays_along_split_planes_and_through_cell_corners(small_dragon):
    rng = np.random.default_rng(3)
    accel = ra.build(small_dragon, "kdtree")
    reference = ra.build(small_dragon, "none")
    axes, positions = _kdtree_planes(accel, 2000, rng)
    _check(reference, accel, *_rays_in_planes(small_dragon, axes, positions, rng))
    # rays aimed at corners of leaf cells, from outside and from inside other cells
    cells = accel.node_cells()[np.flatnonzero(accel.kd.axis == LEAF)]
    corner = rng.integers(0, 2, size=(len(cells), 3)).astype(bool)
    targets = np.where(corner, cells[:, 3:], cells[:, :3])[rng.choice(len(cells), 2000)]
    b = small_dragon.bounds()
    origins = rng.uniform(b.scene_lo, b.scene_hi, size=(2000, 3))
    _check(reference, accel, origins, targets - origins)


def _rays_at_vertices_beside_planes(accel, vertices, faces, rng):
    """Rays lying in the plane ``x_axis = o`` for ``o`` at, or between, a split plane's true
    position ``p`` (a corner's coordinate) and the float32 ``q`` its node stores, aimed at the
    point of a triangle with its corner at ``p`` that lies in that plane; ``q`` and ``p``
    differ on a mesh of float64 corners."""
    kd = accel.kd
    inner = np.flatnonzero(kd.axis != LEAF)
    origins, directions = [], []
    for node in rng.choice(inner, min(len(inner), 400)):
        axis, stored = kd.axis[node], kd.node_split[node]
        corners = np.flatnonzero(float32_below(vertices[:, axis]) == stored)
        if len(corners) == 0:
            continue
        corner = rng.choice(corners)
        exact = vertices[corner, axis]
        o = rng.choice([exact, stored, 0.5 * (exact + stored)])
        face = faces[np.flatnonzero((faces == corner).any(axis=1))[0]]
        others = [v for v in face if v != corner]
        points = []
        for other in others:
            span = vertices[other, axis] - exact
            if span != 0.0 and 0.0 <= (o - exact) / span <= 1.0:
                points.append(vertices[corner] + (o - exact) / span * (vertices[other] - vertices[corner]))
        if len(points) < 2:
            continue
        target = 0.5 * (points[0] + points[1])
        target[axis] = o
        direction = rng.normal(size=3)
        direction[axis] = rng.choice([0.0, 1e-12, -1e-12])
        origins.append(target - direction)
        directions.append(direction)
    return np.array(origins).reshape(-1, 3), np.array(directions).reshape(-1, 3)


@settings(max_examples=examples(20), deadline=None)
@given(n=st.integers(2, 400), seed=st.integers(0, 2**16), exact_below=st.sampled_from([0, 64]))
def test_kdtree_rays_within_a_float32_step_of_float64_planes_property(n, seed, exact_below):
    """The kd-tree keeps each plane rounded down to float32 and walks a bracket one float32 step
    wide (:func:`rayaccel.structures.kdtree.layout.plane_bracket`): on a mesh of float64 corners,
    whose planes lie between float32 numbers, rays lying at the true plane, at the stored one
    and between them, aimed at triangles that reach the plane, and random rays parallel or
    nearly parallel to planes there, hit what brute force hits."""
    rng = np.random.default_rng(seed)
    corners = rng.uniform(0.0, np.pi, size=(n, 1, 3)) + rng.normal(scale=0.1, size=(n, 3, 3))
    vertices = corners.reshape(-1, 3)
    faces = np.arange(3 * n).reshape(n, 3)
    scene = ra.TriangleMesh(vertices, faces)
    accel = ra.build(scene, "kdtree", leaf_size=1, exact_below=exact_below)
    reference = ra.build(scene, "none")
    _check(reference, accel, *_rays_at_vertices_beside_planes(accel, vertices, faces, rng))
    m = 300
    axes = rng.integers(0, 3, m)
    exact = vertices[rng.integers(0, 3 * n, m), axes]
    stored = float32_below(exact).astype(np.float64)
    positions = np.select([rng.random(m) < 0.33, rng.random(m) < 0.5], [exact, stored], 0.5 * (exact + stored))
    origins, directions = _rays_in_planes(scene, axes, positions, rng)
    grazing = rng.random(m) < 0.3
    directions[grazing, axes[grazing]] = rng.choice([-1e-9, 1e-9], int(grazing.sum()))
    _check(reference, accel, origins, directions)


def test_octree_and_grids_rays_through_cell_corners_and_planes(small_dragon):
    rng = np.random.default_rng(4)
    reference = ra.build(small_dragon, "none")
    octree = ra.build(small_dragon, "octree")
    inner = np.flatnonzero(~octree.tree.leaf)
    centers = octree.tree.node_center[rng.choice(inner, 2000)]
    b = small_dragon.bounds()
    origins = rng.uniform(b.scene_lo, b.scene_hi, size=(2000, 3))
    _check(reference, octree, origins, centers - origins)
    axes = rng.integers(0, 3, 2000)
    _check(reference, octree, *_rays_in_planes(small_dragon, axes, centers[np.arange(2000), axes], rng))
    for method in ("hgrid", "grid-bvh"):
        accel = ra.build(small_dragon, method)
        grid_lo = accel.hgrid.grid_lo[0] if method == "hgrid" else accel.hybrid.lo
        size = accel.hgrid.grid_cell_size[0] if method == "hgrid" else accel.hybrid.cell_size
        corners = grid_lo + rng.integers(0, 6, size=(2000, 3)) * size
        _check(reference, accel, origins, corners - origins)
        _check(reference, accel, *_rays_in_planes(small_dragon, axes, corners[np.arange(2000), axes], rng))


def _overlapping_prims(scene, b, lo, hi):
    """Primitives that meet the box lo..hi shrunk by a millionth (so touching does not count);
    ``b`` is ``scene.bounds()``."""
    shrink = 1e-6 * (hi - lo)
    lo, hi = lo + shrink, hi - shrink
    candidates = np.flatnonzero(((b.lo <= hi) & (b.hi >= lo)).all(axis=1))
    center, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return {int(p) for p in candidates if prim_overlaps_box(scene.kind, scene.geometry, int(p), *center, *half)}


@pytest.mark.parametrize("exact_below", [0, 64, 4096])
def test_kdtree_invariants(closed_sphere_mesh, exact_below):
    scene = closed_sphere_mesh
    accel = ra.build(scene, "kdtree", exact_below=exact_below)
    kd = accel.kd
    leaf = kd.axis == LEAF
    cells = accel.node_cells()
    # cells partition the root (each child reaching across its plane's float32 bracket): leaf
    # volumes add up, children split their parent at the plane
    volume = np.prod(cells[:, 3:] - cells[:, :3], axis=1)
    assert volume[leaf].sum() == pytest.approx(volume[0], rel=1e-5)
    inner = np.flatnonzero(~leaf)
    below = kd.node_link[inner, 0]
    assert (below > inner).all()
    assert np.allclose(cells[below, 3 + kd.axis[inner]], kd.node_split[inner])
    assert np.allclose(cells[below + 1, kd.axis[inner]], kd.node_split[inner])
    # every primitive is referenced by every leaf whose interior it overlaps: the leaf's cell as
    # built lies within a float32 step of the cell node_cells gives
    bounds = scene.bounds()
    step = np.abs(cells) * 2.0 ** -23 + 2.0 ** -149
    for node in np.flatnonzero(leaf):
        first, count = kd.node_link[node, 0], kd.count[node]
        held = set(kd.leaf_prims[first:first + count].tolist())
        inner_lo, inner_hi = cells[node, :3] + step[node, :3], cells[node, 3:] - step[node, 3:]
        assert _overlapping_prims(scene, bounds, inner_lo, inner_hi) <= held
    stats = accel.stats()
    assert 1.0 <= stats["avg_prims_per_nonempty_leaf"] <= accel.options["leaf_size"]
    assert stats["max_depth"] <= round(8 + 1.3 * np.log2(len(scene)))


@settings(max_examples=examples(40), deadline=None)
@given(n=st.integers(1, 400), seed=st.integers(0, 2**16), grid=st.sampled_from([0.0, 4.0, 1e6]))
def test_kdtree_events_sorted_by_position_then_type(n, seed, grid):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-1, 1, size=(n, 3)) * rng.choice([1e-30, 1.0, 1e30], size=(n, 1))
    hi = lo + rng.exponential(size=(n, 3)) * rng.integers(0, 2, size=(n, 3))
    if grid:
        lo, hi = np.round(lo * grid) / grid, np.round(hi * grid) / grid
    lo[rng.random(n) < 0.1, 0] = -0.0
    boxes = np.hstack((lo, np.maximum(lo, hi)))
    pos, code, span = np.empty(6 * n), np.empty(6 * n, dtype=np.int64), np.empty((3, 2), dtype=np.int64)
    write_node_events(7, boxes, pos, code, span, np.empty(2 * n, dtype=np.uint64), np.empty(2 * n, dtype=np.uint64),
                      np.empty(2 * n, dtype=np.int64))
    for axis in range(3):
        first, last = span[axis]
        flat = boxes[:, axis] == boxes[:, axis + 3]
        expected = sorted([(boxes[i, axis], PLANAR, i) for i in np.flatnonzero(flat)]
                          + [(boxes[i, axis], START, i) for i in np.flatnonzero(~flat)]
                          + [(boxes[i, axis + 3], END, i) for i in np.flatnonzero(~flat)])
        got = [(x, c & 3, (c >> 2) - 7) for x, c in zip(pos[first:last].tolist(), code[first:last].tolist())]
        assert [(x, kind) for x, kind, _ in got] == [(x, kind) for x, kind, _ in expected]
        assert sorted(got) == expected


@pytest.mark.parametrize("width", [2, 8])
@pytest.mark.parametrize("interleaved", [False, True])
@pytest.mark.parametrize("any_hit", [False, True])
def test_kdtree_walks_neither_enter_nor_push_empty_leaves(closed_sphere_mesh, monkeypatch, interleaved, any_hit,
                                                          width):
    """The flags of empty children in the nodes' words name exactly the empty leaves, and no walk
    counts a visit to one: a ray that tests no primitive has visited no leaf, however many inner
    nodes it stepped through (rays from the corners of the sphere's box, outwards and inwards, and
    random ones); the cells walked eight-wide hold no empty leaf at all. With ``skip_empty=False``
    the binary walks enter them and count them, with the same answers."""
    accel = ra.build(closed_sphere_mesh, "kdtree", width=width)
    kd = accel.kd
    inner = np.flatnonzero(kd.axis != LEAF)
    below = kd.node_link[inner, 0]
    empty_leaf = (kd.axis == LEAF) & (kd.count == 0)
    assert empty_leaf.any()
    flags = kd.empty_children()
    assert np.array_equal(flags[inner], empty_leaf[below] | empty_leaf[below + 1] << 1)
    assert not flags[kd.axis == LEAF].any()
    if interleaved:
        monkeypatch.setattr(kdtree_accelerator, "interleaving_pays", lambda *_, **__: True)
        monkeypatch.setattr(bvh_accelerator, "interleaving_pays", lambda *_, **__: True)
    bounds = closed_sphere_mesh.bounds()
    centre, half = (bounds.scene_lo + bounds.scene_hi) / 2, (bounds.scene_hi - bounds.scene_lo) / 2
    corners = centre + 0.98 * half * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    rng = np.random.default_rng(3)
    origins = np.vstack((np.repeat(corners, 64, axis=0), rng.uniform(bounds.scene_lo, bounds.scene_hi, (512, 3))))
    directions = rng.normal(size=(len(origins), 3))
    result = accel.intersect(origins, directions, any_hit=any_hit, counters=True)
    work = result.counters
    stepped_between_empty_leaves = (work.tests == 0) & (work.nodes > 0)
    assert stepped_between_empty_leaves.sum() > 10
    assert (work.leaves[work.tests == 0] == 0).all()
    reference = ra.build(closed_sphere_mesh, "none").intersect(origins, directions, any_hit=any_hit)
    if any_hit:
        np.testing.assert_array_equal(result.prim >= 0, reference.prim >= 0)
    else:
        assert_same_hits(reference, result)
    entering = ra.build(closed_sphere_mesh, "kdtree", skip_empty=False, width=2)
    assert np.array_equal(entering.kd.node_records, kd.node_records)
    walked = entering.intersect(origins, directions, any_hit=any_hit, counters=True)
    np.testing.assert_array_equal(walked.prim >= 0, result.prim >= 0)
    if not any_hit:
        assert_same_hits(reference, walked)
    assert (walked.counters.leaves[work.tests == 0] > 0).any()
    if width == 2:
        assert (walked.counters.nodes >= work.nodes).all()


def _wide_leaf_boxes(records):
    """``(first, count, box)`` of every leaf child of eight-wide ``records``, box as lo, hi."""
    links = records.view(np.int32)
    leaves = []
    for node in range(len(records)):
        for c in range(WIDTH):
            if links[node, COUNT + c] > 0:
                box = records[node, [WIDTH * j + c for j in range(6)]].astype(np.float64)
                leaves.append((links[node, LINK + c], links[node, COUNT + c], box))
    return leaves


@pytest.mark.parametrize(("scene_name", "options"), [("small_dragon", {}), ("closed_sphere_mesh", {}),
                                                     ("ground_and_clutter", {}),
                                                     ("ground_and_clutter", {"large_apart": False})])
def test_kdtree_cells_walked_eight_wide_are_its_nonempty_leaves(scene_name, options, request):
    """The eight-wide records of a kd-tree (:mod:`rayaccel.structures.kdtree.wide_cells`) hold each
    leaf that holds references once, no empty one, every node reached once, in a box around the
    leaf's cell within a hair (the rounding margin and float32's rounding); the primitives kept
    apart are the first child of the root, in their box, and the binary walk's cells give the same
    answers."""
    scene = ground_and_clutter() if scene_name == "ground_and_clutter" else request.getfixturevalue(scene_name)
    accel = ra.build(scene, "kdtree", **options)
    kd, records = accel.kd, accel.cells.records
    links = records.view(np.int32)
    cells = accel.node_cells()
    leaf = kd.axis == LEAF
    nonempty = np.flatnonzero(leaf & (kd.count > 0))
    first_of = {int(kd.node_records[node, 0]): node for node in nonempty}
    seen = _wide_leaf_boxes(records)
    apart = [entry for entry in seen if entry[0] == accel.apart_first]
    kd_leaves = [entry for entry in seen if entry[0] != accel.apart_first]
    assert sorted(first_of[first] for first, _, _ in kd_leaves) == sorted(nonempty)
    size = float(np.abs(cells[0]).max() + (cells[0, 3:] - cells[0, :3]).max())
    for first, count, box in kd_leaves:
        node = first_of[first]
        assert count == kd.count[node]
        assert (box[:3] <= cells[node, :3]).all() and (box[3:] >= cells[node, 3:]).all()
        hair = 1e-9 * size + 2.0 ** -22 * np.abs(cells[node])
        assert (cells[node, :3] - box[:3] < hair[:3]).all() and (box[3:] - cells[node, 3:] < hair[3:]).all()
    inner_children = links[:, COUNT:COUNT + WIDTH] == 0
    assert sorted(links[:, LINK:LINK + WIDTH][inner_children]) == list(range(1, len(records)))
    if len(accel.apart_prims):
        assert len(apart) == 1 and apart[0][1] == len(accel.apart_prims)
        assert links[0, COUNT] == len(accel.apart_prims) and links[0, LINK] == accel.apart_first
        assert (apart[0][2][:3] <= accel.apart_box[0]).all() and (apart[0][2][3:] >= accel.apart_box[1]).all()
    else:
        assert not apart
    origins, directions = random_rays(scene, 2000, seed=8)
    assert_same_hits(ra.build(scene, "kdtree", width=2, **options).intersect(origins, directions),
                     accel.intersect(origins, directions))


def test_kdtree_does_not_depend_on_threads_or_batches(small_dragon):
    """The subtrees built in one batch or another, on one thread or several, are the same."""
    for exact_below in (4096, 0):
        trees = [ra.build(small_dragon, "kdtree", exact_below=exact_below, threads=threads) for threads in (1, 2, 5)]
        stats = [tree.stats() for tree in trees]
        for key in ("nodes", "leaves", "references", "max_depth"):
            assert stats[0][key] == stats[1][key] == stats[2][key], key
        assert stats[0]["expected_cost"] == pytest.approx(stats[1]["expected_cost"]) == stats[2]["expected_cost"]
        cells = [np.sort(tree.node_cells(), axis=0) for tree in trees]
        assert np.array_equal(cells[0], cells[1]) and np.array_equal(cells[0], cells[2])


def test_octree_invariants(closed_sphere_mesh):
    scene = closed_sphere_mesh
    accel = ra.build(scene, "octree", leaf_size=4)
    tree = accel.tree
    cells = accel.node_cells()
    leaf = tree.leaf
    volume = np.prod(cells[:, 3:] - cells[:, :3], axis=1)
    assert volume[leaf].sum() == pytest.approx(volume[0], rel=1e-9)
    for node in np.flatnonzero(~leaf):
        first = tree.node_link[node, 0]
        assert first > node
        children = cells[first:first + 8]
        assert np.allclose(children[:, :3].min(axis=0), cells[node, :3])
        assert np.allclose(children[:, 3:].max(axis=0), cells[node, 3:])
    bounds = scene.bounds()
    for node in np.flatnonzero(leaf):
        first, count = tree.node_link[node]
        held = set(tree.leaf_prims[first:first + count].tolist())
        assert _overlapping_prims(scene, bounds, cells[node, :3], cells[node, 3:]) <= held


def test_hgrid_invariants(small_dragon):
    accel = ra.build(small_dragon, "hgrid")
    h = accel.hgrid
    assert h.n_grids > 1
    parents = np.flatnonzero(h.cell_child >= 0)
    for cell in parents[:200]:
        child = h.cell_child[cell]
        assert h.grid_level[child] >= 1
        assert h.cell_first[cell + 1] == h.cell_first[cell]  # its primitives moved down
        # the nested grid covers exactly the parent cell
        g = np.searchsorted(h.grid_cell_base, cell, side="right") - 1
        local = cell - h.grid_cell_base[g]
        r = h.grid_res[g]
        xyz = np.array([local % r[0], local // r[0] % r[1], local // (r[0] * r[1])])
        cell_lo = h.grid_lo[g] + xyz * h.grid_cell_size[g]
        assert np.allclose(h.grid_lo[child], cell_lo)
        assert np.allclose(h.grid_lo[child] + h.grid_res[child] * h.grid_cell_size[child],
                           cell_lo + h.grid_cell_size[g])
    assert accel.stats()["levels"] == h.grid_level.max() + 1


def _wide_leaf_references(links, node, cell_prims):
    """The references in the leaves of the eight-wide tree below ``node`` (records seen as int32)."""
    leaves, stack = [], [node]
    while stack:
        node = stack.pop()
        for c in range(WIDTH):
            count = links[node, COUNT + c]
            if count > 0:
                leaves.extend(cell_prims[links[node, LINK + c]:links[node, LINK + c] + count])
            elif count == 0:
                stack.append(links[node, LINK + c])
    return leaves


@pytest.mark.parametrize("density", [0.5, 0.01])
def test_grid_bvh_cells_hold_their_references(small_dragon, density):
    """Each dense cell's binary BVH, and the eight-wide collapse the ray walk reads, hold exactly the
    cell's references; the cells are the uniform grid's of the same density."""
    accel = ra.build(small_dragon, "grid-bvh", density=density)
    h = accel.hybrid
    grid = ra.build(small_dragon, "grid", density=density)
    assert (grid.grid.cell_first == h.cell_first).all()
    assert ((h.cell_root >= 0) == (accel.wide_root >= 0)).all()
    links = accel.wide.view(np.int32)
    for cell in np.flatnonzero(h.cell_root >= 0)[:300]:
        stack, leaves = [h.cell_root[cell]], []
        while stack:
            node = stack.pop()
            if h.node_count[node] > 0:
                leaves.extend(h.cell_prims[h.node_first[node]:h.node_first[node] + h.node_count[node]])
            else:
                stack += [h.node_first[node], h.node_first[node] + 1]
        expected = sorted(grid.grid.cell_prims[grid.grid.cell_first[cell]:grid.grid.cell_first[cell + 1]].tolist())
        assert sorted(leaves) == expected
        assert sorted(_wide_leaf_references(links, accel.wide_root[cell], h.cell_prims)) == expected


@pytest.mark.parametrize("method", SPATIAL)
def test_degenerate_scenes(method):
    assert_one_and_twin_triangles_hit(method)
    copies = ra.Spheres(np.zeros((20_000, 3)), 1.0)
    hits = ra.build(copies, method).intersect([[0, 0, -5.0], [0, 5.0, 0]], [[0, 0, 1.0], [0, 0, 1.0]])
    assert hits.prim.tolist() == [0, -1]
    flat = ra.TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    origins = np.array([[0.5, 0.5, 1.0], [0.25, 0.25, -1.0], [0.5, 0.5, 0.0]])
    directions = np.array([[0, 0, -1.0], [0, 0, 1.0], [1.0, 0, 0]])
    assert_same_hits(ra.build(flat, "none").intersect(origins, directions),
                     ra.build(flat, method).intersect(origins, directions))


@pytest.mark.parametrize("method", ra.methods())
def test_stats_of_a_scene_of_one_point(method):
    """A root box of zero area: the surface-area figures take the limit of a shrinking box,
    and a batch large enough to be sorted (which asks for the structure's size) is traced."""
    point = ra.TriangleMesh(np.zeros((3, 3)), [[0, 1, 2]])
    accel = ra.build(point, method)
    stats = accel.stats()
    assert stats["bytes"] == accel.nbytes > 0
    assert np.isfinite(stats["expected_cost"])
    origins = np.random.default_rng(0).normal(size=(40_000, 3))
    assert (accel.intersect(origins, -origins).prim == -1).all()


def test_forest_scenes_agree():
    scene = ra.load_scene("forest-small-chair")
    reference = ra.build(scene, "none")
    origins, directions = camera_rays(scene, 24)
    expected = reference.intersect(origins, directions)
    for method in SPATIAL:
        assert_same_hits(expected, ra.build(scene, method).intersect(origins, directions))


def test_bad_options(small_dragon):
    with pytest.raises(ValueError, match="leaf_size"):
        ra.build(small_dragon, "kdtree", leaf_size=0)
    with pytest.raises(ValueError, match="empty_bonus"):
        ra.build(small_dragon, "kdtree", empty_bonus=1.5)
    with pytest.raises(TypeError, match="max_depth"):
        ra.build(small_dragon, "octree", max_depth=2.5)
    with pytest.raises(ValueError, match="insert"):
        ra.build(small_dragon, "octree", insert="center")
    with pytest.raises(ValueError, match="density"):
        ra.build(small_dragon, "hgrid", density=-1)
    with pytest.raises(ValueError, match="threshold"):
        ra.build(small_dragon, "grid-bvh", threshold=0)
    with pytest.raises(TypeError):
        ra.build(small_dragon, "kdtree", buckets=4)
    with pytest.raises(ValueError, match="bins"):
        ra.build(small_dragon, "kdtree", bins=1)
    with pytest.raises(ValueError, match="exact_below"):
        ra.build(small_dragon, "kdtree", exact_below=-1)
    for width in (4, True, "8"):
        with pytest.raises(ValueError, match="width"):
            ra.build(small_dragon, "kdtree", width=width)
    with pytest.raises(ValueError, match="width=2"):
        ra.build(small_dragon, "kdtree", skip_empty=False)


def test_statistics_are_consistent(small_dragon):
    origins, directions = camera_rays(small_dragon, 32)
    for method in SPATIAL:
        stats = ra.build(small_dragon, method).stats(origins, directions)
        assert stats["nonempty_leaves"] <= stats["leaves"] <= stats["nodes"]
        assert stats["references"] >= len(small_dragon) * 0.99
        assert stats["expected_cost"] > 0 and stats["expected_intersections"] > 0
        assert stats["avg_nodes_per_ray"] >= 1


@settings(max_examples=examples(25), deadline=None)
@given(n=st.integers(1, 60), seed=st.integers(0, 2**16), method=st.sampled_from(SPATIAL))
def test_random_triangle_soups_property(n, seed, method):
    rng = np.random.default_rng(seed)
    # snapped coordinates make shared vertices, coplanar triangles and axis-aligned edges common
    vertices = np.round(rng.uniform(0, 1, size=(3 * n, 3)) * 4) / 4
    scene = ra.TriangleMesh(vertices, np.arange(3 * n).reshape(n, 3))
    origins, directions = random_rays(scene, 150, seed=seed)
    snapped = np.round(rng.uniform(-0.5, 1.5, size=(50, 3)) * 4) / 4
    origins = np.concatenate((origins, snapped))
    directions = np.concatenate((directions, np.round(rng.normal(size=(50, 3)))))
    directions[np.abs(directions).sum(axis=1) == 0] = [0.0, 0.0, 1.0]
    assert_same_hits(ra.build(scene, "none").intersect(origins, directions),
                     ra.build(scene, method).intersect(origins, directions))


def test_leaves_are_counted_among_the_nodes(small_dragon):
    origins, directions = random_rays(small_dragon, 300, seed=4)
    for method in ra.methods():
        counters = ra.build(small_dragon, method).intersect(origins, directions, counters=True).counters
        assert (counters.leaves <= counters.nodes).all(), method
        tested = counters.tests > 0
        if method != "none":
            assert (counters.leaves[tested] >= 1).all(), method
        if method == "grid":
            np.testing.assert_array_equal(counters.leaves, counters.nodes)
        if method in ("kdtree", "octree", "bvh-binned"):
            assert (counters.nodes[tested] > counters.leaves[tested]).any(), method


def test_octree_finds_a_triangle_far_from_the_origin_that_a_ray_starts_on():
    """Found by the property test: a mesh moved 1e7 along x, cells a few hundredths wide, and a ray
    starting on a triangle's vertex. The insertion pad must cover the rounding of cell centres
    that far out, not only a fraction of the cell's size."""
    vertices = np.array([[2, 0, 2], [0, 0, 0], [0, 1, 0], [0, 0, 2], [1, 0, 2]], float) + [1e7, 0.0, 0.0]
    mesh = ra.TriangleMesh(vertices, np.array([[0, 3, 0], [1, 2, 4]]))
    origin, direction = np.array([[1e7 + 1.0, 0.0, 2.0]]), np.array([[0.0, 0.0, -1.0]])
    reference = ra.build(mesh, "none").intersect(origin, direction)
    assert reference.prim[0] == 1
    assert_same_hits(reference, ra.build(mesh, "octree", leaf_size=1).intersect(origin, direction))
