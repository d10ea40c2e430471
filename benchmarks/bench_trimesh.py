"""trimesh's ray and proximity calls on trimesh's Embree engine, its numpy engine and rayaccel's, same run.

Subjects, each set on a copy of the mesh as ``mesh.ray`` and ``mesh.nearest``:
    Embree   ``trimesh.ray.ray_pyembree.RayMeshIntersector`` (Embree 4 through embreex, one thread: what
             trimesh uses when embreex is installed) with ``trimesh.proximity.ProximityQuery`` (an r-tree
             of the triangles and a kd-tree of the vertices, queried from Python: trimesh's only one);
    numpy    ``trimesh.ray.ray_triangle.RayMeshIntersector`` (an r-tree and numpy, trimesh's fallback
             without embreex) with the same ``ProximityQuery``;
    rayaccel ``rayaccel.integrations.trimesh.RayMeshIntersector`` and ``ProximityQuery`` (``--method``).

Calls: ``mesh.ray.intersects_location`` with every hit and with the first hit only, ``intersects_any``
on two ray sets (``side`` x ``side`` pinhole-camera rays framing the mesh, and as many rays with
origins uniform in the mesh's box and uniform directions); ``mesh.ray.contains_points`` on ``points``
points, half near the surface and half in the box (:func:`rayaccel.experiments.queries.query_points`);
``mesh.nearest.on_surface`` and ``mesh.nearest.signed_distance`` on ``proximity_points`` of those
points (evenly spaced among them), since trimesh's ``ProximityQuery`` gathers a candidate list per
point whose size grows with its distance from the surface (65,536 such points on the full dragon
took more than 20 GB here).

Timing: a first call on a fresh copy of the mesh with a fresh engine (``mesh.copy()`` untimed; every
structure the call needs built inside it: Embree's scene, rayaccel's BVH, trimesh's r-tree and the
mesh's triangles and normals), then the same call again. Embree and rayaccel are timed in ``rounds``
interleaved rounds (each call of both, in turn, each round), and the figures are medians. The numpy
engine is timed once, in the first round, on ``numpy_rays`` evenly spaced rays or points of each call
(its per-ray Python loop makes the full sets take hours): its rate is that subset's, reported as
measured, not scaled up. Answers are compared with Embree's in the first round.

    PYTHONPATH=src python3 benchmarks/bench_trimesh.py [--scenes bunny dragon] [--side 512] [--rounds 5]
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).parent))
from _common import ROOT, import_problem, incoherent_rays, primary_rays  # noqa: E402

import rayaccel as ra  # noqa: E402
from rayaccel.experiments.queries import query_points  # noqa: E402

SUBJECTS = ("Embree", "rayaccel", "numpy")
RAY_CALLS = ("intersects_location", "intersects_location first", "intersects_any")
POINT_CALLS = ("contains_points", "nearest.on_surface", "nearest.signed_distance")


def engines(subject: str, method: str):
    """``(ray engine class, proximity class)`` of a subject; both take the mesh."""
    import trimesh

    if subject == "rayaccel":
        from rayaccel.integrations.trimesh import ProximityQuery, RayMeshIntersector

        return (lambda mesh: RayMeshIntersector(mesh, method)), (lambda mesh: ProximityQuery(mesh, method))
    if subject == "Embree":
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    else:
        from trimesh.ray.ray_triangle import RayMeshIntersector
    return RayMeshIntersector, trimesh.proximity.ProximityQuery


def run_call(call: str, mesh, data):
    if call == "intersects_location":
        return mesh.ray.intersects_location(*data)
    if call == "intersects_location first":
        return mesh.ray.intersects_location(*data, multiple_hits=False)
    if call == "intersects_any":
        return mesh.ray.intersects_any(*data)
    if call == "contains_points":
        return mesh.ray.contains_points(data)
    if call == "nearest.on_surface":
        return mesh.nearest.on_surface(data)
    return mesh.nearest.signed_distance(data)


def agreement(call: str, ours, theirs, n: int, scale: float) -> float:
    """The share of rays or points on which rayaccel's answer is Embree's: the same set of triangles
    hit, the same first triangle, the same verdict, the same distance (to 1e-9 of the mesh's size),
    the same sign."""
    if call.startswith("intersects_location"):
        def per_ray(answer):
            keys = answer[1] * (1 << 32) + answer[2]
            order = np.argsort(keys)
            return np.split(keys[order], np.searchsorted(answer[1][order], np.arange(1, n)))
        return float(np.mean([np.array_equal(a, b) for a, b in zip(per_ray(ours), per_ray(theirs))]))
    if call == "nearest.on_surface":
        return float(np.mean(np.abs(ours[1] - theirs[1]) <= 1e-9 * scale))
    if call == "nearest.signed_distance":
        return float(np.mean(np.sign(ours) == np.sign(theirs)))
    return float(np.mean(ours == theirs))


@dataclass
class Result:
    """One call on one input set: medians of seconds per subject, ``(first, repeat)``."""

    scene: str
    inputs: str
    call: str
    n: int
    seconds: dict[str, tuple[float, float]] = field(default_factory=dict)
    numpy_n: int = 0
    agree: float = float("nan")

    def speedup(self, which: int) -> float:
        return self.seconds["Embree"][which] / self.seconds["rayaccel"][which]

    def rate(self, subject: str, which: int) -> float:
        return (self.numpy_n if subject == "numpy" else self.n) / self.seconds[subject][which]


def subset(data, k: int):
    """``k`` evenly spaced rays ``(origins, directions)`` or points of ``data``."""
    if isinstance(data, tuple):
        return tuple(subset(array, k) for array in data)
    return np.ascontiguousarray(data[::max(1, len(data) // k)][:k])


def bench_scene(name: str, args, subjects: list[str], console: Console) -> list[Result]:
    import trimesh

    scene = ra.load_scene(name)
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
    points = query_points(scene, args.points)
    inputs = {"camera rays": primary_rays(scene, args.side), "incoherent rays": incoherent_rays(scene, args.side ** 2)}
    jobs = [(label, call, data) for label, data in inputs.items() for call in RAY_CALLS]
    jobs.append(("points", "contains_points", points))
    jobs += [("points", call, subset(points, args.proximity_points)) for call in POINT_CALLS[1:]]
    results = [Result(name, label, call, len(data[0]) if isinstance(data, tuple) else len(data))
               for label, call, data in jobs]
    times = {(k, s): [] for k in range(len(jobs)) for s in subjects}
    answers = {}
    builders = {s: engines(s, args.method) for s in subjects}
    for round_ in range(args.rounds):
        for k, (_, call, data) in enumerate(jobs):
            for subject in subjects:
                given = data
                if subject == "numpy":
                    if round_:
                        continue
                    given = subset(data, args.numpy_rays)
                    results[k].numpy_n = len(given[0]) if isinstance(given, tuple) else len(given)
                fresh = mesh.copy()
                make_ray, make_nearest = builders[subject]
                fresh.ray, fresh.nearest = make_ray(fresh), make_nearest(fresh)
                start = time.perf_counter()
                answer = run_call(call, fresh, given)
                first = time.perf_counter() - start
                start = time.perf_counter()
                run_call(call, fresh, given)
                times[k, subject].append((first, time.perf_counter() - start))
                if round_ == 0:
                    answers[k, subject] = answer
        console.print(f"{name}: round {round_ + 1} of {args.rounds} done, load average {os.getloadavg()[0]:.1f}")
    for k, result in enumerate(results):
        for subject in subjects:
            seconds = np.array(times[k, subject])
            result.seconds[subject] = (float(np.median(seconds[:, 0])), float(np.median(seconds[:, 1])))
        if "Embree" in subjects:
            result.agree = agreement(result.call, answers[k, "rayaccel"], answers[k, "Embree"], result.n, mesh.scale)
    return results


def _rate(value: float) -> str:
    return f"{value / 1e6:.3g} M/s" if value >= 1e5 else f"{value / 1e3:.3g} k/s" if value >= 100 else f"{value:.3g}/s"


def table_rows(results: list[Result], subjects: list[str]) -> tuple[list[str], list[list[str]]]:
    header = ["scene", "input", "call", "n", "Embree first s", "rayaccel first s", "x Embree first",
              "Embree repeat s", "rayaccel repeat s", "x Embree repeat", "agree"]
    if "numpy" in subjects:
        header += ["numpy n", "numpy first rate", "numpy repeat rate", "rayaccel repeat rate"]
    rows = []
    for r in results:
        row = [r.scene, r.inputs, r.call, f"{r.n:,}"]
        for which in (0, 1):
            row += [f"{r.seconds['Embree'][which]:.3f}", f"{r.seconds['rayaccel'][which]:.3f}",
                    f"**{r.speedup(which):.2f}**"]
        row.append(f"{r.agree:.2%}")
        if "numpy" in subjects:
            row += [f"{r.numpy_n:,}", _rate(r.rate("numpy", 0)), _rate(r.rate("numpy", 1)),
                    _rate(r.rate("rayaccel", 1))]
        rows.append(row)
    return header, rows


def environment(load_start: tuple, load_end: tuple, args) -> list[str]:
    versions = []
    for package in ("rayaccel", "trimesh", "embreex", "rtree", "scipy", "numpy", "numba"):
        try:
            versions.append(f"{package} {importlib.metadata.version(package)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{package} not installed")
    try:
        with open("/proc/cpuinfo") as info:
            cpu = next(line.split(":", 1)[1].strip() for line in info if line.startswith("model name"))
    except (OSError, StopIteration):
        cpu = platform.processor() or "unknown CPU"
    return [f"date: {datetime.datetime.now().astimezone().isoformat(timespec='minutes')}",
            f"machine: {cpu}, {os.cpu_count()} cores; load average (1, 5, 15 min) at the start "
            f"{', '.join(f'{x:.1f}' for x in load_start)}, at the end {', '.join(f'{x:.1f}' for x in load_end)}",
            f"Python {platform.python_version()}; " + ", ".join(versions),
            f"rayaccel method {args.method}; medians of {args.rounds} interleaved rounds (Embree, rayaccel); "
            f"numpy engine timed once on {args.numpy_rays} evenly spaced rays or points of each call"]


def plot(results: list[Result], path: Path) -> None:
    """Grouped bars: rayaccel's speed-up over trimesh's Embree engine per call, first and repeated."""
    from rayaccel.experiments._report import new_figure, save_figure

    scenes = list(dict.fromkeys(r.scene for r in results))
    fig, axes = new_figure(len(scenes), width=7.5, height=4.8)
    for ax, scene in zip(axes, scenes):
        rows = [r for r in results if r.scene == scene]
        x = np.arange(len(rows))
        for which, (label, color) in enumerate([("first call (build included)", "C0"), ("repeated call", "C1")]):
            ax.bar(x - 0.2 + 0.4 * which, [r.speedup(which) for r in rows], 0.4, label=label, color=color)
        ax.axhline(1.0, color="black", linewidth=1)
        ax.set_yscale("log")
        labels = [f"{r.call.replace('intersects_location', 'location')}\n{r.inputs}" for r in rows]
        ax.set_xticks(x, labels, rotation=55, ha="right", fontsize=7)
        ax.set(ylabel="x trimesh's Embree engine (time ratio)", title=f"{scene}")
        ax.grid(axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=8)
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=["bunny", "dragon"])
    parser.add_argument("--side", type=int, default=512, help="side x side camera rays, as many incoherent ones")
    parser.add_argument("--points", type=int, default=65_536, help="points of contains_points")
    parser.add_argument("--proximity-points", type=int, default=1024, help="points of on_surface, signed_distance")
    parser.add_argument("--numpy-rays", type=int, default=32, help="rays or points the numpy engine is timed on")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--method", default="bvh-binned")
    parser.add_argument("--no-numpy", action="store_true", help="leave trimesh's numpy engine out")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args()
    console = Console(width=240)
    subjects = ["Embree", "rayaccel"] + ([] if args.no_numpy else ["numpy"])
    for name, needed_by in (("embreex", "trimesh's Embree engine"), ("rtree", "trimesh's proximity and numpy engine")):
        problem = import_problem(name)
        if problem:
            console.print(f"MISSING: {name} ({needed_by}) cannot run here: {problem[0]}; install it with "
                          f"pip install {name}", style="bold red", markup=False)
            raise SystemExit(1)
    load_start = os.getloadavg()
    results = []
    for name in args.scenes:
        results += bench_scene(name, args, subjects, console)
    load_end = os.getloadavg()
    header, rows = table_rows(results, subjects)
    table = Table(title="trimesh's calls: trimesh's Embree engine vs rayaccel (x Embree = Embree's time / rayaccel's)")
    for k, column in enumerate(header):
        table.add_column(column, justify="left" if k < 3 else "right")
    for row in rows:
        table.add_row(*(cell.replace("**", "") for cell in row))
    console.print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    chart = args.out / "bench_trimesh.png"
    plot(results, chart)
    lines = ["# trimesh's calls on trimesh's engines and on rayaccel", "",
             *(f"- {item}" for item in environment(load_start, load_end, args)), "",
             f"![speed-up over trimesh's Embree engine]({chart.name})", "",
             "| " + " | ".join(header) + " |", "|" + "|".join([":---"] * 3 + ["---:"] * (len(header) - 3)) + "|",
             *("| " + " | ".join(row) + " |" for row in rows), ""]
    (args.out / "bench_trimesh.md").write_text("\n".join(lines))
    console.print(f"wrote {args.out / 'bench_trimesh.md'} and {chart}")


if __name__ == "__main__":
    main()
