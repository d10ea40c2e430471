"""The statistics the literature reports for an acceleration structure.

Structure: ``build_seconds``, ``nodes``, ``leaves``, ``nonempty_leaves``, ``max_depth``,
``references`` (primitive references stored; more than the primitives where they straddle
cells), ``avg_prims_per_nonempty_leaf`` and ``bytes`` (everything a query reads: the
structure's arrays, the primitive geometry it tests, and the grids' per-thread mailboxes).
The kd-tree adds ``primitives_apart``, the large primitives it was built without and every
ray tests first, which its expected tests count once per ray.

Expected figures use the surface area argument (Goldsmith & Salmon 1987;
MacDonald & Booth 1990): for a random line that hits a convex body A, the
probability that it also hits a convex body B inside A is SA(B) / SA(A)
(Cauchy-Crofton: the mean projected area of a convex body is a quarter of its
surface area). Summing over the nodes of a structure gives, per ray that hits
the root box, the expected number of

* traversal steps ``sum over inner nodes of SA / SA_root``,
* leaves visited ``sum over leaves of SA / SA_root``,
* primitive tests ``sum over leaves of n * SA / SA_root``,

and ``expected_cost = C_t * steps + C_i * tests``. These assume rays that
neither stop at the first hit nor skip repeated tests; the measured counters
``avg_nodes_per_ray`` and ``avg_intersections_per_ray`` show what a real ray
batch costs.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TRAVERSAL_COST", "INTERSECTION_COST", "box_area", "surface_area_stats", "measured_stats"]

TRAVERSAL_COST = 1.0
INTERSECTION_COST = 1.0


def box_area(lo, hi) -> np.ndarray:
    """Surface area of boxes given by corner arrays (..., 3)."""
    e = np.maximum(np.asarray(hi, float) - np.asarray(lo, float), 0.0)
    return 2.0 * (e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 0] * e[..., 2])


def surface_area_stats(root_area, step_areas, leaf_areas, leaf_counts,
                       traversal_cost: float = TRAVERSAL_COST, intersection_cost: float = INTERSECTION_COST) -> dict:
    """Expected steps, leaves, tests and cost per ray from node surface areas.

    ``root_area``: area of the root volume; ``step_areas``: areas of the nodes
    whose visit is a traversal step (inner nodes of a tree; every cell of a
    grid); ``leaf_areas``/``leaf_counts``: area and primitive count of each leaf or cell.
    A root of zero area (every vertex on one point or line) gives the limit of a shrinking
    box, in which a ray that enters the root enters every node.
    """
    root = float(root_area)
    step_areas, leaf_areas = np.asarray(step_areas, float), np.asarray(leaf_areas, float)
    if root == 0.0:
        root, step_areas, leaf_areas = 1.0, np.ones_like(step_areas), np.ones_like(leaf_areas)
    steps = float(np.sum(step_areas)) / root
    leaves = float(np.sum(leaf_areas)) / root
    tests = float(np.dot(leaf_areas, np.asarray(leaf_counts, float))) / root
    return {
        "expected_traversal_steps": steps,
        "expected_leaves_visited": leaves,
        "expected_intersections": tests,
        "expected_cost": traversal_cost * steps + intersection_cost * tests,
    }


def measured_stats(accel, origins, directions) -> dict:
    """Average nodes (cells) visited and primitive tests per ray over a ray batch, closest hit."""
    hits = accel.intersect(origins, directions, counters=True)
    return {
        "avg_nodes_per_ray": float(hits.counters.nodes.mean()),
        "avg_leaves_per_ray": float(hits.counters.leaves.mean()),
        "avg_intersections_per_ray": float(hits.counters.tests.mean()),
        "avg_mailbox_skips_per_ray": float(hits.counters.mailbox_skips.mean()),
        "hit_fraction": float(hits.hit.mean()),
        "rays_measured": int(len(hits.t)),
    }
