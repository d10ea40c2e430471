"""One runner for every experiment, shared by ``rayaccel experiment NAME`` and ``rayaccel report``.

Each experiment is one function taking ``(out_dir, size, scenes, progress, quick)`` (plus its own
keyword options) that runs the experiment's module, writes its markdown table and chart into
``out_dir``, and returns them as :class:`Written`, with any further images it wrote. ``size`` is
the side of the images traced (``None``: the default, smaller when ``quick``), ``scenes`` the
scenes measured (``None``: the default list), ``progress(description, total)`` a context manager
yielding ``advance(done)`` (:func:`rayaccel._progress.progress_bar` fits), and ``quick`` asks for
small scenes, sizes and sweeps, so that every experiment together takes about a minute once the
kernels are compiled.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from .._progress import progress_bar

__all__ = ["EXPERIMENTS", "FULL_SIDE", "QUICK_SIDE", "Image", "Written", "names", "run", "silent"]

FULL_SIDE = 512
QUICK_SIDE = 96


class Image(NamedTuple):
    """An image an experiment wrote besides its chart: ``group`` (e.g. the method) and what it shows."""

    group: str
    caption: str
    path: Path


class Written(NamedTuple):
    """What one experiment wrote: its markdown table, its chart, and further images."""

    table: Path
    plot: Path
    images: tuple[Image, ...] = ()


def silent(description: str, total: int):
    """A progress factory that shows nothing."""
    return progress_bar(description, total, enabled=False)


def _side(size: int | None, quick: bool) -> int:
    return size or (QUICK_SIDE if quick else FULL_SIDE)


def grid_vs_none(out_dir, size=None, scenes=None, progress=silent, quick=False, *, max_n=None,
                 client=None) -> Written:
    """The lecture's first table: n random spheres (10 ... ``max_n``), grid against brute force.
    ``scenes`` does not apply; ``client``: a Dask client for the rows of 100,000 spheres or more."""
    from . import grid_vs_none as experiment

    if scenes:
        raise ValueError("grid-vs-none measures random spheres: give --max-n, not --scenes")
    max_n = max_n or (10_000 if quick else 1_000_000)
    sizes = [n for n in (10, 100, 1_000, 10_000, 100_000, 1_000_000, 10_000_000) if n <= max_n]
    if not sizes:
        raise ValueError("--max-n must be at least 10")
    side = _side(size, quick)
    with progress("grid vs no grid", len(sizes)) as advance:
        rows = experiment.run(sizes, image_size=side, progress=advance, client=client)
    return Written(*experiment.write_report(rows, out_dir, side))


def grid_resolution(out_dir, size=None, scenes=None, progress=silent, quick=False) -> Written:
    """Grid cells per primitive swept against the cost model's optimum."""
    from . import grid_resolution as experiment

    scenes = scenes or (["bunny", "spheres:10000"] if quick else ["bunny", "spheres:100000"])
    densities = (0.5, 2.0, 8.0, 32.0) if quick else experiment.DENSITIES
    side = _side(size, quick)
    with progress("grid resolution sweep", len(scenes) * len(densities)) as advance:
        rows = experiment.run(scenes, densities, side=side, progress=advance)
    return Written(*experiment.write_report(rows, out_dir, side))


def bvh(out_dir, size=None, scenes=None, progress=silent, quick=False) -> Written:
    """Which BVH is better: every builder on every scene, with node heatmaps on the first scene."""
    from ..structures.registry import methods
    from . import bvh_builders as experiment

    scenes = scenes or (["bunny"] if quick else list(experiment.DEFAULT_SCENES))
    builders = [m for m in methods() if m.startswith("bvh-")]
    side = _side(size, quick)
    with progress("which BVH is better", len(scenes) * len(builders)) as advance:
        rows = experiment.run(scenes, builders, side=side, heatmap_dir=Path(out_dir), progress=advance)
    images = tuple(Image(method, "nodes visited", experiment.heatmap_path(out_dir, scenes[0], method))
                   for method in builders)
    return Written(*experiment.write_report(rows, out_dir, side), images)


def bounding_volumes(out_dir, size=None, scenes=None, progress=silent, quick=False) -> Written:
    """Cheap vs tight: boxes, spheres and 14-DOPs as the volumes of one BVH."""
    from . import bounding_volumes as experiment

    scenes = scenes or (["bunny"] if quick else ["bunny", "dragon-203k", "armadillo"])
    side = _side(size, quick)
    with progress("cheap vs tight volumes", len(scenes) * len(experiment.VOLUMES)) as advance:
        rows = experiment.run(scenes, side=side, progress=advance)
    return Written(*experiment.write_report(rows, out_dir, side))


def kdtree_table(out_dir, size=None, scenes=None, progress=silent, quick=False, *, method=None) -> Written:
    """The lecture's kd-tree statistics table, for the kd-tree or the structure ``method``."""
    from ..structures.registry import methods
    from . import kdtree_table as experiment

    method = method or "kdtree"
    if method not in methods():
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(methods())}")
    scenes = scenes or (["bunny", "forest"] if quick else list(experiment.DEFAULT_SCENES))
    side = _side(size, quick)
    with progress(f"kd-tree table for {method}", len(scenes)) as advance:
        columns = experiment.run(scenes, method, side=side, progress=advance)
    return Written(*experiment.write_report(columns, method, out_dir, side))


def structures(out_dir, size=None, scenes=None, progress=silent, quick=False) -> Written:
    """Every structure but brute force on one scene, with its render and nodes-visited heatmap."""
    from ..structures.registry import methods
    from . import structures as experiment

    if scenes and len(scenes) > 1:
        raise ValueError("experiment structures takes one scene")
    scene = scenes[0] if scenes else "forest-small-chair"
    chosen = [m for m in methods() if m != "none"]
    side = _side(size, quick)
    with progress(f"every structure on {scene}", len(chosen)) as advance:
        rows = experiment.run(scene, chosen, side=side, out_dir=Path(out_dir), progress=advance)
    images = []
    for method in chosen:
        render, heatmap = experiment.image_paths(out_dir, scene, method)
        images += [Image(method, "render", render), Image(method, "nodes or cells visited", heatmap)]
    return Written(*experiment.write_report(rows, out_dir, side), tuple(images))


def leaf_size(out_dir, size=None, scenes=None, progress=silent, quick=False) -> Written:
    """The kd-tree's and the binned BVH's leaf size swept."""
    from . import leaf_size as experiment

    scenes = scenes or (["bunny"] if quick else ["bunny", "dragon-203k"])
    leaf_sizes = (1, 4, 16) if quick else experiment.LEAF_SIZES
    side = _side(size, quick)
    with progress("leaf size sweep", len(scenes) * len(experiment.SWEPT) * len(leaf_sizes)) as advance:
        rows = experiment.run(scenes, leaf_sizes, side=side, progress=advance)
    return Written(*experiment.write_report(rows, out_dir, side))


def queries(out_dir, size=None, scenes=None, progress=silent, quick=False, *, points=None) -> Written:
    """Point queries (closest point, contains, signed distance) against Open3D and trimesh, on one scene;
    ``size`` does not apply, ``points``: how many query points."""
    from . import queries as experiment

    if scenes and len(scenes) > 1:
        raise ValueError("experiment queries takes one scene")
    scene = scenes[0] if scenes else ("bunny" if quick else "dragon-203k")
    points = points or (32_768 if quick else 262_144)
    rounds = 3
    with progress("point queries", rounds) as advance:
        rows, builds = experiment.run(scene, n=points, rounds=rounds, progress=advance)
    return Written(*experiment.write_report(rows, builds, out_dir, scene, rounds))


EXPERIMENTS: dict[str, Callable[..., Written]] = {
    "grid-vs-none": grid_vs_none,
    "grid-resolution": grid_resolution,
    "bvh": bvh,
    "bounding-volumes": bounding_volumes,
    "kdtree-table": kdtree_table,
    "structures": structures,
    "leaf-size": leaf_size,
    "queries": queries,
}


def names() -> list[str]:
    """Every experiment's name, as ``rayaccel experiment`` takes it."""
    return list(EXPERIMENTS)


def run(name: str, out_dir, size=None, scenes=None, progress=silent, quick=False, **options) -> Written:
    """Run the experiment ``name`` (see :data:`EXPERIMENTS`) and return what it wrote into ``out_dir``."""
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    return EXPERIMENTS[name](Path(out_dir), size, scenes, progress, quick, **options)
