"""First use on an empty Numba cache: how long a new user waits, and which kernels it is spent on.

Each measurement runs in a fresh Python process whose ``NUMBA_CACHE_DIR`` points at an
empty temporary folder, and times, one after the other:

    import      ``import rayaccel``
    scene       ``ra.load_scene("bunny")`` (reading the mesh; no kernel of ours)
    build       the first ``ra.build(scene, METHOD)``
    intersect   the first ``accel.intersect`` of ``--rays`` rays
    occluded    the first ``accel.occluded`` of the same rays

Each step is reported as wall time and as CPU time of the process
(``time.process_time``). Compilation runs on one thread, so on this shared 2-core machine
the CPU time is the robust figure; the wall time grows with the load average, which is
printed before and after. ``--warm`` runs the same steps once more on the now filled
cache (what every later run of the user's script costs).

Per kernel: Numba announces every compilation that misses the cache as a
``numba:compile`` event (``numba.core.event``); the child records their start and end,
and each kernel's *own* time is its events' total minus the compilations nested inside
them (a caller's type inference compiles its callees first). Kernels inlined at
Numba's IR level (``inline="always"``) are typed and compiled inside their callers, so
their cost shows up in the caller's row. The signatures column counts the type
specialisations compiled per kernel.

    python benchmarks/bench_compile.py [--method bvh-binned] [--rays 1000] [--repeat 1] [--warm]
                                       [--until build] [--src src] [--top 25] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STEPS = ("import", "scene", "build", "intersect", "occluded")


def _name(event) -> str:
    """The module and name of the Python function behind a compile event's dispatcher."""
    function = event.data["dispatcher"].py_func
    return f"{function.__module__}.{function.__qualname__}".removeprefix("rayaccel.")


def _child(method: str, n_rays: int, until: str) -> dict:
    """The measured steps, in this (fresh) process; returns the figures as a dict."""
    import numba.core.event as ev

    open_events = []
    kernels = {}

    class Recorder(ev.Listener):
        def on_start(self, event):
            open_events.append([time.perf_counter(), 0.0, _name(event)])

        def on_end(self, event):
            started, nested, name = open_events.pop()
            total = time.perf_counter() - started
            if open_events:
                open_events[-1][1] += total
            entry = kernels.setdefault(name, {"seconds": 0.0, "signatures": 0, "step": current[0],
                                              "caller": open_events[-1][2] if open_events else ""})
            entry["seconds"] += total - nested
            entry["signatures"] += 1

    ev.register("numba:compile", Recorder())
    steps = {}
    current = [None]

    def timed(step, run):
        current[0] = step
        wall, cpu = time.perf_counter(), time.process_time()
        value = run()
        steps[step] = {"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu}
        return value

    ra = timed("import", lambda: __import__("rayaccel"))
    import numpy as np

    scene = timed("scene", lambda: ra.load_scene("bunny"))
    accel = timed("build", lambda: ra.build(scene, method))
    rng = np.random.default_rng(0)
    lo, hi = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    centre, radius = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    toward = rng.normal(size=(n_rays, 3))
    origins = centre + radius * toward / np.linalg.norm(toward, axis=1, keepdims=True)
    directions = rng.uniform(lo, hi, size=(n_rays, 3)) - origins
    hits = None
    if until != "build":
        hits = timed("intersect", lambda: accel.intersect(origins, directions))
        timed("occluded", lambda: accel.occluded(origins, directions))
    for step in STEPS:
        steps.setdefault(step, {"wall": 0.0, "cpu": 0.0})
    return {"steps": steps, "kernels": kernels, "hit_fraction": float(np.isfinite(hits.t).mean()) if hits else 0.0}


def _measure(src: Path, method: str, n_rays: int, until: str, cache: str) -> dict:
    """One child process on the Numba cache folder ``cache``; its figures and the load averages."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(src))
    load_before = os.getloadavg()[0]
    run = subprocess.run([sys.executable, __file__, "--child", "--method", method, "--rays", str(n_rays),
                          "--until", until],
                         env=env, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(f"the measuring process failed:\n{run.stderr}")
    result = json.loads(run.stdout.strip().splitlines()[-1])
    result["load"] = (load_before, os.getloadavg()[0])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--method", default="bvh-binned")
    parser.add_argument("--rays", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=1, help="empty-cache measurements, one after the other")
    parser.add_argument("--warm", action="store_true", help="measure once more on the filled cache")
    parser.add_argument("--src", type=Path, default=ROOT / "src", help="the folder holding the rayaccel package")
    parser.add_argument("--top", type=int, default=25, help="kernels listed, dearest first")
    parser.add_argument("--json", type=Path, help="also write every figure here")
    parser.add_argument("--until", choices=["build", "occluded"], default="occluded",
                        help="stop after this step (build: skip the queries, to iterate on the builders)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(args.method, args.rays, args.until)))
        return

    from rich.console import Console
    from rich.table import Table

    console = Console(width=200)
    src = args.src.resolve()
    console.print(f"[bold]first use of {args.method}[/] on the bunny, {args.rays:,} rays, package from {src}")
    cold, warm = [], None
    for k in range(args.repeat):
        with tempfile.TemporaryDirectory(prefix="rayaccel-numba-") as cache:
            with console.status(f"empty cache, run {k + 1} of {args.repeat} ..."):
                cold.append(_measure(src, args.method, args.rays, args.until, cache))
            if args.warm and k == args.repeat - 1:
                with console.status("warm cache ..."):
                    warm = _measure(src, args.method, args.rays, args.until, cache)

    table = Table(title=f"first use, seconds (median of {len(cold)} empty-cache run(s))")
    table.add_column("step")
    for label in ("wall", "CPU"):
        table.add_column(f"empty cache {label}", justify="right")
    if warm:
        table.add_column("warm wall", justify="right")
        table.add_column("warm CPU", justify="right")
    for step in (*STEPS, "total"):
        def figure(result, kind, step=step):
            if step == "total":
                return sum(result["steps"][s][kind] for s in STEPS)
            return result["steps"][step][kind]
        row = [step] + [f"{statistics.median(figure(r, kind) for r in cold):.2f}" for kind in ("wall", "cpu")]
        if warm:
            row += [f"{figure(warm, 'wall'):.2f}", f"{figure(warm, 'cpu'):.2f}"]
        table.add_row(*row, style="bold" if step == "total" else None)
    console.print(table)
    loads = ", ".join(f"{r['load'][0]:.2f} -> {r['load'][1]:.2f}" for r in cold)
    console.print(f"load average (1 min) before -> after each empty-cache run: {loads}; "
                  f"rays hitting: {cold[0]['hit_fraction']:.0%}")

    kernels = cold[0]["kernels"]
    table = Table(title=f"kernels compiled in the first empty-cache run: {len(kernels)}, "
                        f"{sum(k['signatures'] for k in kernels.values())} signatures, "
                        f"{sum(k['seconds'] for k in kernels.values()):.1f} s of own compile time (wall)")
    for column in ("kernel", "first needed by", "first caller", "signatures", "own seconds", "share"):
        table.add_column(column, justify="left" if column == "kernel" else "right")
    total = sum(k["seconds"] for k in kernels.values()) or 1.0
    ranked = sorted(kernels.items(), key=lambda item: -item[1]["seconds"])
    for name, entry in ranked[:args.top]:
        table.add_row(name, entry["step"], entry["caller"], str(entry["signatures"]),
                      f"{entry['seconds']:.2f}", f"{entry['seconds'] / total:.0%}")
    rest = ranked[args.top:]
    if rest:
        table.add_row(f"{len(rest)} more", "", "", str(sum(e["signatures"] for _, e in rest)),
                      f"{sum(e['seconds'] for _, e in rest):.2f}", f"{sum(e['seconds'] for _, e in rest) / total:.0%}")
    console.print(table)
    by_step = {step: sum(e["seconds"] for e in kernels.values() if e["step"] == step) for step in STEPS}
    console.print("own compile time by step: " + ", ".join(f"{step} {s:.1f} s" for step, s in by_step.items()))
    if args.json:
        args.json.write_text(json.dumps({"method": args.method, "rays": args.rays, "cold": cold, "warm": warm},
                                        indent=1))


if __name__ == "__main__":
    main()
