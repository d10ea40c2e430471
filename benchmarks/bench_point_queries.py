"""Point queries on the full dragon: rayaccel against Open3D's RaycastingScene and trimesh.

1,048,576 query points, half near the surface and half uniform in the box
(:func:`rayaccel.experiments.queries.query_points`): ``closest_point`` vs
``compute_closest_points``, ``contains`` vs ``compute_occupancy``,
``signed_distance`` vs ``compute_signed_distance``, medians of interleaved
rounds in one process, and trimesh's ``proximity.closest_point`` on a subset.

    PYTHONPATH=src python3 benchmarks/bench_point_queries.py [--points N] [--rounds R] [--out DIR]
"""

from __future__ import annotations

import argparse

from _common import ensure_competitors
from rich.console import Console

from rayaccel.experiments import queries


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="dragon")
    parser.add_argument("--points", type=int, default=1_048_576)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--method", default="bvh-binned")
    parser.add_argument("--trimesh-points", type=int, default=2000)
    parser.add_argument("--out", default="rayaccel-out")
    args = parser.parse_args()
    console = Console()
    available = ensure_competitors(console)
    if "open3d" not in available:
        console.print("Open3D is missing: only rayaccel and trimesh are timed")
    rows, builds = queries.run(args.scene, n=args.points, rounds=args.rounds, method=args.method,
                               trimesh_points=args.trimesh_points)
    table, plot = queries.write_report(rows, builds, args.out, args.scene, args.rounds)
    console.print(table.read_text())
    console.print(f"wrote {table} and {plot}")


if __name__ == "__main__":
    main()
