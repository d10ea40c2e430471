"""Every BVH builder and bounding volume against the brute-force oracle, and the tree's invariants."""

from __future__ import annotations

import functools
import pickle

import numpy as np
import pytest
from conftest import (
    assert_counts_and_lists_match,
    assert_one_and_twin_triangles_hit,
    assert_same_hits,
    axis_parallel_rays,
    camera_rays,
    examples,
    random_rays,
    vertex_and_edge_rays,
)
from hypothesis import given, settings
from hypothesis import strategies as st

import rayaccel as ra
from rayaccel._memory import cache_line_aligned
from rayaccel.geometry.gather import layout_rows, prim_count
from rayaccel.geometry.kdop import KDOP_NORMALS
from rayaccel.structures.bvh.nodes import node_depths
from rayaccel.structures.bvh.reinsertion import _largest
from rayaccel.structures.bvh.wide import WIDTH, wide_records

BUILDERS = [m for m in ra.methods() if m.startswith("bvh-")]
BOUNDS = ["aabb", "sphere", "kdop"]
VOLUMES = [{"bounds": "aabb"}, {"bounds": "aabb", "width": 2}, {"bounds": "sphere"}, {"bounds": "kdop"}]


def test_all_six_builders_are_registered():
    assert set(BUILDERS) == {"bvh-agglomerative", "bvh-median-space", "bvh-median-object", "bvh-sah",
                             "bvh-binned", "bvh-lbvh"}


@pytest.mark.parametrize("volume", VOLUMES, ids=lambda v: "-".join(map(str, v.values())))
@pytest.mark.parametrize("method", BUILDERS)
@pytest.mark.parametrize("scene_name", ["small_dragon", "spheres"])
def test_bvh_agrees_with_brute_force(scene_name, method, volume, request):
    scene = request.getfixturevalue(scene_name)
    reference = ra.build(scene, "none")
    accel = ra.build(scene, method, **volume)
    for origins, directions in (camera_rays(scene, 40), random_rays(scene, 1500), axis_parallel_rays(scene, 600)):
        assert_same_hits(reference.intersect(origins, directions), accel.intersect(origins, directions))
        np.testing.assert_array_equal(accel.occluded(origins, directions), reference.occluded(origins, directions))


@pytest.mark.parametrize("method", ["bvh-binned", "bvh-agglomerative", "bvh-lbvh"])
def test_bvh_on_bunny_and_adversarial_rays(bunny, small_dragon, method):
    reference = ra.build(bunny, "none")
    origins, directions = camera_rays(bunny, 32)
    assert_same_hits(reference.intersect(origins, directions), ra.build(bunny, method).intersect(origins, directions))
    reference = ra.build(small_dragon, "none")
    rng = np.random.default_rng(9)
    faces = rng.integers(0, len(small_dragon), 1000)
    corners = small_dragon.geometry[faces].reshape(-1, 3, 3)
    on_surface = np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], 1000), corners)
    directions = rng.normal(size=(1000, 3))
    t_max = rng.uniform(0.0, 0.05, 1000)
    at_vertices_and_edges = vertex_and_edge_rays(small_dragon, 2000)
    for volume in ({"bounds": "kdop"}, {"bounds": "aabb"}):
        accel = ra.build(small_dragon, method, **volume)
        assert_same_hits(reference.intersect(*at_vertices_and_edges), accel.intersect(*at_vertices_and_edges))
        assert_same_hits(reference.intersect(on_surface, directions, 0.0, t_max),
                         accel.intersect(on_surface, directions, 0.0, t_max))


def _leaf_ranges(accel):
    b = accel.bvh
    leaf = b.node_count > 0
    return b.node_first[leaf].astype(np.int64), b.node_count[leaf].astype(np.int64)


def _assert_valid_tree(accel, scene, max_leaf_size):
    """Every primitive in exactly one leaf of at most ``max_leaf_size``, the leaves tiling the
    primitive order; a binary tree with children after their parents, each box inside its
    parent's, each leaf's box around its primitives."""
    b = accel.bvh
    n = len(scene)
    assert sorted(b.prim_order.tolist()) == list(range(n))
    first, count = _leaf_ranges(accel)
    covered = np.zeros(n, dtype=int)
    for f, c in zip(first, count):
        covered[f:f + c] += 1
    assert (covered == 1).all()
    assert (count >= 1).all() and (count <= max_leaf_size).all()
    assert b.n_nodes == 2 * len(first) - 1
    inner = np.flatnonzero(b.node_count == 0)
    assert (b.node_first[inner] > inner).all()
    for node in inner:
        for child in (b.node_first[node], b.node_first[node] + 1):
            assert (b.node_box[child, :3] >= b.node_box[node, :3]).all()
            assert (b.node_box[child, 3:] <= b.node_box[node, 3:]).all()
    bounds = scene.bounds()
    for node in np.flatnonzero(b.node_count > 0):
        prims = b.prim_order[b.node_first[node]:b.node_first[node] + b.node_count[node]]
        assert (bounds.lo[prims] >= b.node_box[node, :3]).all()
        assert (bounds.hi[prims] <= b.node_box[node, 3:]).all()


def _leaf_sets(accel):
    b = accel.bvh
    return sorted(tuple(sorted(b.prim_order[f:f + c].tolist())) for f, c in zip(*_leaf_ranges(accel)))


@pytest.mark.parametrize("reinsertion", [False, True])
@pytest.mark.parametrize("method", BUILDERS)
def test_structural_invariants(small_dragon, method, reinsertion):
    _assert_valid_tree(ra.build(small_dragon, method, max_leaf_size=6, reinsertion=reinsertion), small_dragon, 6)


@functools.cache
def _forest_with_a_speck():
    """Sixty trees over the 100 x 100 ground and a chair half a unit tall among them, tessellated
    finely: the binned SAH's top splits, whose 32 bins span the forest, cannot cut the dense
    speck out, and the tree it builds costs a quarter more than the one reinsertion makes of it."""
    trees = ra.procedural.forest(n_trees=60)
    seat = ra.procedural.chair(0.25, detail=6)
    return ra.TriangleMesh(np.concatenate((trees.vertices, seat.vertices + [50.3, 0.0, 49.7])),
                           np.concatenate((trees.faces, seat.faces + len(trees.vertices))))


@pytest.mark.parametrize("method", BUILDERS)
def test_reinsertion_moves_subtrees_without_raising_the_sah_cost(small_dragon, method):
    """Reinsertion keeps every leaf as it was and never raises the cost; the lecture's builders
    keep their trees as built unless asked, the default ``bvh-binned`` moves them."""
    built = ra.build(small_dragon, method, reinsertion=False)
    moved = ra.build(small_dragon, method, reinsertion=True)
    assert moved.stats()["sah_cost"] <= built.stats()["sah_cost"]
    assert _leaf_sets(moved) == _leaf_sets(built)
    assert ra.build(small_dragon, method).options["reinsertion"] == (method == "bvh-binned")


@settings(max_examples=examples(60), deadline=None)
@given(n=st.integers(1, 5000), batch=st.integers(1, 300), levels=st.integers(1, 50), seed=st.integers(0, 2**31))
def test_reinsertion_picks_the_largest_measures(n, batch, levels, seed):
    """The nodes reinsertion moves are the ``batch`` largest non-negative measures, largest first,
    equal ones by index, whether the sampled threshold finds them or all are partitioned: measures
    drawn from few levels (many ties), with negative ones (nodes that cannot move) and infinite ones."""
    rng = np.random.default_rng(seed)
    measure = rng.integers(-2, levels, n).astype(float)
    measure[rng.random(n) < 0.01] = np.inf
    order = np.lexsort((np.arange(n), -measure))
    expected = order[measure[order] >= 0.0][:batch]
    np.testing.assert_array_equal(_largest(measure, batch), expected)


def test_reinsertion_repairs_the_binned_sah_around_a_dense_speck():
    """On the forest with a speck the default ``bvh-binned`` tree costs at least 10 % less than as
    built, stays a valid tree with the same leaves, and answers every query as brute force does,
    after pickling too."""
    scene = _forest_with_a_speck()
    built = ra.build(scene, "bvh-binned", reinsertion=False)
    moved = ra.build(scene, "bvh-binned")
    assert moved.stats()["sah_cost"] <= 0.9 * built.stats()["sah_cost"]
    _assert_valid_tree(moved, scene, 8)
    assert _leaf_sets(moved) == _leaf_sets(built)
    reference = ra.build(scene, "none")
    restored = pickle.loads(pickle.dumps(moved))
    rays = (camera_rays(scene, 48), random_rays(scene, 3000), axis_parallel_rays(scene, 600),
            vertex_and_edge_rays(scene, 1500))
    for origins, directions in rays:
        expected = reference.intersect(origins, directions)
        for accel in (moved, restored):
            assert_same_hits(expected, accel.intersect(origins, directions))
            np.testing.assert_array_equal(accel.occluded(origins, directions),
                                          reference.occluded(origins, directions))
    assert_counts_and_lists_match(reference, moved, *random_rays(scene, 1000, seed=3))


def test_wide_nodes_hold_every_leaf_once_inside_their_boxes(small_dragon):
    from rayaccel.structures.bvh.wide import COUNT, LINK, UNUSED, WIDTH

    accel = ra.build(small_dragon, "bvh-binned", max_leaf_size=2)
    b, records = accel.bvh, accel.wide
    links = records.view(np.int32)
    child, count = links[:, LINK:LINK + WIDTH], links[:, COUNT:COUNT + WIDTH]
    inner = count == 0
    assert sorted(child[inner].tolist()) == list(range(1, len(records)))
    leaves = count > 0
    binary_leaves = b.node_count > 0
    assert sorted(zip(child[leaves], count[leaves])) == sorted(zip(b.node_first[binary_leaves],
                                                                  b.node_count[binary_leaves]))
    vertices = layout_rows(accel.geometry).reshape(-1, 3, 3)
    for node, c in zip(*np.nonzero(leaves)):
        points = vertices[child[node, c]:child[node, c] + count[node, c]].reshape(-1, 3)
        assert (points >= records[node, [c, WIDTH + c, 2 * WIDTH + c]]).all()
        assert (points <= records[node, [3 * WIDTH + c, 4 * WIDTH + c, 5 * WIDTH + c]]).all()
    assert ((count >= 0) | (count == UNUSED)).all()
    assert (inner | leaves).sum(axis=1).min() >= 2


@pytest.mark.parametrize("bounds", ["sphere", "kdop"])
def test_node_volumes_contain_their_primitives(small_dragon, bounds):
    from rayaccel.structures.bvh.volumes import node_ranges

    accel = ra.build(small_dragon, "bvh-binned", bounds=bounds)
    b = accel.bvh
    range_lo, range_hi = node_ranges(b.node_first, b.node_count)
    vertices = layout_rows(accel.geometry).reshape(-1, 3, 3)
    for node in range(0, b.n_nodes, 7):
        points = vertices[range_lo[node]:range_hi[node]].reshape(-1, 3)
        if bounds == "sphere":
            assert (np.linalg.norm(points - accel.volume[node, :3], axis=1) <= accel.volume[node, 3]).all()
        else:
            proj = points @ KDOP_NORMALS.T
            assert (proj >= accel.volume[node, :7] - 1e-12).all() and (proj <= accel.volume[node, 7:] + 1e-12).all()


def test_sah_cost_ranks_the_builders(small_dragon):
    cost = {m: ra.build(small_dragon, m).stats()["sah_cost"] for m in BUILDERS}
    assert cost["bvh-sah"] <= cost["bvh-binned"] * 1.05
    assert cost["bvh-binned"] < cost["bvh-median-object"]
    assert cost["bvh-binned"] < cost["bvh-lbvh"]


def test_tighter_volumes_have_lower_expected_leaf_visits(small_dragon):
    stats = {b: ra.build(small_dragon, "bvh-binned", bounds=b, traversal_cost=3.0).stats() for b in BOUNDS}
    assert stats["kdop"]["expected_leaves_visited"] < stats["aabb"]["expected_leaves_visited"]


@pytest.mark.parametrize("method", BUILDERS)
def test_degenerate_scenes(method):
    assert_one_and_twin_triangles_hit(method)
    # many copies of one primitive: all centroids equal; ties go to the lowest index
    copies = ra.Spheres(np.zeros((20_000, 3)), 1.0)
    accel = ra.build(copies, method, max_leaf_size=4)
    assert (accel.bvh.node_count <= 4).all()
    hits = accel.intersect([[0, 0, -5.0], [0, 5.0, 0]], [[0, 0, 1.0], [0, 0, 1.0]])
    assert hits.prim.tolist() == [0, -1]


def test_a_million_copies_of_one_point():
    copies = ra.Spheres(np.full((1_000_000, 3), 0.5), 1e-3)
    accel = ra.build(copies, "bvh-binned")
    assert accel.stats(np.array([[0.5, 0.5, -1.0]]), np.array([[0, 0, 1.0]]))["max_depth"] <= 40
    assert accel.intersect([[0.5, 0.5, -1.0]], [[0, 0, 1.0]]).prim[0] == 0


def test_bad_bvh_options(small_dragon):
    with pytest.raises(ValueError, match="bounds"):
        ra.build(small_dragon, "bvh-binned", bounds="capsule")
    with pytest.raises(ValueError, match="bins"):
        ra.build(small_dragon, "bvh-binned", bins=1)
    with pytest.raises(ValueError, match="max_leaf_size"):
        ra.build(small_dragon, "bvh-sah", max_leaf_size=0)
    with pytest.raises(TypeError, match="max_leaf_size"):
        ra.build(small_dragon, "bvh-sah", max_leaf_size=2.5)
    with pytest.raises(TypeError):
        ra.build(small_dragon, "bvh-lbvh", bins=8)
    with pytest.raises(ValueError, match="width"):
        ra.build(small_dragon, "bvh-binned", width=4)
    with pytest.raises(TypeError, match="reinsertion"):
        ra.build(small_dragon, "bvh-binned", reinsertion="yes")


def test_counters(small_dragon):
    origins, directions = camera_rays(small_dragon, 48)
    hits = ra.build(small_dragon, "bvh-binned").intersect(origins, directions, counters=True)
    assert (hits.counters.nodes[hits.hit] >= 2).all()
    assert (hits.counters.tests[hits.hit] >= 1).all()
    assert (hits.counters.tests <= len(small_dragon)).all()
    assert (hits.counters.mailbox_skips == 0).all()


@settings(max_examples=examples(30), deadline=None)
@given(
    n=st.integers(1, 80),
    seed=st.integers(0, 2**16),
    method=st.sampled_from(BUILDERS),
    volume=st.sampled_from(VOLUMES),
    leaf=st.integers(1, 9),
    reinsertion=st.booleans(),
)
def test_random_scenes_property(n, seed, method, volume, leaf, reinsertion):
    scene = ra.random_spheres(n, seed=seed, fill=0.2)
    origins, directions = random_rays(scene, 200, seed=seed)
    reference = ra.build(scene, "none").intersect(origins, directions)
    accel = ra.build(scene, method, max_leaf_size=leaf, reinsertion=reinsertion, **volume)
    assert_same_hits(reference, accel.intersect(origins, directions))
    assert (accel.bvh.node_count <= leaf).all()


@functools.cache
def _vector_and_scalar_child_tests():
    """A kernel running the eight-lane float32 slab test and the exact scalar one on the same node,
    compiled once for every example of the properties below."""
    from numba import njit

    from rayaccel.structures.bvh.traverse import enter_box
    from rayaccel.structures.bvh.wide_slab import box_reach, enter_children, slab_limits, slab_ray

    @njit(error_model="numpy")
    def both(records, boxes, bound, node, o, d, t_min, t_max):
        inv = (1.0 / d[0], 1.0 / d[1], 1.0 / d[2])
        near = (0 if inv[0] >= 0.0 else 3, 1 if inv[1] >= 0.0 else 4, 2 if inv[2] >= 0.0 else 5)
        reach = box_reach(bound[0, :3], bound[0, 3:])
        slab = slab_ray(o[0], o[1], o[2], d[0], d[1], d[2], inv[0], inv[1], inv[2], reach[0], reach[1], reach[2])
        enter_from, exit_by = slab_limits(slab, t_min, t_max)
        vector = np.empty(WIDTH, dtype=np.float32)
        mask = enter_children(records, node, near[0], near[1], near[2], slab, enter_from, exit_by, vector)
        scalar = [enter_box(boxes, c, o[0], o[1], o[2], inv[0], inv[1], inv[2], near[0], near[1], near[2], t_min,
                            t_max) for c in range(WIDTH)]
        return vector.astype(np.float64) * slab[9], scalar, mask

    return both


def _wide_node(lo, hi, used):
    """A wide record of the children ``lo``, ``hi`` (WIDTH, 3) whose slots ``used`` holds (the
    others empty, as :mod:`rayaccel.structures.bvh.wide` leaves them), their float64 boxes, and
    the box around them all."""
    lo, hi = lo.copy(), hi.copy()
    lo[~used], hi[~used] = np.inf, -np.inf
    records = cache_line_aligned((1, 8 * WIDTH), np.float32)
    records[0, :3 * WIDTH] = lo.T.ravel()
    records[0, 3 * WIDTH:6 * WIDTH] = hi.T.ravel()
    bound = np.hstack([lo[used].min(axis=0), hi[used].max(axis=0)])[None, :]
    return records, np.hstack([lo, hi]).astype(np.float64), bound


@settings(max_examples=examples(80), deadline=None)
@given(seed=st.integers(0, 2**32 - 1), zero_axes=st.sets(st.integers(0, 2)), on_plane=st.booleans(),
       scale=st.sampled_from([1e-20, 1e-3, 1.0, 1e7, 1e20]), length=st.sampled_from([1e-30, 1e-3, 1.0, 1e9, 1e30]),
       t_min=st.sampled_from([0.0, 0.25, -1.0]), t_max=st.sampled_from([np.inf, 1.5, 0.3]))
def test_vector_child_test_enters_what_the_exact_test_enters(seed, zero_axes, on_plane, scale, length, t_min,
                                                             t_max):
    """The eight-lane float32 slab test of the wide layout is conservative: it enters every child
    the exact float64 test enters, at a distance no greater than the exact one, for zero direction
    components of either sign, origins on slab planes, coordinates and directions of any
    magnitude, and any ``[t_min, t_max]``; the others it enters lie within ``2**-17`` of the
    coordinates' size of the ray (the exact test enters them grown by that much); it never
    enters an empty slot; its mask has bit ``c`` set exactly where ``entry[c]`` is finite."""
    both = _vector_and_scalar_child_tests()
    rng = np.random.default_rng(seed)
    lo = (rng.uniform(-1, 1, (WIDTH, 3)) * scale).astype(np.float32)
    hi = lo + (rng.uniform(0, 1, (WIDTH, 3)) * scale).astype(np.float32)
    used = rng.random(WIDTH) < 0.8
    used[0] = True
    records, boxes, bound = _wide_node(lo, hi, used)
    origin = rng.uniform(-2, 2, 3) * scale
    direction = rng.normal(size=3) * length * scale
    for axis in zero_axes:
        direction[axis] = rng.choice([0.0, -0.0])
        if on_plane:
            origin[axis] = lo[rng.integers(WIDTH), axis]
    if not direction.any():
        direction[0] = length * scale
    t_min, t_max = t_min / length, t_max / length
    vector, scalar, mask = both(records, boxes, bound, 0, origin, direction, t_min, t_max)
    scalar = np.array(scalar)
    exact = scalar != np.inf
    assert np.all(vector[exact] <= scalar[exact])
    assert mask == sum(1 << c for c in range(WIDTH) if vector[c] != np.inf)
    assert not np.any(np.isfinite(vector[~used]))
    margin = 2.0 ** -17 * (np.abs(bound).max(axis=0).reshape(2, 3).max(axis=0) + np.abs(origin))
    grown = np.hstack([boxes[:, :3] - margin, boxes[:, 3:] + margin])
    _, loose, _ = both(records, grown, bound, 0, origin, direction, t_min, t_max)
    assert np.all(np.array(loose)[np.isfinite(vector)] != np.inf)


def test_vector_child_test_enters_every_box_for_rays_beyond_float32_distances():
    """A ray whose distances float32 cannot bound (a direction component below ``2**-100`` of the
    largest but not zero, coordinates beyond ``2**100``, a subnormal direction) enters every child
    in use, and no empty slot."""
    both = _vector_and_scalar_child_tests()
    rng = np.random.default_rng(3)
    lo = rng.uniform(-1, 1, (WIDTH, 3)).astype(np.float32)
    hi = lo + rng.uniform(0, 1, (WIDTH, 3)).astype(np.float32)
    used = np.arange(WIDTH) < 6
    records, boxes, bound = _wide_node(lo, hi, used)
    for origin, direction in (((5.0, 0.5, 0.5), (-1.0, 1e-35, 0.0)), ((2.0 ** 110, 0.5, 0.5), (-1.0, 0.0, 0.0)),
                              ((5.0, 0.5, 0.5), (-1e-309, 0.0, 0.0))):
        vector, scalar, mask = both(records, boxes, bound, 0, np.array(origin), np.array(direction), 0.0, np.inf)
        exact = np.array(scalar) != np.inf
        assert mask == (1 << 6) - 1
        assert np.all(vector[exact] <= np.array(scalar)[exact])


def test_highest_and_lowest_bit():
    from numba import njit

    from rayaccel.structures.bvh.wide_slab import highest_bit, lowest_bit

    top = njit(lambda mask: highest_bit(mask))
    bottom = njit(lambda mask: lowest_bit(mask))
    for mask in (1, 2, 3, 0b10110000, 255, 1 << 40):
        assert top(mask) == mask.bit_length() - 1
        assert bottom(mask) == (mask & -mask).bit_length() - 1


@pytest.mark.parametrize(("scene_name", "layout"), [("small_dragon", "lanes"), ("bunny", "indexed")])
def test_leaf_triangles_take_the_smallest_exact_layout(scene_name, layout, request):
    """The dragon's PLY holds float32 vertices, so its leaf triangles are float32 lanes, four
    triangles a group, the last group's spare lanes repeating the last triangle; the bunny's OBJ
    does not, so its are vertex indices into vertices renumbered by first use. Both hold the
    scene's corners exactly, and what a ray query reads stays under 85 bytes per triangle."""
    scene = request.getfixturevalue(scene_name)
    accel = ra.build(scene, "bvh-binned")
    expected = scene.geometry[accel.bvh.prim_order]
    if layout == "lanes":
        n = len(expected)
        assert accel.geometry.dtype == np.float32 and accel.geometry.shape == ((n + 3) // 4, 9, 4)
        rows = layout_rows(accel.geometry)
        assert prim_count(accel.geometry) == len(rows) >= n
        assert (rows[n:] == rows[n - 1]).all()
        corners = rows[:n]
    else:
        corner_ids, leaf_vertices = accel.geometry
        assert corner_ids.dtype == np.int32 and leaf_vertices.dtype == np.float64
        _, first_use = np.unique(corner_ids.ravel(), return_index=True)
        assert (np.diff(first_use) > 0).all() and len(leaf_vertices) <= len(scene.vertices)
        corners = leaf_vertices[corner_ids].reshape(-1, 9)
    np.testing.assert_array_equal(corners, expected)
    assert accel.stats()["bytes"] / len(scene) < 85


@pytest.mark.parametrize("max_leaf_size", [1, 3, 5, 8])
def test_leaves_at_every_lane_offset_match_brute_force(small_dragon, max_leaf_size):
    """Leaves of the lanes layout start at any lane of a group and may span two or three
    groups; the edge test of a group's lanes admits every triangle of the leaf the full test
    would hit and no lane outside the leaf, whatever the query: closest hit, any hit, counts and
    lists, on rays through vertices and edges, axis-parallel rays and rays leaving the surface.
    Degenerate triangles (collinear corners, a repeated corner) among them are never hit."""
    faces = np.concatenate((small_dragon.faces, [[0, 0, 1], [2, 3, 3]]))
    mesh = ra.TriangleMesh(small_dragon.vertices, faces)
    accel = ra.build(mesh, "bvh-binned", max_leaf_size=max_leaf_size, packets=False, interleave=False)
    assert accel.geometry.ndim == 3
    first = accel.bvh.node_first[accel.bvh.node_count > 0]
    assert len(np.unique(first % 4)) == 4
    reference = ra.build(mesh, "none")
    rng = np.random.default_rng(max_leaf_size)
    corners = mesh.geometry[rng.integers(0, len(faces), 500)].reshape(-1, 3, 3)
    on_surface = np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], 500), corners)
    for origins, directions in (vertex_and_edge_rays(mesh, 1500), axis_parallel_rays(mesh, 500),
                                (on_surface, rng.normal(size=(500, 3))), random_rays(mesh, 1500)):
        assert_same_hits(reference.intersect(origins, directions), accel.intersect(origins, directions))
        np.testing.assert_array_equal(accel.occluded(origins, directions), reference.occluded(origins, directions))
        assert_counts_and_lists_match(reference, accel, origins, directions)


def test_edges_of_four_lanes_admit_every_triangle_the_full_test_hits():
    """:func:`rayaccel.structures.bvh.triangle_lanes.edges_admit` admits every triangle the scalar
    watertight test hits and rejects others: random float32 triangles, many of them small and
    near the ray, and rays through the corners two triangles of opposite windings share."""
    from numba import njit

    from rayaccel.geometry.gather import gather_triangles
    from rayaccel.geometry.primitive import ray_setup
    from rayaccel.geometry.triangle import intersect_triangle
    from rayaccel.structures.bvh.triangle_lanes import edges_admit

    @njit
    def verdicts(lanes, n, ox, oy, oz, dx, dy, dz):
        ray = ray_setup(ox, oy, oz, dx, dy, dz)
        admitted = np.zeros(n, dtype=np.bool_)
        hit = np.zeros(n, dtype=np.bool_)
        for k in range(n):
            mask = edges_admit(lanes, k // 4, ray[6], ray[7], ray[8], ray[12], ray[13], ray[14], ray[9], ray[10])
            admitted[k] = (mask >> (k % 4)) & 1
            t, _, _ = intersect_triangle(lanes, k, ray[12], ray[13], ray[14], ray[6], ray[7], ray[8], ray[9],
                                         ray[10], ray[11], 0.0, np.inf)
            hit[k] = t < np.inf
        return admitted, hit

    rng = np.random.default_rng(7)
    vertices = rng.normal(scale=rng.choice([1e-3, 1.0], (3000, 1)), size=(3000, 3)).astype(np.float32)
    vertices[:3] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    faces = np.concatenate(([[0, 1, 2], [0, 2, 1]], rng.integers(0, 3000, (997, 3))))
    lanes = gather_triangles(vertices.astype(np.float64), faces, np.arange(len(faces)), True)
    for origin, direction in (((0.0, 0.0, 5.0), (0.0, 0.0, -1.0)), ((0.01, 0.02, -3.0), (0.0, 0.0, 1.0)),
                              ((0.3, -0.2, 2.0), (-0.1, 0.1, -1.0))):
        admitted, hit = verdicts(lanes, len(faces), *origin, *direction)
        assert (admitted | ~hit).all() and hit.any() and not admitted.all()


def test_refit_to_vertices_float32_cannot_hold_changes_the_layout(small_dragon):
    """Moved vertices that float32 cannot hold turn the dragon's float32 lanes into the indexed
    layout at the refit, and the hits stay brute force's."""
    accel = ra.build(small_dragon, "bvh-binned")
    moved = small_dragon.vertices + 1e-3 / 3
    accel.refit(moved)
    assert isinstance(accel.geometry, tuple)
    moved_mesh = ra.TriangleMesh(moved, small_dragon.faces)
    origins, directions = random_rays(moved_mesh, 3000)
    assert_same_hits(ra.build(moved_mesh, "none").intersect(origins, directions), accel.intersect(origins, directions))


def test_bvh_queries_leave_the_scene_without_float64_rows(small_dragon):
    """A BVH reads its own leaf layout; building it and answering every query gathers no (F, 9)
    float64 copy of the triangles onto the scene (72 bytes a triangle kept as long as the mesh)."""
    mesh = ra.TriangleMesh(small_dragon.vertices, small_dragon.faces)
    accel = ra.build(mesh, "bvh-binned")
    origins, directions = random_rays(mesh, 500)
    accel.intersect(origins, directions)
    accel.occluded(origins, directions)
    accel.count(origins, directions)
    accel.intersect_all(origins, directions)
    accel.closest_point(origins)
    accel.signed_distance(origins)
    assert "geometry" not in vars(mesh)


@pytest.mark.parametrize("method", ["bvh-binned", "bvh-lbvh", "bvh-agglomerative"])
@pytest.mark.parametrize("scene_name", ["small_dragon", "spheres"])
def test_eight_wide_bvh_recovers_its_binary_tree_exactly(scene_name, method, request):
    """A BVH walked eight-wide keeps no binary tree after its build; the one it recovers
    (:mod:`rayaccel.structures.bvh.binary_from_wide`) is the build's, node for node up to
    numbering: the same leaves with the same boxes, the same inner boxes, depth and SAH cost."""
    scene = request.getfixturevalue(scene_name)
    wide = ra.build(scene, method, traversal_cost=2.0)
    binary = ra.build(scene, method, traversal_cost=2.0, width=2).bvh
    assert wide._binary is None and wide._wide_tree is None
    recovered = wide.bvh
    assert recovered.n_nodes == binary.n_nodes and wide.max_depth == int(node_depths(recovered.node_first,
                                                                                     recovered.node_count).max())

    def leaves(tree):
        leaf = tree.node_count > 0
        rows = np.column_stack((tree.node_first[leaf], tree.node_count[leaf], tree.node_box[leaf]))
        return rows[np.lexsort(rows.T[::-1])]

    np.testing.assert_array_equal(leaves(recovered), leaves(binary))
    np.testing.assert_array_equal(np.sort(recovered.node_box, axis=0), np.sort(binary.node_box, axis=0))
    np.testing.assert_array_equal(recovered.prim_order, binary.prim_order)
    assert wide.sah_cost() == pytest.approx(ra.build(scene, method, traversal_cost=2.0, width=2).sah_cost(), rel=1e-12)
    slots, child_wide = wide._wide_tree
    np.testing.assert_array_equal(wide_records(recovered.node_box, recovered.node_first, recovered.node_count,
                                               (slots, child_wide)), wide.wide)


def test_single_leaf_tree_recovers_its_binary_tree():
    mesh = ra.TriangleMesh(np.eye(3), np.array([[0, 1, 2]]))
    accel = ra.build(mesh, "bvh-binned")
    assert accel.bvh.n_nodes == 1 and accel.bvh.node_count[0] == 1
    np.testing.assert_array_equal(accel.closest_point(np.zeros((1, 3))).prim, [0])
