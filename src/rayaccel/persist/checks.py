"""Checks on arrays read from a file, before any kernel sees them.

Numba kernels do no bounds checks, so a saved structure is trusted only once
every index a traversal dereferences is known to lie in range and every tree
is known to be a tree: child links point forward (so every walk ends), each
node has at most one parent (so the depth that sizes the traversal stacks is
the real depth), leaf ranges lie inside their reference arrays. All checks
are vectorised numpy over the whole array.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CorruptFileError", "array", "finite", "boxes", "index_range", "offsets", "permutation",
           "single_parents", "leaf_ranges", "require"]


class CorruptFileError(ValueError):
    """A saved accelerator that cannot be trusted: truncated, corrupted, of another format
    version, or holding arrays of the wrong shape, dtype or range."""


def require(condition, message: str) -> None:
    """Raise :class:`CorruptFileError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise CorruptFileError(message)


def array(arrays: dict, name: str, dtype, shape: tuple) -> np.ndarray:
    """``arrays[name]``, required to have exactly ``dtype`` and ``shape`` (None matches any
    length on that axis) and to be C-contiguous."""
    require(name in arrays, f"array {name!r} is missing")
    a = arrays[name]
    require(isinstance(a, np.ndarray), f"{name} is not an array")
    require(a.dtype == np.dtype(dtype), f"{name} has dtype {a.dtype}, expected {np.dtype(dtype)}")
    require(a.ndim == len(shape) and all(s is None or s == t for s, t in zip(shape, a.shape)),
            f"{name} has shape {a.shape}, expected {tuple('n' if s is None else s for s in shape)}")
    require(a.flags.c_contiguous, f"{name} is not C-contiguous")
    return a


def finite(name: str, a: np.ndarray) -> np.ndarray:
    require(bool(np.isfinite(a).all()), f"{name} holds NaN or infinite values")
    return a


def boxes(name: str, box: np.ndarray) -> np.ndarray:
    """(n, 6) finite boxes ``lo, hi`` with ``lo <= hi``."""
    finite(name, box)
    require(bool((box[:, :3] <= box[:, 3:]).all()), f"{name} holds boxes whose lo exceeds hi")
    return box


def index_range(name: str, index: np.ndarray, low: int, high: int) -> np.ndarray:
    """Every entry in ``low .. high - 1``."""
    if index.size:
        require(int(index.min()) >= low and int(index.max()) < high,
                f"{name} indexes outside {low} .. {high - 1} (found {int(index.min())} .. {int(index.max())})")
    return index


def offsets(name: str, first: np.ndarray, total: int) -> np.ndarray:
    """Row offsets of a compressed-row array of ``total`` entries: 0 first, non-decreasing,
    ``total`` last."""
    require(len(first) >= 1 and int(first[0]) == 0 and int(first[-1]) == total,
            f"{name} must run from 0 to {total}")
    require(bool((np.diff(first) >= 0).all()), f"{name} decreases")
    return first


def permutation(name: str, order: np.ndarray, n: int) -> np.ndarray:
    """A permutation of ``0 .. n - 1``."""
    require(len(order) == n, f"{name} has {len(order)} entries, expected {n}")
    index_range(name, order, 0, n)
    require(bool((np.bincount(order, minlength=n) == 1).all()), f"{name} is not a permutation")
    return order


def single_parents(name: str, parent: np.ndarray, child: np.ndarray, n_nodes: int, roots=(0,)) -> None:
    """``child[k]`` is a child of ``parent[k]``: children must come after their parents, lie
    among the ``n_nodes`` nodes, have one parent each, and not be a root."""
    index_range(f"{name} child links", child, 0, n_nodes)
    require(bool((child > parent).all()), f"{name} links a node to a child before it")
    seen = np.bincount(child, minlength=n_nodes)
    require(bool((seen <= 1).all()), f"{name} gives a node two parents")
    require(not seen[np.asarray(roots, dtype=np.int64)].any(), f"{name} gives a root a parent")


def leaf_ranges(name: str, first: np.ndarray, count: np.ndarray, n_refs: int) -> None:
    """Leaves' ranges ``first .. first + count`` inside ``0 .. n_refs``."""
    first = first.astype(np.int64)
    count = count.astype(np.int64)
    require(bool((count >= 0).all()) and bool((first >= 0).all()), f"{name} has negative offsets or counts")
    require(bool((first + count <= n_refs).all()), f"{name} reaches past its {n_refs} references")
