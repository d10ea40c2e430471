"""Procedural scenes for the lecture's kd-tree table: a forest, and a forest with a chair; and an
instanced forest (:class:`rayaccel.Scene`) of thousands of placements of one tree.

The lecture compares structures on scenes whose primitives are spread very
unevenly: a *forest* (many small objects scattered over a plane) and the same
forest with one dense object in it, either large (it fills much of the scene)
or small (a "teapot in a stadium": a few cells of a uniform grid would hold all
of it). These are built here from simple parts, deterministic for a seed, with
y pointing up:

* a tree is a hexagonal trunk and two stacked eight-sided cones (28 triangles);
* the chair is a seat, four legs and a back, each a box whose faces are
  tessellated into a fine grid of triangles (about 41,000 in all), so that it
  is far denser than the trees around it.

The instanced forest places one tree mesh thousands of times, each with its
own height, turn about the vertical and position, with the chair among them:
a scene whose flattened copy would repeat the tree's triangles per placement,
while its two-level structure stores them once.
"""

from __future__ import annotations

import numpy as np

from .instances import Scene
from .scene import TriangleMesh

__all__ = ["forest", "chair", "forest_with_chair", "forest_instanced", "PROCEDURAL_SCENES"]

FOREST_SIZE = 100.0


def _prism(base_center, radius, height, sides):
    """Side walls of a vertical prism (no caps): vertices and faces."""
    angles = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = np.column_stack((radius * np.cos(angles), radius * np.sin(angles), np.zeros(sides)))
    vertices = np.concatenate((ring, ring + [0.0, 0.0, height])) + base_center
    k = np.arange(sides)
    nxt = (k + 1) % sides
    faces = np.concatenate((np.column_stack((k, nxt, sides + k)), np.column_stack((nxt, sides + nxt, sides + k))))
    return vertices, faces


def _cone(base_center, radius, height, sides):
    """A cone's mantle (no base): vertices and faces."""
    angles = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = np.column_stack((radius * np.cos(angles), radius * np.sin(angles), np.zeros(sides)))
    vertices = np.concatenate((ring, [[0.0, 0.0, height]])) + base_center
    k = np.arange(sides)
    return vertices, np.column_stack((k, (k + 1) % sides, np.full(sides, sides)))


def _merge(parts):
    vertices, faces, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def _tree(position, height):
    trunk_height = 0.3 * height
    return [
        _prism(position, 0.04 * height, trunk_height, 6),
        _cone(position + [0.0, 0.0, trunk_height], 0.25 * height, 0.45 * height, 8),
        _cone(position + [0.0, 0.0, trunk_height + 0.3 * height], 0.18 * height, 0.4 * height, 8),
    ]


def _ground(s=FOREST_SIZE):
    return np.array([[0.0, 0.0, 0.0], [s, 0.0, 0.0], [s, s, 0.0], [0.0, s, 0.0]]), np.array([[0, 1, 2], [0, 2, 3]])


def _y_up(vertices):
    """Built with z up; returned with y up like the scanned meshes (and the default camera)."""
    return vertices[:, [0, 2, 1]]


def forest(n_trees: int = 700, seed: int = 0) -> TriangleMesh:
    """``n_trees`` trees of random height (2-6 units) scattered over a 100 x 100 ground
    plane; 700 trees make about 19,600 triangles."""
    rng = np.random.default_rng(seed)
    positions = np.column_stack((rng.uniform(2.0, FOREST_SIZE - 2.0, (n_trees, 2)), np.zeros(n_trees)))
    heights = rng.uniform(2.0, 6.0, n_trees)
    parts = [_ground()]
    for position, height in zip(positions, heights):
        parts.extend(_tree(position, height))
    vertices, faces = _merge(parts)
    return TriangleMesh(_y_up(vertices), faces)


def _tessellated_box(lo, hi, k):
    """A box whose six faces are each a k x k grid of quads (two triangles each)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    s = np.linspace(0.0, 1.0, k + 1)
    u, v = np.meshgrid(s, s, indexing="ij")
    quad = np.arange(k + 1)[:, None] * (k + 1) + np.arange(k + 1)[None, :]
    a, b, c, d = quad[:-1, :-1].ravel(), quad[1:, :-1].ravel(), quad[1:, 1:].ravel(), quad[:-1, 1:].ravel()
    grid_faces = np.concatenate((np.column_stack((a, b, c)), np.column_stack((a, c, d))))
    parts = []
    for axis in range(3):
        i, j = (axis + 1) % 3, (axis + 2) % 3
        for side in (lo[axis], hi[axis]):
            points = np.empty(((k + 1) ** 2, 3))
            points[:, axis] = side
            points[:, i] = lo[i] + u.ravel() * (hi[i] - lo[i])
            points[:, j] = lo[j] + v.ravel() * (hi[j] - lo[j])
            parts.append((points, grid_faces))
    return _merge(parts)


def chair(size: float = 1.0, detail: int = 24) -> TriangleMesh:
    """A chair of height about ``2 * size`` standing on y = 0 at the origin, made of six
    boxes tessellated ``detail`` x ``detail`` per face (12 detail^2 triangles per box)."""
    legs = [((x, y, 0.0), (x + 0.08, y + 0.08, 1.0)) for x in (0.0, 0.92) for y in (0.0, 0.92)]
    boxes = legs + [((0.0, 0.0, 1.0), (1.0, 1.0, 1.1)), ((0.0, 0.92, 1.1), (1.0, 1.0, 2.1))]
    vertices, faces = _merge([_tessellated_box(lo, hi, detail) for lo, hi in boxes])
    return TriangleMesh(_y_up(vertices) * size, faces)


def forest_with_chair(large: bool, seed: int = 0) -> TriangleMesh:
    """The forest with a chair in it: ``large`` spans 30 units of the 100-unit forest
    (taller than the trees), small is 0.5 units (a dense speck among them)."""
    trees = forest(seed=seed)
    size = 15.0 if large else 0.25
    seat = chair(size)
    offset = np.array([35.0, 0.0, 35.0]) if large else np.array([50.3, 0.0, 49.7])
    vertices = np.concatenate((trees.vertices, seat.vertices + offset))
    faces = np.concatenate((trees.faces, seat.faces + len(trees.vertices)))
    return TriangleMesh(vertices, faces)


def forest_instanced(n_trees: int = 5000, size: float = 250.0, seed: int = 0) -> Scene:
    """``n_trees`` placements of one 28-triangle tree (heights 2-6 units, turned at random
    about the vertical) over a ``size`` x ``size`` ground, about as dense as :func:`forest`,
    with the chair of :func:`chair` (3 units tall) among them near the middle. Instance 0 is
    the ground, 1 the chair, the trees follow."""
    rng = np.random.default_rng(seed)
    tree_vertices, tree_faces = _merge(_tree(np.zeros(3), 1.0))
    tree = TriangleMesh(_y_up(tree_vertices), tree_faces)
    ground_vertices, ground_faces = _ground(size)
    scene = Scene()
    scene.add(TriangleMesh(_y_up(ground_vertices), ground_faces))
    seat = np.eye(4)
    seat[:3, 3] = (0.5 * size + 1.3, 0.0, 0.5 * size - 0.7)
    scene.add(chair(1.5), seat)
    positions = rng.uniform(2.0, size - 2.0, (n_trees, 2))
    heights = rng.uniform(2.0, 6.0, n_trees)
    angles = rng.uniform(0.0, 2.0 * np.pi, n_trees)
    for (x, z), height, angle in zip(positions, heights, angles):
        place = np.eye(4)
        cos, sin = np.cos(angle), np.sin(angle)
        place[:3, :3] = height * np.array([[cos, 0.0, sin], [0.0, 1.0, 0.0], [-sin, 0.0, cos]])
        place[:3, 3] = (x, 0.0, z)
        scene.add(tree, place)
    return scene


PROCEDURAL_SCENES = {
    "forest": forest,
    "forest-large-chair": lambda: forest_with_chair(large=True),
    "forest-small-chair": lambda: forest_with_chair(large=False),
    "forest-instanced": forest_instanced,
}
