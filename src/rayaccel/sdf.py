"""Signed distance sampled on a regular grid over a scene's box, and a picture of three slices.

Samples sit on grid nodes: ``resolution`` of them along the longest side of the scene's
box padded by ``pad`` of its size on every side, as many at the same spacing along the
shorter sides (cubic voxels); ``sdf[i, j, k]`` lies at ``lo + (i, j, k) * spacing``.
Values come from :meth:`rayaccel.structures.base.Accelerator.signed_distance` (negative
inside), one slab of constant ``x`` at a time, so that a progress bar can follow.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["sample_signed_distance", "write_slices"]


def sample_signed_distance(accel, resolution: int = 128, pad: float = 0.05, progress=None):
    """``(sdf, lo, spacing)``: the signed distance on the grid described in the module docstring;
    ``progress(done)`` is called after each slab of constant x."""
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 2:
        raise ValueError(f"resolution must be an integer of at least 2, got {resolution!r}")
    scene_lo, scene_hi = (np.asarray(v, dtype=np.float64) for v in accel.scene_box)
    size = scene_hi - scene_lo
    margin = pad * float(size.max())
    lo, hi = scene_lo - margin, scene_hi + margin
    spacing = float((hi - lo).max()) / (resolution - 1)
    counts = np.maximum(np.ceil((hi - lo) / spacing).astype(int) + 1, 2)
    ys = lo[1] + spacing * np.arange(counts[1])
    zs = lo[2] + spacing * np.arange(counts[2])
    yy, zz = np.meshgrid(ys, zs, indexing="ij")
    sdf = np.empty(tuple(counts))
    for i in range(counts[0]):
        slab = np.column_stack([np.full(yy.size, lo[0] + spacing * i), yy.ravel(), zz.ravel()])
        sdf[i] = accel.signed_distance(slab).reshape(yy.shape)
        if progress is not None:
            progress(i + 1)
    return sdf, lo, spacing


def write_slices(sdf: np.ndarray, lo: np.ndarray, spacing: float, path, title: str = "") -> Path:
    """A PNG of the middle slice across each axis: a diverging colour map centred at 0 (blue
    inside, red outside) with the zero contour, the surface, drawn in black."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    limit = float(np.abs(sdf).max()) or 1.0
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-limit, vmax=limit)
    figure, axes = plt.subplots(1, 3, figsize=(15, 5), constrained_layout=True)
    names = "xyz"
    for axis, ax in enumerate(axes):
        index = sdf.shape[axis] // 2
        plane = np.take(sdf, index, axis=axis)
        u, v = [a for a in range(3) if a != axis]
        extent = (lo[u], lo[u] + spacing * (sdf.shape[u] - 1), lo[v], lo[v] + spacing * (sdf.shape[v] - 1))
        image = ax.imshow(plane.T, origin="lower", extent=extent, cmap="RdBu_r", norm=norm)
        if plane.min() < 0.0 < plane.max():
            ax.contour(plane.T, levels=[0.0], colors="black", linewidths=1.0, extent=extent, origin="lower")
        ax.set_title(f"{names[axis]} = {lo[axis] + spacing * index:.4g}")
        ax.set_xlabel(names[u])
        ax.set_ylabel(names[v])
    figure.colorbar(image, ax=axes, shrink=0.8, label="signed distance (negative inside)")
    if title:
        figure.suptitle(title)
    path = Path(path)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path
