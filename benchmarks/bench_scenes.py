"""Refit and load against build on the full dragon, and the instanced forest's memory against its flattened copy.

Prints, for ``bvh-binned`` on the full dragon (871,414 triangles), the medians over
interleaved rounds of: a build, a refit to a twisted copy of the mesh and back,
a save and a load, and the ratios refit / build and load / build (the issue's
targets: at most 0.1 and 0.2). Then, each in its own process, the
``forest-instanced`` scene built as a two-level structure and its flattened
copy built as one mesh: the bytes ``stats()`` counts, the resident memory the
build and a render add, and the render time.

    python benchmarks/bench_scenes.py [--rounds 5] [--size 512]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import rayaccel as ra


def _twisted(vertices: np.ndarray) -> np.ndarray:
    center = vertices.mean(axis=0)
    angle = 1.2 * (vertices[:, 1] - center[1]) / np.ptp(vertices[:, 1])
    x, z = vertices[:, 0] - center[0], vertices[:, 2] - center[2]
    return np.column_stack((center[0] + x * np.cos(angle) - z * np.sin(angle), vertices[:, 1],
                            center[2] + x * np.sin(angle) + z * np.cos(angle)))


def _timed(run):
    start = time.perf_counter()
    result = run()
    return time.perf_counter() - start, result


def dragon(rounds: int) -> None:
    mesh = ra.load_scene("dragon")
    moved = _twisted(mesh.vertices)
    times = {"build": [], "refit": [], "refit back": [], "save": [], "load": []}
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "dragon.npz"
        warm = ra.build(mesh, "bvh-binned")
        warm.refit(moved)
        warm.save(path)
        ra.load_accelerator(path)
        for _ in range(rounds):
            seconds, accel = _timed(lambda: ra.build(mesh, "bvh-binned"))
            times["build"].append(seconds)
            times["refit"].append(_timed(lambda: accel.refit(moved))[0])
            sah = accel.stats(*ra.Camera.framing(*accel.scene_box).rays(64, 64))
            times["refit back"].append(_timed(lambda: accel.refit(mesh.vertices))[0])
            times["save"].append(_timed(lambda: accel.save(path))[0])
            times["load"].append(_timed(lambda: ra.load_accelerator(path))[0])
        size = path.stat().st_size
    median = {key: float(np.median(values)) for key, values in times.items()}
    print(f"full dragon, {len(mesh):,} triangles, bvh-binned, medians of {rounds} interleaved rounds")
    for key, value in median.items():
        print(f"  {key:10s} {value:7.3f} s   ({value / median['build']:.3f} x build)")
    print(f"  file {size / 1e6:.1f} MB; SAH cost after the twist {sah['sah_cost']:.1f} "
          f"against {sah['sah_cost_at_build']:.1f} at build")


def _resident_bytes() -> int:
    import os

    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def forest_variant(variant: str, size: int) -> dict:
    """Build and render ``forest-instanced`` as given or flattened, in this process."""
    from rayaccel.render import default_camera, default_lights, render

    scene = ra.load_scene("forest-instanced")
    reference = ra.build(scene.flatten(), "none")  # the same camera and lights for both variants
    camera = default_camera(reference)
    lights = default_lights(reference, camera)
    target = scene.flatten() if variant == "flattened" else scene
    warm = ra.build(target, "bvh-binned")
    render(warm, camera, 16, 16, lights)
    del warm, reference
    before = _resident_bytes()
    seconds, accel = _timed(lambda: ra.build(target, "bvh-binned"))
    built = _resident_bytes() - before
    result = render(accel, camera, size, size, lights)
    stats = accel.stats(np.zeros((1, 3)), np.ones((1, 3)))
    per_object = [s["bytes"] for s in stats.get("object_stats", [])]
    return {"variant": variant, "primitives": len(scene), "build_seconds": seconds, "stats_bytes": stats["bytes"],
            "top_bytes": stats.get("top_bytes", 0), "object_bytes": per_object, "built_bytes": built,
            "resident_bytes": _resident_bytes() - before, "render_seconds": result.trace_seconds,
            "primary_mrays": result.mrays_per_second}


def forest(size: int) -> None:
    print(f"forest-instanced, bvh-binned, {size}x{size} with shadows, each variant in its own process")
    for variant in ("instanced", "flattened"):
        out = subprocess.run([sys.executable, __file__, "--forest-variant", variant, "--size", str(size)],
                             check=True, capture_output=True, text=True).stdout
        row = json.loads(out.strip().splitlines()[-1])
        parts = ""
        if row["object_bytes"]:
            parts = (f" (top level {row['top_bytes'] / 1e6:.2f}, objects "
                     + " / ".join(f"{b / 1e6:.3f}" for b in row["object_bytes"]) + ")")
        print(f"  {variant:9s} {row['primitives']:,} primitives: structures {row['stats_bytes'] / 1e6:6.2f} MB{parts}, "
              f"resident +{row['built_bytes'] / 1e6:.1f} MB after the build, +{row['resident_bytes'] / 1e6:.1f} MB "
              f"after the render, build "
              f"{row['build_seconds']:.3f} s, trace {row['render_seconds']:.3f} s "
              f"(primary {row['primary_mrays']:.2f} Mrays/s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--forest-variant", choices=["instanced", "flattened"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.forest_variant:
        print(json.dumps(forest_variant(args.forest_variant, args.size)))
        return
    dragon(args.rounds)
    forest(args.size)


if __name__ == "__main__":
    main()
