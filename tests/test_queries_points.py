"""Point queries (closest point, distance, winding number, contains, signed distance) against
numpy float64 oracles and brute force, on every method."""

from __future__ import annotations

import numpy as np
import pytest

import rayaccel as ra

METHODS = ra.methods()


def closest_on_triangles(p, a, b, c):
    """Ericson, Real-Time Collision Detection, 5.1.5, vectorised over triangles: (d2, point)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    vc, vb, va = d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        face = a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]
        edge_ab = a + ab * (d1 / (d1 - d3))[:, None]
        edge_ac = a + ac * (d2 / (d2 - d6))[:, None]
        edge_bc = b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]
    out = face
    for mask, value in [(va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), edge_bc], [(vb <= 0) & (d2 >= 0) & (d6 <= 0),
                                                                              edge_ac], \
            [(vc <= 0) & (d1 >= 0) & (d3 <= 0), edge_ab], [(d6 >= 0) & (d5 <= d6), c], [(d3 >= 0) & (d4 <= d3), b], \
            [(d1 <= 0) & (d2 <= 0), a]:
        out = np.where(mask[:, None], value, out)
    return ((out - p) ** 2).sum(1), out


def oracle_distance(mesh, points):
    corners = mesh.geometry.reshape(-1, 3, 3)
    return np.array([np.sqrt(closest_on_triangles(p, corners[:, 0], corners[:, 1], corners[:, 2])[0].min())
                     for p in points])


def exact_winding(mesh, points):
    """Van Oosterom & Strackee's solid angles summed, numpy float64."""
    corners = mesh.geometry.reshape(-1, 3, 3)
    result = []
    for p in points:
        a, b, c = corners[:, 0] - p, corners[:, 1] - p, corners[:, 2] - p
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = la * lb * lc + (a * b).sum(1) * lc + (a * c).sum(1) * lb + (b * c).sum(1) * la
        result.append(2.0 * np.arctan2(det, den).sum() / (4 * np.pi))
    return np.array(result)


def sample_points(scene, n, seed=0, pad=0.2):
    rng = np.random.default_rng(seed)
    b = scene.bounds()
    lo, hi = b.scene_lo, b.scene_hi
    return rng.uniform(lo - pad * (hi - lo), hi + pad * (hi - lo), size=(n, 3))


@pytest.fixture(scope="module")
def scenes(small_dragon, closed_sphere_mesh, spheres):
    return {"dragon-11k": small_dragon, "sphere": closed_sphere_mesh, "spheres": spheres}


@pytest.fixture(scope="module")
def references(scenes):
    out = {}
    for name, scene in scenes.items():
        points = sample_points(scene, 400, seed=len(name))
        if scene.kind == 0:
            corners = scene.geometry.reshape(-1, 3, 3)
            on_surface = np.concatenate([corners[:20, 0], corners[20:40].mean(axis=1),
                                         0.5 * (corners[40:60, 0] + corners[40:60, 1])])
        else:
            on_surface = scene.centers[:20] + scene.radii[:20, None] * np.array([0.0, 0.0, 1.0])
            on_surface = np.concatenate([on_surface, scene.centers[:5]])
        points = np.concatenate([points, on_surface])
        brute = ra.build(scene, "none")
        out[name] = (points, brute.closest_point(points), brute.winding_number(points),
                     brute.closest_point(points, max_distance=0.01))
    return out


def test_brute_force_matches_the_numpy_oracles(scenes, references):
    for name in ("dragon-11k", "sphere"):
        points, closest, winding, _ = references[name]
        chosen = points[::7]
        np.testing.assert_allclose(closest.distance[::7], oracle_distance(scenes[name], chosen), rtol=1e-9,
                                   atol=1e-12)
        off = closest.distance[::7] > 1e-9
        np.testing.assert_allclose(winding[::7][off], exact_winding(scenes[name], chosen[off]), atol=1e-9)
    points, closest, winding, _ = references["spheres"]
    s = scenes["spheres"]
    gaps = np.linalg.norm(points[:, None] - s.centers[None], axis=2) - s.radii[None]
    np.testing.assert_allclose(closest.distance, np.abs(gaps).min(axis=1), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(winding, (gaps < 0).sum(axis=1))


@pytest.mark.parametrize("method", METHODS)
def test_every_method_answers_every_query_as_brute_force(method, scenes, references):
    for name, scene in scenes.items():
        points, ref, ref_winding, ref_near = references[name]
        accel = ra.build(scene, method)
        cp = accel.closest_point(points)
        np.testing.assert_array_equal(cp.prim, ref.prim, err_msg=f"{method} {name}")
        np.testing.assert_array_equal(cp.distance, ref.distance)
        np.testing.assert_array_equal(cp.point, ref.point)
        np.testing.assert_array_equal(cp.u, ref.u)
        np.testing.assert_array_equal(cp.geom, np.zeros(len(points), dtype=np.int64))
        near = accel.closest_point(points, max_distance=0.01)
        np.testing.assert_array_equal(near.prim, ref_near.prim)
        assert np.isinf(near.distance[near.prim < 0]).all() and np.isnan(near.point[near.prim < 0]).all()
        np.testing.assert_array_equal(accel.distance(points), ref.distance)
        winding = accel.winding_number(points)
        off_surface = ref.distance > 1e-9
        assert np.abs(winding - ref_winding)[off_surface].max() < 0.2
        assert np.isfinite(winding).all()
        away = ref.distance > 0.02 * np.linalg.norm(scene.bounds().scene_hi - scene.bounds().scene_lo)
        inside = np.abs(ref_winding) > 0.5
        np.testing.assert_array_equal(accel.contains(points)[away], inside[away])
        signed = accel.signed_distance(points)
        np.testing.assert_array_equal(np.abs(signed), ref.distance)
        np.testing.assert_array_equal((signed < 0)[away], inside[away])


def test_fast_winding_error_is_bounded(small_dragon):
    accel = ra.build(small_dragon, "bvh-binned")
    points = sample_points(small_dragon, 600, seed=3)
    exact = exact_winding(small_dragon, points)
    np.testing.assert_allclose(accel.winding_number(points, accuracy=np.inf), exact, atol=1e-9)
    errors = {beta: np.abs(accel.winding_number(points, accuracy=beta) - exact).max() for beta in (1.0, 2.0, 4.0)}
    assert errors[2.0] < 0.15 and errors[4.0] < 0.03, errors
    assert errors[4.0] <= errors[2.0] <= errors[1.0]


def test_points_on_vertices_edges_faces_and_spheres(closed_sphere_mesh, spheres):
    corners = closed_sphere_mesh.geometry.reshape(-1, 3, 3)
    on = np.concatenate([corners[:, 0], corners[:, 1], 0.5 * (corners[:, 0] + corners[:, 2]), corners.mean(axis=1)])
    for method in ("none", "bvh-binned", "kdtree"):
        cp = ra.build(closed_sphere_mesh, method).closest_point(on)
        assert cp.distance.max() < 1e-12
    centers = spheres.centers[:50]
    on_sphere = centers + spheres.radii[:50, None] * np.array([1.0, 0.0, 0.0])
    accel = ra.build(spheres, "bvh-binned")
    assert accel.distance(on_sphere).max() < 1e-12
    cp = accel.closest_point(centers)
    alone = ra.build(ra.Spheres(centers[:1], spheres.radii[:1]), "none").closest_point(centers[:1])
    np.testing.assert_allclose(alone.point[0], centers[0] + [0, 0, spheres.radii[0]])
    assert alone.u[0] == 0.0 and alone.v[0] == 0.0
    assert (cp.distance <= spheres.radii[:50] + 1e-15).all()


@pytest.mark.parametrize("method", ["none", "grid", "bvh-binned", "kdtree", "octree"])
def test_duplicated_and_degenerate_triangles(method):
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [5, 5, 5]]
    faces = [[0, 1, 2], [0, 1, 2], [0, 3, 4], [5, 5, 5], [1, 3, 4]]
    mesh = ra.TriangleMesh(vertices, faces)
    points = np.array([[0.2, 0.2, 1.0], [2.5, 0.5, 0.0], [5, 5, 6.0], [3.5, -1, 0], [2.2, 0.0, 0.0]])
    cp = ra.build(mesh, method).closest_point(points)
    np.testing.assert_array_equal(cp.prim, [0, 2, 3, 2, 2])
    np.testing.assert_allclose(cp.distance, [1.0, 0.5, 1.0, np.sqrt(0.5 ** 2 + 1), 0.0], atol=1e-15)
    np.testing.assert_allclose(cp.point[1], [2.5, 0, 0])
    np.testing.assert_allclose(cp.distance, oracle_distance(mesh, points), atol=1e-15)


def _parity(accel, points, direction):
    """Ray-crossing parity: hits counted by stepping ``intersect`` past each one."""
    count = np.zeros(len(points), dtype=np.int64)
    t_min = np.zeros(len(points))
    alive = np.ones(len(points), dtype=bool)
    directions = np.broadcast_to(direction, points.shape)
    while alive.any():
        hits = accel.intersect(points[alive], directions[alive], t_min[alive])
        index = np.flatnonzero(alive)
        hit = hits.prim >= 0
        count[index[hit]] += 1
        t_min[index[hit]] = np.nextafter(hits.t[hit], np.inf) * (1 + 1e-12)
        alive[index[~hit]] = False
    return count % 2 == 1


def test_contains_agrees_with_parity_on_a_watertight_mesh(closed_sphere_mesh):
    accel = ra.build(closed_sphere_mesh, "bvh-binned")
    points = sample_points(closed_sphere_mesh, 1000, seed=5)
    points = points[accel.distance(points) > 1e-3]
    np.testing.assert_array_equal(accel.contains(points), _parity(accel, points, [0.3, 0.5, 0.81]))


def _capped(mesh):
    """The mesh with every boundary loop closed by a fan around its centroid."""
    faces = mesh.faces
    half = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(half, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = half[counts[inverse.ravel()] == 1]
    successor = {b: a for a, b in boundary}
    vertices, new_faces, seen = [mesh.vertices], [faces], set()
    n = len(mesh.vertices)
    for start in successor:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = successor[v]
        vertices.append(mesh.vertices[loop].mean(axis=0)[None])
        new_faces.append(np.array([[loop[i], loop[i - 1], n] for i in range(len(loop))]))
        n += 1
    return ra.TriangleMesh(np.concatenate(vertices), np.concatenate(new_faces)), mesh.vertices[list(seen)]


def test_winding_number_beats_parity_near_the_bunnys_holes(bunny):
    closed, rim = _capped(bunny)
    rng = np.random.default_rng(0)
    extent = np.linalg.norm(bunny.bounds().scene_hi - bunny.bounds().scene_lo)
    points = rim[rng.integers(0, len(rim), 400)] + rng.normal(scale=0.03 * extent, size=(400, 3))
    truth_accel = ra.build(closed, "bvh-binned")
    points = points[truth_accel.distance(points) > 1e-3 * extent]
    truth = truth_accel.contains(points)
    holey = ra.build(bunny, "bvh-binned")
    winding_errors = np.count_nonzero(holey.contains(points) != truth)
    parity_errors = np.count_nonzero(_parity(holey, points, [0.0, -1.0, 0.05]) != truth)
    assert truth.any() and (~truth).any()
    assert winding_errors < parity_errors, (winding_errors, parity_errors)


def test_scene_of_instances():
    mesh = ra.load_scene("sphere")
    similar = np.eye(4)
    similar[:3, :3] = 0.5 * np.array([[0, -1.0, 0], [1, 0, 0], [0, 0, 1]])
    similar[:3, 3] = [3, 0, 0]
    sheared = np.eye(4)
    sheared[:3, :3] = [[1, 0.5, 0], [0, 2, 0], [0, 0, 0.7]]
    sheared[:3, 3] = [-3, 1, 0]
    mirrored = np.diag([-1.0, 1, 1, 1])
    mirrored[:3, 3] = [0, 4, 0]
    scene = ra.Scene()
    for transform in (None, similar, sheared, mirrored):
        scene.add(mesh, transform)
    flat = ra.build(scene.flatten(), "none")
    points = sample_points(scene.flatten(), 500, seed=9)
    ref = flat.closest_point(points)
    for method in ("none", "bvh-binned", "grid"):
        accel = ra.build(scene, method)
        cp = accel.closest_point(points)
        np.testing.assert_allclose(cp.distance, ref.distance, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(cp.point, ref.point, atol=1e-12)
        flat_prim = cp.prim + len(mesh) * cp.geom
        reported = np.array([oracle_distance(ra.TriangleMesh(scene.flatten().geometry[k].reshape(3, 3), [[0, 1, 2]]),
                                             p[None])[0] for k, p in zip(flat_prim, points)])
        np.testing.assert_allclose(reported, ref.distance, rtol=1e-9, atol=1e-14)
        np.testing.assert_allclose(accel.winding_number(points, accuracy=np.inf), flat.winding_number(points),
                                   atol=1e-9)
        away = ref.distance > 1e-2
        np.testing.assert_array_equal(accel.contains(points)[away], flat.contains(points)[away])
        np.testing.assert_allclose(accel.signed_distance(points)[away], flat.signed_distance(points)[away],
                                   rtol=1e-12)


def test_bad_and_empty_input(closed_sphere_mesh):
    accel = ra.build(closed_sphere_mesh, "bvh-binned")
    for bad in ([[np.nan, 0, 0]], [[np.inf, 0, 0]], np.zeros((3, 2)), np.zeros((2, 3, 1)), [["a", "b", "c"]]):
        for query in ("closest_point", "distance", "winding_number", "contains", "signed_distance"):
            with pytest.raises(ValueError):
                getattr(accel, query)(bad)
    for bad in (-1.0, np.nan, "far"):
        with pytest.raises(ValueError):
            accel.closest_point([[0, 0, 0]], max_distance=bad)
    with pytest.raises(ValueError):
        accel.winding_number([[0, 0, 0]], accuracy=0.0)
    empty = np.zeros((0, 3))
    cp = accel.closest_point(empty)
    assert cp.point.shape == (0, 3) and cp.prim.shape == (0,) and cp.prim.dtype == np.int64
    for query in ("distance", "winding_number", "contains", "signed_distance"):
        assert getattr(accel, query)(empty).shape == (0,)
    assert accel.closest_point(np.zeros((4, 3), dtype=np.float32), max_distance=0).prim.tolist() == [-1] * 4


def test_dask_point_queries(closed_sphere_mesh):
    da = pytest.importorskip("dask.array")
    accel = ra.build(closed_sphere_mesh, "bvh-binned")
    points = sample_points(closed_sphere_mesh, 300, seed=2)
    lazy = da.from_array(points, chunks=100)
    cp = accel.closest_point(lazy)
    ref = accel.closest_point(points)
    np.testing.assert_array_equal(cp.point.compute(), ref.point)
    np.testing.assert_array_equal(cp.prim.compute(), ref.prim)
    for query in ("distance", "winding_number", "contains", "signed_distance"):
        np.testing.assert_array_equal(getattr(accel, query)(lazy).compute(), getattr(accel, query)(points))


def _subdivided_cube():
    """A closed cube of side 1 centred at the origin, each face split into 8 triangles around its
    centre, counter-clockwise seen from outside."""
    import trimesh

    cube = trimesh.creation.box()
    return ra.TriangleMesh(*trimesh.remesh.subdivide(cube.vertices, cube.faces))


def test_caps_close_the_holes_and_nothing_else(bunny):
    from rayaccel.geometry.caps import boundary_caps

    def open_edges(vertices, faces):
        points, same = np.unique(vertices, axis=0, return_inverse=True)
        f = same.reshape(-1)[faces]
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        edges = edges[edges[:, 0] != edges[:, 1]]
        balance = {}
        for a, b in edges.tolist():
            key, sign = ((a, b), 1) if a < b else ((b, a), -1)
            balance[key] = balance.get(key, 0) + sign
        return {k: v for k, v in balance.items() if v}, points

    cube = _subdivided_cube()
    assert len(boundary_caps(cube.vertices, cube.faces)[1]) == 0
    split = cube.geometry.reshape(-1, 3)
    assert len(boundary_caps(split, np.arange(len(split)).reshape(-1, 3))[1]) == 0
    for vertices, faces in [(bunny.vertices, bunny.faces), (cube.vertices, cube.faces[3:]),
                            (cube.vertices, np.concatenate([cube.faces[2:], cube.faces[:1], cube.faces[5:9, ::-1]]))]:
        cap_vertices, cap_faces = boundary_caps(vertices, faces)
        assert len(cap_faces) == sum(abs(v) for v in open_edges(vertices, faces)[0].values())
        closed = np.concatenate([np.asarray(vertices)[faces].reshape(-1, 3), cap_vertices[cap_faces].reshape(-1, 3)])
        assert not open_edges(closed, np.arange(len(closed)).reshape(-1, 3))[0]
    assert len(boundary_caps(bunny.vertices, bunny.faces)[1]) == 223


@pytest.mark.parametrize("method", ["bvh-binned", "kdtree", "grid", "octree"])
def test_winding_number_of_a_closed_mesh_is_exact_through_vertices_and_edges(method):
    from rayaccel.structures.ray_winding import escape_directions

    cube = _subdivided_cube()
    accel = ra.build(cube, method)
    corners = cube.geometry.reshape(-1, 3, 3)
    targets = np.unique(np.concatenate([corners[:, 0], 0.5 * (corners[:, 0] + corners[:, 1])]), axis=0)
    targets = targets[np.abs(targets).max(axis=1) == 0.5]
    points = []
    for target in targets:
        axis = int(np.argmax(np.abs(target)))
        if np.sum(np.abs(target) == 0.5) > 1:
            continue
        direction = np.array([3.0, 5.0, 7.0]) / 512.0
        direction[axis] = np.sign(target[axis])
        for step in (0.25, 0.5, 0.75):
            point = target - step * direction
            if np.array_equal(escape_directions(point[None], *accel.scene_box)[0], direction):
                points.append(point)
    points = np.array(points)
    assert len(points) > 20
    np.testing.assert_array_equal(accel.winding_number(points), np.ones(len(points)))
    assert accel.contains(points).all()
    outside = points * 1.5
    np.testing.assert_array_equal(accel.winding_number(outside), np.where(np.abs(outside).max(axis=1) < 0.5, 1, 0))
    on_face = np.array([[0.5, 0.125, -0.1875], [-0.25, 0.5, 0.0625], [0.3125, 0.0625, -0.5]])
    np.testing.assert_array_equal(accel.winding_number(on_face), [0.5, 0.5, 0.5])


@pytest.mark.parametrize("method", ["bvh-binned", "kdtree"])
def test_winding_number_with_caps_matches_the_exact_sum(bunny, method):
    accel = ra.build(bunny, method)
    points = sample_points(bunny, 300, seed=11)
    exact = exact_winding(bunny, points)
    np.testing.assert_allclose(accel.winding_number(points, accuracy=np.inf), exact, atol=1e-9)
    assert np.abs(accel.winding_number(points) - exact).max() < 0.05
    np.testing.assert_array_equal(accel.contains(points), np.abs(exact) > 0.5)


def test_winding_number_of_a_soup_and_after_a_refit(bunny):
    rng = np.random.default_rng(4)
    soup = ra.TriangleMesh(rng.normal(size=(300, 3)), np.arange(300).reshape(-1, 3))
    points = rng.normal(size=(50, 3))
    np.testing.assert_allclose(ra.build(soup, "bvh-binned").winding_number(points, accuracy=np.inf),
                               exact_winding(soup, points), atol=1e-9)
    accel = ra.build(bunny, "bvh-binned")
    points = sample_points(bunny, 200, seed=12)
    before = accel.winding_number(points)
    shift = np.array([0.3, -0.2, 0.1])
    accel.refit(bunny.vertices + shift)
    np.testing.assert_allclose(accel.winding_number(points + shift), before, atol=1e-9)
