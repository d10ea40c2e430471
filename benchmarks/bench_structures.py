"""rayaccel's structures against the ray tracers a Python user would reach for, same rays, same run.

Subjects
    rayaccel, one row per method (``--methods``), plus the first method whose walk is
    sorted (the eight-wide BVH's is not) with its rays traced as given (``reorder=False``),
    to show what rayaccel's ray sort adds, and the first method given the rays in float32,
    as the peers get them (its other rows take the float64 rays, twice the bytes to read:
    forest camera rays, one thread, two runs, 1.06-1.07 times as fast closest and 1.03-1.14
    any hit in float32);
    Embree 4 through embreex, on one thread, and with the rays split over as many
    Python threads as the machine has cores (embreex releases the GIL);
    Open3D's ``RaycastingScene`` (``cast_rays``, ``test_occlusions``), on all cores;
    Mitsuba 3, variant ``llvm_ad_rgb`` (``ray_intersect_preliminary``, ``ray_test``),
    on Dr.Jit's thread pool. Mitsuba is timed with ``coherent=False`` and with
    ``coherent=True`` and each column keeps the faster of the two (the report says
    which). Its timed calls evaluate the lazy Dr.Jit result and copy it out to NumPy.

Columns: closest hit and any hit on three ray sets:
    primary     ``side`` x ``side`` pinhole-camera rays framing the scene;
    incoherent  as many rays with origins uniform in the scene box and uniform directions;
    shadow      one ray from every primary hit point toward a point light, direction
                ``light - hit`` so that the light is at t = 1, searched over
                [1e-4, 1] (``SHADOW_T_MIN``). The light is the framing camera's eye
                raised along +y by the radius of the scene's bounding sphere, so above
                and in front of the scene. The hit points come from the first
                rayaccel method, in float64.

Intervals: rayaccel takes ``t_min``/``t_max`` per ray. None of the peers takes a t_min
(Mitsuba 3's rays have only ``maxt``; embreex fixes tnear at 0; Open3D's ``cast_rays``
has neither), so every peer gets the same shadow segment as origin ``hit + 1e-4 *
direction`` and t_max ``1 - 1e-4``: embreex's ``dists``, Mitsuba's ``maxt``, Open3D's
``tfar`` for ``test_occlusions``; Open3D's ``cast_rays`` cannot stop at t_max, so its
hits beyond it are dropped afterwards, inside the timed call.

Fairness: rays are converted into each subject's own input format (float32 arrays,
Open3D tensors, Dr.Jit arrays) before timing; every timed call returns NumPy arrays.
The camera's rays, which share one origin, are given as that one origin to the subjects
whose API takes one (rayaccel: a (1, 3) array; Mitsuba 3: a scalar ``Point3f``), as a user
would pass them; Embree and Open3D take an origin per ray. Given one origin, Mitsuba's
camera queries on the forest and the full dragon took 0.98-1.00 of their time with an
origin per ray (medians of 8, one process, alternating).
Every figure is the median of ``ROUNDS`` rounds in which all subjects take turns at
every query, so that all of them meet the same phases of a noisy machine: read the
ratios (to the best peer of each column, and to Embree on all cores), not the
absolute figures. Each timed call follows a pause and an untimed call of the same query
(``_common.settled_seconds``): no peer's thread pool still spins while the next subject is
timed, and each subject meets its query warm, as in a loop of its own. Each subject's
answers are compared with the first rayaccel method's (same primitive for closest hit,
same verdict for any hit; the peers trace in float32). Every subject traces the same
triangles: a scene whose vertices are not float32 numbers (the procedural forest) is
rounded to float32 first, as the peers store it (``_common.scene_every_subject_traces``).

    python benchmarks/bench_structures.py [--scenes dragon forest-small-chair] [--methods bvh-binned kdtree]
                                          [--side 1024] [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import platform
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

sys.path.insert(0, str(Path(__file__).parent))
from _common import (  # noqa: E402
    ROOT,
    ensure_competitors,
    incoherent_rays,
    light_position,
    primary_rays,
    scene_every_subject_traces,
    settled_seconds,
    shadow_rays,
)
from peers import (  # noqa: E402
    BUILD_REPEATS,
    CORES,
    EmbreePeer,
    MitsubaPeer,
    Open3dPeer,
    RayaccelSubject,
    RaySet,
    Subject,
    interleaved_build_seconds,
)

ROUNDS = 5  # timing rounds; each figure is the median
SHADOW_T_MIN = 1e-4  # in units of light - hit: a relative epsilon
RAY_SETS = ("primary", "incoherent", "shadow")
QUERIES = ("closest", "any")
COLUMNS = tuple(f"{rays} {query}" for query in QUERIES for rays in RAY_SETS)
DEFAULT_METHODS = ["bvh-binned", "bvh-sah", "bvh-lbvh", "kdtree", "grid-bvh", "octree", "hgrid", "grid"]


@dataclass
class Row:
    """One subject's figures in one scene, per column: Mrays/s, and the number of rays whose answer
    differs from the reference's."""

    label: str
    short: str
    is_peer: bool
    is_baseline: bool
    build: float
    rates: dict[str, float] = field(default_factory=dict)
    differ: dict[str, int] = field(default_factory=dict)
    note: str = ""


@dataclass
class SceneResult:
    name: str
    triangles: int
    ray_counts: dict[str, int]
    hit_share: dict[str, float]  # per column
    rows: list[Row]

    def best_peer(self, column: str) -> Row | None:
        peers = [row for row in self.rows if row.is_peer]
        return max(peers, key=lambda row: row.rates[column]) if peers else None

    def embree_all_cores(self) -> Row | None:
        return next((row for row in self.rows if row.is_baseline), None)


def build_subjects(scene, methods: list[str], competitors: set[str], progress: Progress) -> list[Subject]:
    """rayaccel's structures, the as-given row and every available peer, each built; then every
    build timed again in interleaved rounds (:func:`peers.interleaved_build_seconds`)."""
    makers = [(f"rayaccel {m}", lambda m=m: [RayaccelSubject(scene, m)]) for m in methods]
    if "embreex" in competitors:
        makers.append(("Embree", lambda: [(e := EmbreePeer(scene)), *([e.with_threads(CORES)] * (CORES > 1))]))
    if "open3d" in competitors:
        makers.append(("Open3D", lambda: [Open3dPeer(scene)]))
    if "mitsuba" in competitors:
        makers.append(("Mitsuba 3", lambda: [(m := MitsubaPeer(scene)), m.with_coherent(True)]))
    task = progress.add_task("building", total=len(makers))
    subjects = []
    for label, make in makers:
        progress.update(task, description=f"building {label}")
        subjects += make()
        progress.advance(task)
    sorted_ones = [s for s in subjects[:len(methods)] if s.accel._walk_gains_from_sorting]
    if sorted_ones:
        first = sorted_ones[0]
        subjects.insert(len(methods), first.variant(f"{first.label}, rays as given", reorder=False))
    subjects.insert(1, subjects[0].variant(f"{subjects[0].label}, float32 rays", float32=True))
    progress.update(task, description=f"timing the builds, {BUILD_REPEATS} interleaved rounds")
    makes = list({id(s.make): s.make for s in subjects}.values())
    for make, seconds in zip(makes, interleaved_build_seconds(makes)):
        for subject in subjects:
            if subject.make is make:
                subject.build_seconds = seconds
    progress.remove_task(task)
    return subjects


def ray_sets(scene, side: int, reference: RayaccelSubject) -> dict[str, RaySet]:
    """The three ray sets; the shadow rays start at the reference's primary hits."""
    primary = RaySet(*primary_rays(scene, side))
    incoherent = RaySet(*incoherent_rays(scene, side * side))
    t_hit = reference.accel.intersect(primary.origins, primary.directions).t
    shadow = RaySet(*shadow_rays(primary.origins, primary.directions, t_hit, light_position(scene)),
                    t_min=SHADOW_T_MIN, t_max=1.0)
    return {"primary": primary, "incoherent": incoherent, "shadow": shadow}


def _calls(subjects: list[Subject], rays: dict[str, RaySet]) -> list[tuple[int, str, object]]:
    """``(subject index, column, call)`` for every query of every subject, inputs prepared."""
    calls = []
    for i, subject in enumerate(subjects):
        for set_name in RAY_SETS:
            prepared = subject.prepare(rays[set_name])
            calls.append((i, f"{set_name} closest", lambda s=subject, p=prepared: s.closest(p)))
            calls.append((i, f"{set_name} any", lambda s=subject, p=prepared: s.any_hit(p)))
    return calls


def measure(subjects: list[Subject], rays: dict[str, RaySet], scene_name: str,
            progress: Progress) -> tuple[list[Row], dict[str, float]]:
    """Every subject's Mrays/s per column, the median of ``ROUNDS`` interleaved rounds after one
    warm-up round whose answers are compared with the first subject's; and the share of rays
    that hit something per column, by the first subject's answers."""
    calls = _calls(subjects, rays)
    rows = [Row(s.label, s.short, s.is_peer, s.is_baseline, s.build_seconds) for s in subjects]
    seconds = {(i, column): [] for i, column, _ in calls}
    reference = {}
    task = progress.add_task(scene_name, total=len(calls) * (ROUNDS + 1))
    for round_ in range(ROUNDS + 1):
        phase = "warm-up" if round_ == 0 else f"round {round_}/{ROUNDS}"
        for i, column, call in calls:
            progress.update(task, description=f"{scene_name} {phase}: {subjects[i].label}, {column}")
            if round_ == 0:
                expected = reference.setdefault(column, answer := call())
                rows[i].differ[column] = int(np.count_nonzero(np.asarray(answer) != expected))
            else:
                seconds[i, column].append(settled_seconds(call))
            progress.advance(task)
    progress.remove_task(task)
    for (i, column), times in seconds.items():
        rows[i].rates[column] = len(rays[column.split()[0]]) / float(np.median(times)) / 1e6
    hit_share = {column: float(np.mean(np.asarray(answer) >= 0 if "closest" in column else answer))
                 for column, answer in reference.items()}
    return _merge_variants(rows, subjects), hit_share


def _merge_variants(rows: list[Row], subjects: list[Subject]) -> list[Row]:
    """One row per group of variants (Mitsuba's coherent hint): the fastest variant per column,
    with a note naming it."""
    merged, groups = [], {}
    for row, subject in zip(rows, subjects):
        if subject.group is None:
            merged.append(row)
        else:
            groups.setdefault(subject.group, []).append(row)
            if len(groups[subject.group]) == 1:
                merged.append(Row(subject.group, subject.short, row.is_peer, row.is_baseline, row.build))
    for group, variants in groups.items():
        row = next(r for r in merged if r.label == group)
        winners = []
        for column in COLUMNS:
            best = max(variants, key=lambda r: r.rates[column])
            row.rates[column], row.differ[column] = best.rates[column], best.differ[column]
            winners.append(f"{column}: {best.label.removeprefix(group).strip(', ')}")
        others = "; ".join(f"{v.label.removeprefix(group).strip(', ')} " + ", ".join(
            f"{v.rates[c]:.3g}" for c in COLUMNS) for v in variants)
        row.note = f"faster variant per column: {'; '.join(winners)}. Mrays/s of each variant: {others}"
    return merged


def bench_scene(name: str, methods: list[str], side: int, competitors: set[str], progress: Progress) -> SceneResult:
    task = progress.add_task(f"loading {name}", total=None)
    scene = scene_every_subject_traces(name)
    progress.remove_task(task)
    subjects = build_subjects(scene, methods, competitors, progress)
    rays = ray_sets(scene, side, subjects[0])
    rows, hit_share = measure(subjects, rays, name, progress)
    return SceneResult(name, len(scene.faces), {k: len(v) for k, v in rays.items()}, hit_share, rows)


def _ratio_rows(result: SceneResult, baseline) -> list[list[str]]:
    """Each row's Mrays/s over ``baseline(column)``'s, per column."""
    rows = []
    for row in result.rows:
        cells = []
        for column in COLUMNS:
            base = baseline(column)
            cells.append(f"{row.rates[column] / base.rates[column]:.3g}" if base else "-")
        rows.append([row.label, *cells])
    return rows


def _agreement(differ: int, n: int) -> str:
    """The share of ``n`` answers that agree, and how many differ."""
    return f"{1 - differ / n:.3%} ({differ:,} differ)" if differ else "100% (all)"


def scene_tables(result: SceneResult) -> list[tuple[str, list[str], list[list[str]]]]:
    """``(title, header, rows)`` of the scene's tables: throughput, the two ratios, agreement."""
    header = ["subject", *COLUMNS]
    counts = ", ".join(f"{n:,} {k}" for k, n in result.ray_counts.items())
    embree = result.embree_all_cores()
    tables = [(f"{result.name} ({result.triangles:,} triangles; {counts} rays): build s and Mrays/s",
               ["subject", "build s", *COLUMNS],
               [[r.label, f"{r.build:.3g}", *(f"{r.rates[c]:.3g}" for c in COLUMNS)] for r in result.rows])]
    if result.best_peer(COLUMNS[0]):
        best_names = ["(best peer)", *(result.best_peer(c).short for c in COLUMNS)]
        tables.append((f"{result.name}: Mrays/s relative to the best peer of each column", header,
                       [best_names, *_ratio_rows(result, result.best_peer)]))
    if embree:
        tables.append((f"{result.name}: Mrays/s relative to {embree.label}", header,
                       _ratio_rows(result, lambda column: embree)))
    agreement = (f"{result.name}: answers agreeing with {result.rows[0].label}'s (same primitive for closest hit, "
                 "same verdict for any hit)")
    hits = ["(rays that hit)", *(f"{result.hit_share[c]:.1%}" for c in COLUMNS)]
    tables.append((agreement, header, [hits] +
                   [[r.label, *(_agreement(r.differ[c], result.ray_counts[c.split()[0]]) for c in COLUMNS)]
                    for r in result.rows]))
    return tables


def rich_table(title: str, header: list[str], rows: list[list[str]]) -> Table:
    table = Table(title=title)
    for k, column in enumerate(header):
        table.add_column(column, justify="left" if k == 0 else "right")
    for row in rows:
        table.add_row(*row)
    return table


def markdown_table(title: str, header: list[str], rows: list[list[str]]) -> str:
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |",
             "|" + "|".join([":---"] + ["---:"] * (len(header) - 1)) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def environment() -> list[str]:
    """The machine, the library versions and the date, as markdown list items."""
    try:
        with open("/proc/cpuinfo") as info:
            cpu = next(line.split(":", 1)[1].strip() for line in info if line.startswith("model name"))
    except (OSError, StopIteration):
        cpu = platform.processor() or "unknown CPU"
    versions = []
    for package in ("rayaccel", "numpy", "numba", "embreex", "open3d", "mitsuba", "drjit", "matplotlib"):
        try:
            versions.append(f"{package} {importlib.metadata.version(package)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{package} not installed")
    import numba

    return [f"date: {datetime.datetime.now().astimezone().isoformat(timespec='minutes')}",
            f"machine: {cpu}, {CORES} cores ({platform.platform()}); Numba threads: {numba.config.NUMBA_NUM_THREADS}",
            f"Python {platform.python_version()}; " + ", ".join(versions)]


def write_markdown(results: list[SceneResult], competitors: set[str], path: Path, chart: str) -> None:
    from _common import COMPETITORS

    missing = [COMPETITORS[name] for name in COMPETITORS if name not in competitors]
    lines = ["# rayaccel against its peers", "", *(f"- {item}" for item in environment()),
             f"- {ROUNDS} interleaved rounds, medians; build: median of {BUILD_REPEATS} interleaved builds",
             (f"- shadow rays: from the primary hits toward a point light at the framing camera's eye raised by "
              f"the scene's bounding radius along +y, over t in [{SHADOW_T_MIN:g}, 1]; peers, which take no t_min, "
              "get origins moved by the epsilon"),
             f"- peers missing here: {', '.join(missing) if missing else 'none'}",
             "", f"![ratios to the best peer]({chart})", ""]
    for result in results:
        lines += [f"## {result.name}", ""]
        lines += [markdown_table(*table) for table in scene_tables(result)]
        lines += [f"- {row.label}: {row.note}" for row in result.rows if row.note] + [""]
    path.write_text("\n".join(lines))


def plot(results: list[SceneResult], path: Path) -> None:
    """Grouped bars of each subject's Mrays/s over the best peer's, per column, one panel per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator

    fig, axes = plt.subplots(len(results), 1, figsize=(16, 5 * len(results)), squeeze=False)
    for ax, result in zip(axes[:, 0], results):
        x = np.arange(len(COLUMNS))
        width = 0.85 / len(result.rows)
        ours = [r for r in result.rows if not r.is_peer]
        for k, row in enumerate(result.rows):
            ratios = [row.rates[c] / result.best_peer(c).rates[c] for c in COLUMNS]
            color = plt.cm.viridis(k / max(len(ours) - 1, 1)) if not row.is_peer else plt.cm.Reds(
                0.4 + 0.5 * (k - len(ours)) / max(len(result.rows) - len(ours) - 1, 1))
            ax.bar(x - 0.425 + (k + 0.5) * width, ratios, width, label=row.label, color=color,
                   hatch="//" if row.is_peer else None, edgecolor="white" if row.is_peer else None, linewidth=0)
        ax.axhline(1.0, color="black", linewidth=1)
        ax.set_yscale("log")
        ax.yaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
        for formatter in (ax.yaxis.set_major_formatter, ax.yaxis.set_minor_formatter):
            formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        ax.set_xticks(x, COLUMNS)
        ax.set_ylabel("Mrays/s / best peer's")
        ax.set_title(f"{result.name} ({result.triangles:,} triangles)")
        ax.grid(axis="y", which="both", alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.suptitle("rayaccel and its peers: throughput relative to the best peer of each column (1 = best peer)")
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=["dragon", "forest-small-chair"])
    parser.add_argument("--methods", nargs="+", default=DEFAULT_METHODS)
    parser.add_argument("--side", type=int, default=1024, help="primary rays are side x side; as many incoherent")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results",
                        help="folder for bench_structures.md and bench_structures.png")
    args = parser.parse_args()
    console = Console(width=220)
    competitors = ensure_competitors(console)
    results = []
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        for name in args.scenes:
            results.append(bench_scene(name, args.methods, args.side, competitors, progress))
            for table in scene_tables(results[-1]):
                progress.console.print(rich_table(*table))
            for row in results[-1].rows:
                if row.note:
                    progress.console.print(f"{row.label}: {row.note}")
    args.out.mkdir(parents=True, exist_ok=True)
    chart = args.out / "bench_structures.png"
    if competitors:
        plot(results, chart)
    write_markdown(results, competitors, args.out / "bench_structures.md", chart.name)
    console.print(f"wrote {args.out / 'bench_structures.md'}" + (f" and {chart}" if competitors else ""))


if __name__ == "__main__":
    main()
