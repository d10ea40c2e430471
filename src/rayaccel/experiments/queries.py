"""Point queries against Open3D's ``RaycastingScene`` and trimesh's ``proximity``.

On one mesh (the full dragon by default in ``benchmarks/bench_point_queries.py``),
``n`` query points, half near the surface (uniform surface samples plus
Gaussian noise of 1 % of the box diagonal) and half uniform in the box:
``closest_point`` against Open3D's ``compute_closest_points``, ``contains``
against ``compute_occupancy``, ``signed_distance`` against
``compute_signed_distance``; trimesh's ``proximity.closest_point`` on a subset,
its time scaled to all points. Each figure is the median of interleaved
rounds (every subject once per round), so that the ratios compare the same
moments of a shared machine. Builds are timed once, separately.
Writes ``queries.md`` and ``queries.png``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..catalog import load_scene
from ..structures.registry import build
from ._report import markdown_table, new_figure, save_figure

__all__ = ["QueryRow", "query_points", "open3d_scene", "run", "write_report"]


@dataclass
class QueryRow:
    query: str
    subject: str
    seconds: float
    points: int

    @property
    def mpoints_per_second(self) -> float:
        return self.points / self.seconds / 1e6


def query_points(mesh, n: int, seed: int = 0) -> np.ndarray:
    """``n`` points: half near the surface (area-weighted samples plus noise), half uniform in the box."""
    rng = np.random.default_rng(seed)
    corners = mesh.geometry.reshape(-1, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    near = n // 2
    tri = rng.choice(len(corners), near, p=area / area.sum())
    r1, r2 = rng.random(near), rng.random(near)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    c = corners[tri]
    surface = c[:, 0] + r1[:, None] * (c[:, 1] - c[:, 0]) + r2[:, None] * (c[:, 2] - c[:, 0])
    b = mesh.bounds()
    diagonal = float(np.linalg.norm(b.scene_hi - b.scene_lo))
    surface += rng.normal(scale=0.01 * diagonal, size=surface.shape)
    box = rng.uniform(b.scene_lo, b.scene_hi, size=(n - near, 3))
    return np.ascontiguousarray(np.concatenate([surface, box]))


def open3d_scene(mesh):
    """``(RaycastingScene over the mesh, the open3d module)``, or None when Open3D is not installed."""
    try:
        import open3d as o3d
    except ImportError:
        return None
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    return scene, o3d


def _trimesh_proximity_works() -> bool:
    """trimesh's proximity queries need ``rtree`` (``pip install rtree``); without it the row is left out."""
    try:
        import rtree  # noqa: F401
    except ImportError:
        return False
    return True


def run(scene_name: str = "dragon-203k", n: int = 262_144, rounds: int = 3, method: str = "bvh-binned",
        trimesh_points: int = 2000, progress=None) -> tuple[list[QueryRow], dict]:
    """Time the queries; returns the rows and the build seconds per subject."""
    mesh = load_scene(scene_name)
    points = query_points(mesh, n)
    start = time.perf_counter()
    accel = build(mesh, method)
    builds = {f"rayaccel {method}": time.perf_counter() - start}
    accel.closest_point(points[:64])
    accel.signed_distance(points[:64])
    subjects = {
        ("closest_point", f"rayaccel {method}"): lambda: accel.closest_point(points),
        ("contains", f"rayaccel {method}"): lambda: accel.contains(points),
        ("signed_distance", f"rayaccel {method}"): lambda: accel.signed_distance(points),
    }
    start = time.perf_counter()
    o3d_scene = open3d_scene(mesh)
    if o3d_scene is not None:
        scene, o3d = o3d_scene
        builds["Open3D RaycastingScene (lazy: builds on the first query)"] = time.perf_counter() - start
        query = o3d.core.Tensor(points.astype(np.float32))
        subjects[("closest_point", "Open3D")] = lambda: scene.compute_closest_points(query)["points"].numpy()
        subjects[("contains", "Open3D")] = lambda: scene.compute_occupancy(query).numpy()
        subjects[("signed_distance", "Open3D")] = lambda: scene.compute_signed_distance(query).numpy()
        subjects[("closest_point", "Open3D")]()
    times = {key: [] for key in subjects}
    for r in range(rounds):
        for key, call in subjects.items():
            start = time.perf_counter()
            call()
            times[key].append(time.perf_counter() - start)
        if progress is not None:
            progress(r + 1)
    rows = [QueryRow(query, subject, float(np.median(t)), n) for (query, subject), t in times.items()]
    if trimesh_points and _trimesh_proximity_works():
        import trimesh

        tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        subset = points[:: max(1, n // trimesh_points)][:trimesh_points]
        start = time.perf_counter()
        trimesh.proximity.closest_point(tm, subset)
        seconds = time.perf_counter() - start
        rows.append(QueryRow("closest_point", "trimesh (subset, scaled)", seconds * n / len(subset), n))
    return rows, builds


def write_report(rows: list[QueryRow], builds: dict, out_dir, scene_name: str, rounds: int) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ours = {r.query: r.seconds for r in rows if r.subject.startswith("rayaccel")}
    headers = ["query", "subject", "seconds", "M points/s", "rayaccel speed-up"]
    table = [[r.query, r.subject, f"{r.seconds:.3f}", f"{r.mpoints_per_second:.3f}",
              f"{r.seconds / ours[r.query]:.2f}x"] for r in rows]
    n = rows[0].points
    lines = [f"# Point queries on {scene_name}: {n:,} points (half near the surface, half in the box)", "",
             f"Medians of {rounds} interleaved rounds; rayaccel speed-up = subject's time / rayaccel's time. "
             "trimesh ran on a subset, its time scaled to all points.", ""]
    lines += markdown_table(headers, table, align_right_from=2)
    lines += ["", "Builds: " + ", ".join(f"{k} {v:.2f} s" for k, v in builds.items())]
    path = out_dir / "queries.md"
    path.write_text("\n".join(lines) + "\n")
    fig, (ax,) = new_figure(1, width=8.0)
    queries = list(dict.fromkeys(r.query for r in rows))
    subjects = list(dict.fromkeys(r.subject for r in rows))
    width = 0.8 / len(subjects)
    for j, subject in enumerate(subjects):
        xs, ys = [], []
        for i, query in enumerate(queries):
            for r in rows:
                if r.query == query and r.subject == subject:
                    xs.append(i + j * width)
                    ys.append(r.mpoints_per_second)
        ax.bar(xs, ys, width=width, color=f"C{j}", label=subject)
    ax.set_xticks([i + 0.4 - width / 2 for i in range(len(queries))], queries)
    ax.set(yscale="log", ylabel="million points per second", title=f"point queries, {scene_name}, {n:,} points")
    ax.legend(fontsize=8)
    return path, save_figure(fig, out_dir / "queries.png")
