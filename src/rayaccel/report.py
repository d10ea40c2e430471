"""One self-contained HTML page of every lecture experiment: ``rayaccel report``.

The page only assembles what the experiments write (:mod:`rayaccel.experiments.runner`): each
experiment's markdown table, converted to HTML by the ``markdown`` package, its chart, and the
further images it wrote (the renders and heatmaps of every structure on one scene, the BVH
builders' heatmaps); the peers' throughput table and chart of ``benchmarks/bench_structures.py``
when that benchmark has been run; and the machine, library versions and date of the run. Images
are inlined as base64 data URIs and the style sheet is inlined too, so the page needs no other
file and no network to be viewed; the experiments' own files are kept in a folder beside it.
"""

from __future__ import annotations

import base64
import datetime
import html
import importlib.metadata
import os
import platform
import re
import time
from pathlib import Path
from typing import NamedTuple

from .experiments import runner

__all__ = ["SECTIONS", "Section", "find_bench_results", "machine", "write_report"]

BENCH_COMMAND = "python benchmarks/bench_structures.py"


class Section(NamedTuple):
    """One experiment on the page: its runner name, heading, the lecture's claim and what we measured."""

    name: str
    title: str
    lecture: str
    measured: str


SECTIONS = (
    Section("grid-vs-none", "Grid vs no grid",
            "Without acceleration every ray tests every object, so the time of a frame grows with the number n of "
            "objects. A uniform grid of about 8 cells per object (λ = 8) makes it almost independent of n: the "
            "lecture's table grows only 1.9 times from 1,000 to 1,000,000 random spheres, 5.2 s at a million.",
            "n random spheres in the unit cube; the same frame (primary rays, one shadow ray per lit hit, shading) "
            "rendered through a grid of 8n cells, build included, and by brute force. Where brute force would take "
            "hours, a random subset of the pixels is rendered and the time scaled up (marked *)."),
    Section("grid-resolution", "Grid resolution and the cost model",
            "More cells mean fewer objects to test per cell but more cells to step through. A ray costs about "
            "C_c·R^(1/3) + C_i·n/R^(2/3) for R cells, least at R = 2·n·C_i/C_c; in practice about 8 cells per object.",
            "Grids of 1/4 to 64 cells per primitive (fewer in a quick run), timed on closest-hit primary rays, "
            "with the cost model's optimum from C_i and C_c calibrated on this machine (the band is its "
            "uncertainty), the fastest density measured, and the lecture's 8."),
    Section("kdtree-table", "The kd-tree table",
            "The lecture's kd-tree statistics on scanned meshes and forest scenes: leaves, triangles per "
            "non-empty leaf, construction time, the expected traversal steps, leaves visited and intersections "
            "per ray, and the nodes and intersections a ray really visits.",
            "The same rows with our SAH kd-tree on our scenes; the table says where our scenes and definitions "
            "differ from the lecture's."),
    Section("leaf-size", "Leaf size",
            "Splitting goes on until a leaf holds a fixed number of primitives, often between 2 and 8.",
            "The kd-tree's leaf_size and the binned-SAH BVH's max_leaf_size swept: build time, expected cost, "
            "time of the primary rays, nodes and tests per ray."),
    Section("bvh", "Which BVH is better?",
            "Builders trade construction time against the quality of the tree: the surface area heuristic (SAH) "
            "gives the best trees, median splits, Morton codes and clustering build faster or differently.",
            "Every BVH builder: build time, SAH cost, nodes, depth, nodes and tests per ray, and closest-hit and "
            "any-hit throughput on primary and incoherent rays; below, the nodes each builder visits per pixel "
            "(dark: few, bright: many)."),
    Section("bounding-volumes", "Cheap vs tight bounding volumes",
            "A volume that is cheap to test but loose lets rays into children they miss; a tight one costs more "
            "per test. By the surface-area (Cauchy–Crofton) argument, a ray that hits a convex parent hits a "
            "convex child with probability SA(child)/SA(parent).",
            "One binned-SAH tree with boxes, spheres (two fits) and 14-DOPs as node volumes: nanoseconds per "
            "ray-volume test, tightness, expected and measured nodes per ray, and trace time."),
    Section("structures", "Every structure on one scene",
            "No structure wins everywhere: a uniform grid suits evenly spread objects, while a scene with one "
            "dense object in a sparse one (a teapot in a stadium) needs a structure that adapts to it.",
            "Every structure but brute force on one scene: build time, expected cost, render time, nodes (or "
            "cells) and tests per ray; then each structure's render and its nodes or cells visited per pixel, "
            "from dark (few) to bright (many)."),
)

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 0; color: #1d232b;
       background: #f6f7f9; line-height: 1.5; }
main { max-width: 1180px; margin: 0 auto; padding: 1.5rem 2rem 4rem; background: #fff; }
h1 { font-size: 2rem; margin: 0.5rem 0 0.25rem; }
h2 { font-size: 1.45rem; margin-top: 2.5rem; padding-top: 0.5rem; border-top: 2px solid #d9dee5; }
h3 { font-size: 1.1rem; margin: 1.2rem 0 0.4rem; }
h4 { font-size: 1rem; margin: 1rem 0 0.3rem; }
.subtitle { color: #55606e; margin: 0 0 1rem; }
.banner { background: #fff4d6; border: 1px solid #e8c766; padding: 0.6rem 1rem; border-radius: 6px; }
.note { background: #eef3fb; border-left: 4px solid #5b8def; padding: 0.6rem 1rem; }
.claim { margin: 0.4rem 0; }
.claim b { color: #34495e; }
nav ol { columns: 2; padding-left: 1.4rem; }
.scroll { overflow-x: auto; margin: 0.6rem 0 1rem; }
table { border-collapse: collapse; font-size: 0.86rem; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid #d9dee5; padding: 0.25rem 0.55rem; }
th { background: #eef1f5; }
tbody tr:nth-child(even) { background: #f8f9fb; }
code { background: #eef1f5; padding: 0 0.25rem; border-radius: 3px; }
img { max-width: 100%; height: auto; }
figure { margin: 0.8rem 0; }
figcaption { font-size: 0.85rem; color: #55606e; }
.chart img { max-height: 560px; }
.gallery { display: grid; grid-template-columns: repeat(auto-fill, minmax(330px, 1fr)); gap: 0.8rem; }
.card { border: 1px solid #d9dee5; border-radius: 6px; padding: 0.5rem; }
.card h4 { margin: 0 0 0.3rem; }
.pair { display: grid; grid-template-columns: 1fr 1fr; gap: 0.4rem; align-items: end; }
.pair figure, .single figure { margin: 0; min-width: 0; }
.render img { image-rendering: pixelated; width: 100%; }
.took { color: #55606e; font-size: 0.85rem; margin-top: -0.4rem; }
dl.machine { display: grid; grid-template-columns: max-content 1fr; gap: 0.2rem 1rem; }
dl.machine dt { font-weight: 600; }
dl.machine dd { margin: 0; }
"""


def _data_uri(path: Path) -> str:
    kind = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml"}
    mime = kind.get(path.suffix.lower(), "application/octet-stream")
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def _inline_images(text: str, folder: Path) -> str:
    """Replace every ``<img src>`` of a file in ``folder`` by its data URI; a missing file becomes a note."""

    def inline(match: re.Match) -> str:
        source = folder / html.unescape(match.group(2))
        if not source.is_file():
            return f'<p class="note">image {html.escape(source.name)} was not written by this run</p>'
        return f'{match.group(1)}{_data_uri(source)}{match.group(3)}'

    return re.sub(r'(<img\b[^>]*?\bsrc=")(?!data:)([^"]+)("[^>]*>)', inline, text)


def _markdown():
    try:
        import markdown
    except ImportError:
        raise ImportError("the report converts markdown with the markdown package: pip install markdown") from None
    return markdown


def markdown_html(path: Path, demote: int = 2, drop_title: bool = False) -> str:
    """A markdown file as HTML: tables converted, headings ``demote`` levels down, images inlined;
    ``drop_title``: without its first top-level heading."""
    markdown = _markdown()

    source = Path(path).read_text()
    if drop_title:
        source = re.sub(r"\A\s*# [^\n]*\n", "", source)
    text = markdown.markdown(source, extensions=["tables"], output_format="html")
    text = re.sub(r"<(/?)h([1-6])\b", lambda m: f"<{m.group(1)}h{min(int(m.group(2)) + demote, 6)}", text)
    text = text.replace("<table>", '<div class="scroll"><table>').replace("</table>", "</table></div>")
    return _inline_images(text, Path(path).parent)


def _figure(path: Path, caption: str, css: str = "") -> str:
    alt = html.escape(caption, quote=True)
    return (f'<figure class="{css}"><img src="{_data_uri(path)}" alt="{alt}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _gallery(images) -> str:
    groups: dict[str, list] = {}
    for image in images:
        groups.setdefault(image.group, []).append(image)
    cards = []
    for group, members in groups.items():
        figures = "".join(_figure(m.path, m.caption, "render" if m.caption == "render" else "")
                          for m in members if m.path.is_file())
        layout = "pair" if len(members) > 1 else "single"
        cards.append(f'<div class="card"><h4>{html.escape(group)}</h4><div class="{layout}">{figures}</div></div>')
    return f'<div class="gallery">{"".join(cards)}</div>'


def _section(section: Section, written: runner.Written, seconds: float, quick: bool) -> str:
    command = f"rayaccel experiment {section.name}" + (" --quick" if quick else "")
    parts = [f'<h2 id="{section.name}">{html.escape(section.title)}</h2>',
             f'<p class="took">Alone: <code>{command}</code>; {seconds:.0f} s in this run.</p>',
             f'<p class="claim"><b>The lecture:</b> {html.escape(section.lecture)}</p>',
             f'<p class="claim"><b>Measured here:</b> {html.escape(section.measured)}</p>',
             markdown_html(written.table),
             _figure(written.plot, f"{section.title}: chart", "chart")]
    if written.images:
        parts.append(_gallery(written.images))
    return "\n".join(parts)


def find_bench_results(folder: Path | None = None) -> Path | None:
    """The newest ``bench_structures*.md`` under ``folder`` (default ``benchmarks/results`` in the current
    directory), or None."""
    folder = Path(folder) if folder is not None else Path.cwd() / "benchmarks" / "results"
    found = [path for path in folder.rglob("bench_structures*.md") if path.is_file()] if folder.is_dir() else []
    return max(found, key=lambda path: path.stat().st_mtime, default=None)


def _bench_section(folder: Path | None) -> str:
    where = Path(folder) if folder is not None else Path("benchmarks") / "results"
    parts = ['<h2 id="peers">rayaccel against its peers</h2>',
             '<p class="claim"><b>Measured here:</b> rayaccel\'s structures against the ray tracers a Python user '
             "would otherwise reach for (Embree through embreex, Open3D, Mitsuba 3), on the same rays in the same "
             "process, taking turns; figures are medians, read the ratios rather than the absolute values.</p>"]
    found = find_bench_results(folder)
    if found is None:
        parts.append(f'<p class="note">No benchmark results were found in <code>{html.escape(str(where))}</code>. '
                     f"Run <code>{BENCH_COMMAND}</code> from the project's folder (it installs the peers "
                     "itself; the default run took 13 to 19 minutes on a shared 2-core machine; "
                     "<code>--scenes bunny --side 256</code> is shorter), then write the report again, or point "
                     "<code>--bench-results DIR</code> at the folder of its <code>--out</code>.</p>")
        return "\n".join(parts)
    stamp = datetime.datetime.fromtimestamp(found.stat().st_mtime).astimezone().strftime("%Y-%m-%d %H:%M")
    parts.append(f'<p class="subtitle">From <code>{html.escape(str(found))}</code>, written {stamp}.</p>')
    parts.append(markdown_html(found, drop_title=True))
    return "\n".join(parts)


def _memory_gib() -> float | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        return None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def machine() -> list[tuple[str, str]]:
    """The machine and software a report was measured with, as (label, value) pairs."""
    import numba

    memory = _memory_gib()
    return [
        ("CPU", _cpu_model()),
        ("cores", f"{os.cpu_count()} logical; Numba threads {numba.config.NUMBA_NUM_THREADS}"),
        ("memory", f"{memory:.1f} GiB" if memory else "unknown"),
        ("system", platform.platform()),
        ("Python", platform.python_version()),
        ("versions", ", ".join(f"{name} {_version(name)}" for name in ("rayaccel", "numpy", "numba", "matplotlib"))),
    ]


def _page(body: str, title: str) -> str:
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n"
            f"<body>\n<main>\n{body}\n</main>\n</body>\n</html>\n")


def write_report(out, quick: bool = False, bench_results: Path | None = None, size: int | None = None,
                 show_progress: bool = True) -> Path:
    """Run every lecture experiment and write the page to ``out``; their files go to ``OUT-files/``.

    ``quick``: small scenes, sizes and sweeps (about a minute once the kernels are compiled), said on
    the page; ``size``: the side of the experiments' images; ``bench_results``: the folder of
    ``benchmarks/bench_structures.py``'s results (default ``benchmarks/results``)."""
    from ._progress import progress_steps

    _markdown()
    out = Path(out)
    work = out.with_name(out.stem + "-files")
    started = datetime.datetime.now().astimezone()
    clock = time.perf_counter()
    written, seconds = {}, {}
    with progress_steps("rayaccel report", len(SECTIONS), enabled=show_progress) as bar:
        for section in SECTIONS:
            start = time.perf_counter()
            written[section.name] = runner.run(section.name, work, size, None, bar, quick)
            seconds[section.name] = time.perf_counter() - start
    minutes = (time.perf_counter() - clock) / 60

    title = "Ray-tracing acceleration structures: the lecture's experiments, measured"
    side = size or (runner.QUICK_SIDE if quick else runner.FULL_SIDE)
    toc = [(s.name, s.title) for s in SECTIONS] + [("peers", "rayaccel against its peers"),
                                                   ("machine", "Machine and versions")]
    body = [f"<h1>{html.escape(title)}</h1>",
            f'<p class="subtitle">rayaccel {html.escape(_version("rayaccel"))}, measured on '
            f"{started:%Y-%m-%d %H:%M %Z} on {html.escape(_cpu_model())}, {os.cpu_count()} cores; "
            f"the experiments took {minutes:.1f} min.</p>"]
    if quick:
        body.append(f'<p class="banner"><b>Quick run</b> (<code>rayaccel report --quick</code>): small scenes, '
                    f"{side}x{side} images and short sweeps, to show every experiment in about a minute. The "
                    "figures are noisy and are not the lecture's: run <code>rayaccel report</code> for those.</p>")
    body.append("<p>Each section states what the lecture claims, then what rayaccel measured on this machine: the "
                "table, the chart, and for some the pictures. Times vary by tens of percent on a shared machine; "
                "compare within a table.</p>")
    body.append("<nav><h3>Contents</h3><ol>" + "".join(f'<li><a href="#{anchor}">{html.escape(name)}</a></li>'
                                                       for anchor, name in toc) + "</ol></nav>")
    body += [_section(section, written[section.name], seconds[section.name], quick) for section in SECTIONS]
    body.append(_bench_section(bench_results))
    rows = machine() + [("measured", f"{started:%Y-%m-%d %H:%M %Z}"),
                        ("command", "rayaccel report" + (" --quick" if quick else "")),
                        ("experiments' files", str(work))]
    body.append('<h2 id="machine">Machine and versions</h2><dl class="machine">'
                + "".join(f"<dt>{html.escape(k)}</dt><dd>{html.escape(v)}</dd>" for k, v in rows) + "</dl>")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(_page("\n".join(body), title), encoding="utf-8")
    return out
