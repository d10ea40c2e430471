"""Time per call against the peers, from one ray to tens of thousands: what a caller pays who traces
a few rays at a time (a robot's sensor, an interactive picker, a renderer's next bounce of a tile).

``bench_structures.py`` measures throughput on a million rays, where a call's fixed cost vanishes.
Here the batch sizes run from 1 to 65,536 rays, camera rays (consecutive pixels of a 1024^2 image,
one origin) and incoherent rays (origins in the scene's box, directions on the sphere), closest and
any hit, on one scene. Each subject traces a cycle of distinct batches of each size in a loop (up to
64 batches, about 2^17 rays a loop, at least 8 calls); a figure is the loop's time over its calls,
the median of ``--rounds`` interleaved rounds, after a pause and a first untimed call (as
``_common.settled_seconds``). Subjects: rayaccel's default BVH, Embree through embreex on one
thread and on the rays split over two Python threads, Open3D's ``RaycastingScene`` and Mitsuba 3
(the faster of ``coherent=False`` and ``True``). Results: a markdown table of microseconds a call and
the peers' time over rayaccel's, and a chart of time per call against batch size.

    python benchmarks/bench_batch_size.py [--scene forest-small-chair] [--rounds 5]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _common import ROOT, SETTLE_SECONDS, ensure_competitors, incoherent_rays, primary_rays, scene_every_subject_traces
from bench_structures import environment, markdown_table, rich_table
from peers import EmbreePeer, MitsubaPeer, Open3dPeer, RayaccelSubject, RaySet
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

SIZES = (1, 16, 256, 4096, 65536)
QUERIES = ("closest", "any")
RAYS_PER_LOOP = 1 << 17
MAX_BATCHES = 64
MIN_CALLS = 8


def batches(kind: str, scene, size: int) -> list[RaySet]:
    """Distinct batches of ``size`` rays of ``kind``: camera batches are runs of consecutive pixels
    from the middle of a 1024^2 image on, incoherent ones consecutive slices of one random set."""
    count = max(1, min(MAX_BATCHES, RAYS_PER_LOOP // size))
    if kind == "camera":
        origins, directions = primary_rays(scene, 1024)
        start = len(directions) // 2 - count * size // 2
        return [RaySet(origins[:size], directions[start + k * size:start + (k + 1) * size]) for k in range(count)]
    origins, directions = incoherent_rays(scene, count * size)
    return [RaySet(origins[k * size:(k + 1) * size], directions[k * size:(k + 1) * size]) for k in range(count)]


def seconds_per_call(query, prepared: list) -> float:
    """Wall time of one call, from a settled loop over the prepared batches."""
    calls = max(MIN_CALLS, len(prepared))
    time.sleep(SETTLE_SECONDS)
    query(prepared[0])
    start = time.perf_counter()
    for k in range(calls):
        query(prepared[k % len(prepared)])
    return (time.perf_counter() - start) / calls


def subjects_for(mesh, competitors: set[str]) -> list:
    subjects = [RayaccelSubject(mesh, "bvh-binned")]
    if "embreex" in competitors:
        one = EmbreePeer(mesh, threads=1)
        subjects += [one, one.with_threads(2)]
    if "open3d" in competitors:
        subjects.append(Open3dPeer(mesh))
    if "mitsuba" in competitors:
        mitsuba = MitsubaPeer(mesh)
        subjects += [mitsuba, mitsuba.with_coherent(True)]
    return subjects


def measure(mesh, subjects: list, rounds: int, progress: Progress) -> dict:
    """``{(kind, size, query): {label: seconds a call}}``, the variants of a peer merged to the fastest."""
    cells = [(kind, size, query) for kind in ("camera", "incoherent") for size in SIZES for query in QUERIES]
    task = progress.add_task("timing calls", total=len(cells) * rounds)
    times: dict = {}
    for kind in ("camera", "incoherent"):
        for size in SIZES:
            sets = batches(kind, mesh, size)
            prepared = [[subject.prepare(rays) for rays in sets] for subject in subjects]
            for query in QUERIES:
                samples = [[] for _ in subjects]
                for _ in range(rounds):
                    for k, subject in enumerate(subjects):
                        call = subject.closest if query == "closest" else subject.any_hit
                        samples[k].append(seconds_per_call(call, prepared[k]))
                    progress.advance(task)
                merged: dict = {}
                for subject, values in zip(subjects, samples):
                    label = subject.group or subject.label
                    merged[label] = min(merged.get(label, np.inf), float(np.median(values)))
                times[kind, size, query] = merged
    progress.remove_task(task)
    return times


def table(times: dict, labels: list[str], ours: str) -> tuple[str, list[str], list[list[str]]]:
    header = ["rays", "batch", "query", *(f"{label} us" for label in labels), "best peer / rayaccel"]
    rows = []
    for (kind, size, query), cell in times.items():
        best_peer = min((seconds for label, seconds in cell.items() if label != ours), default=None)
        ratio = "no peer" if best_peer is None else f"{best_peer / cell[ours]:.2f}"
        rows.append([kind, f"{size:,}", query, *(f"{cell[label] * 1e6:,.1f}" for label in labels), ratio])
    return "microseconds a call (speed ratio: above 1, rayaccel is faster)", header, rows


def plot(times: dict, labels: list[str], scene_name: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(13, 9), sharex=True)
    for ax, (kind, query) in zip(axes.ravel(), [(k, q) for k in ("camera", "incoherent") for q in QUERIES]):
        for label in labels:
            ax.plot(SIZES, [times[kind, size, query][label] * 1e6 for size in SIZES], marker="o", label=label,
                    linewidth=2.5 if label.startswith("rayaccel") else 1.2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{kind} rays, {query} hit")
        ax.set_xlabel("rays a call")
        ax.set_ylabel("microseconds a call")
        ax.grid(which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Time per call against batch size, {scene_name}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="forest-small-chair")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results",
                        help="folder for bench_batch_size.md and bench_batch_size.png")
    args = parser.parse_args()
    console = Console(width=200)
    competitors = ensure_competitors(console)
    mesh = scene_every_subject_traces(args.scene)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        subjects = subjects_for(mesh, competitors)
        times = measure(mesh, subjects, args.rounds, progress)
    labels = list(dict.fromkeys(subject.group or subject.label for subject in subjects))
    ours = subjects[0].label
    title, header, rows = table(times, labels, ours)
    console.print(rich_table(title, header, rows))
    args.out.mkdir(parents=True, exist_ok=True)
    chart = args.out / "bench_batch_size.png"
    plot(times, labels, args.scene, chart)
    lines = [f"# Time per call against batch size: {args.scene}", "", *(f"- {item}" for item in environment()),
             f"- medians of {args.rounds} interleaved rounds; a round times each subject's loop of calls", "",
             f"![time per call]({chart.name})", "", markdown_table(title, header, rows)]
    (args.out / "bench_batch_size.md").write_text("\n".join(lines))
    console.print(f"wrote {args.out / 'bench_batch_size.md'} and {chart}")


if __name__ == "__main__":
    main()
