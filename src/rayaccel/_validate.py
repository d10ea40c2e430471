"""Checks at the Python boundary: Numba kernels do no bounds checks, so every
array that reaches one is validated and converted here, once."""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

from ._jit import inline_kernel, kernel, on_threads
from ._ray_lanes import LANES, origin_at, rays_by_axis, rays_readable

__all__ = ["as_points", "as_index_triples", "as_per_ray", "as_positive_int", "check_flag", "check_number",
           "first_zero_row", "check_ray_arrays", "unusable_ray", "unusable_rays"]


@kernel
def _first_nonfinite_row(array):
    for i in range(array.shape[0]):
        for k in range(array.shape[1]):
            if not np.isfinite(array[i, k]):
                return i
    return -1


@kernel
def first_zero_row(array):
    """Index of the first all-zero row of an (n, 3) array, or -1."""
    for i in range(array.shape[0]):
        if array[i, 0] == 0.0 and array[i, 1] == 0.0 and array[i, 2] == 0.0:
            return i
    return -1


@inline_kernel
def unusable_ray(ox, oy, oz, dx, dy, dz):
    """Whether the ray from ``(ox, oy, oz)`` along ``(dx, dy, dz)`` is one :func:`check_ray_arrays`
    refuses: a NaN or infinite coordinate, or an all-zero direction."""
    # x * 0 is 0 for a finite x and NaN for an infinite or NaN one, without a branch
    nonfinite = ox * 0.0 + oy * 0.0 + oz * 0.0 + dx * 0.0 + dy * 0.0 + dz * 0.0 != 0.0
    return nonfinite | ((dx == 0.0) & (dy == 0.0) & (dz == 0.0))


@intrinsic
def _unusable_eight(typingctx, origins, directions, first):
    """How many of the eight rays from row ``first`` are :func:`unusable_ray`, in vector lanes
    (:func:`rayaccel._ray_lanes.rays_by_axis`). Written as a loop over the rays, the check
    compiled to gathers, one per coordinate of eight rays, which held about 40 % of the
    packet walk's samples on the forest's camera rays (any hit, one thread, AMD EPYC): most
    of those rays miss the scene, so the check was most of their cost."""
    if not rays_readable(origins, directions):
        return None
    signature = types.int64(origins, directions, first)

    def codegen(context, builder, sig, args):
        doubles = ir.VectorType(ir.DoubleType(), LANES)
        row = context.cast(builder, args[2], sig.args[2], types.intp)
        zero = ir.Constant(doubles, [0.0] * LANES)
        coordinates = (rays_by_axis(context, builder, sig.args[0], args[0], row)
                       + rays_by_axis(context, builder, sig.args[1], args[1], row))
        total = builder.fmul(coordinates[0], zero)
        for value in coordinates[1:]:
            total = builder.fadd(total, builder.fmul(value, zero))
        bad = builder.fcmp_unordered("!=", total, zero)
        zero_xy = builder.and_(builder.fcmp_ordered("==", coordinates[3], zero),
                               builder.fcmp_ordered("==", coordinates[4], zero))
        bad = builder.or_(bad, builder.and_(zero_xy, builder.fcmp_ordered("==", coordinates[5], zero)))
        int64 = ir.IntType(64)
        mask = builder.zext(builder.bitcast(bad, ir.IntType(LANES)), int64)
        popcount = cgutils.get_or_insert_function(builder.module, ir.FunctionType(int64, [int64]), "llvm.ctpop.i64")
        return builder.call(popcount, [mask])

    return signature, codegen


def unusable_rays(origins, directions, first, end):
    """How many of the rays ``first`` to ``end - 1`` are :func:`unusable_ray` (inside kernels)."""


@overload(unusable_rays, inline="always")
def _unusable_rays(origins, directions, first, end):
    if rays_readable(origins, directions):
        def in_lanes(origins, directions, first, end):
            found = 0
            i = first
            while i + LANES <= end:
                found += _unusable_eight(origins, directions, i)
                i += LANES
            return found + _unusable_one_by_one(origins, directions, i, end)
        return in_lanes

    def one_by_one(origins, directions, first, end):
        return _unusable_one_by_one(origins, directions, first, end)
    return one_by_one


@inline_kernel
def _unusable_one_by_one(origins, directions, first, end):
    found = 0
    for i in range(first, end):
        ox, oy, oz = origin_at(origins, i)
        found += unusable_ray(ox, oy, oz, directions[i, 0], directions[i, 1], directions[i, 2])
    return found


@kernel
def _count_unusable_rays(origins, directions, first, end):
    """:func:`unusable_rays` as a kernel of its own, for :func:`check_ray_arrays`."""
    return unusable_rays(origins, directions, first, end)


def _nonfinite_error(name: str, array: np.ndarray, count: int) -> ValueError:
    first = _first_nonfinite_row(array)
    return ValueError(f"{name} has {count} row(s) with NaN or infinite coordinates "
                      f"(first at index {first}: {array[first].tolist()})")


def check_ray_arrays(origins: np.ndarray, directions: np.ndarray) -> None:
    """Raise ``ValueError`` for NaN or infinite coordinates in the (n, 3) float64 ``origins`` or
    ``directions``, or an all-zero direction (a ray without a direction has no first hit).
    One pass counts the rays :func:`unusable_ray` refuses, the test the walks that check their
    own rays make; only when there are some are the kinds of defect told apart. Such a walk
    leaves the rays it refuses unwalked and may take the rays unchecked, calling this only
    when it met one."""
    if not sum(on_threads(lambda first, end, _: _count_unusable_rays(origins, directions, first, end),
                          len(directions))):
        return
    origins = np.atleast_2d(origins)
    bad_origins = int((~np.isfinite(origins).all(axis=1)).sum())
    if bad_origins:
        raise _nonfinite_error("origins", origins, bad_origins)
    bad_directions = int((~np.isfinite(directions).all(axis=1)).sum())
    if bad_directions:
        raise _nonfinite_error("directions", directions, bad_directions)
    zero_directions = int((directions == 0.0).all(axis=1).sum())
    if zero_directions:
        raise ValueError(f"{zero_directions} ray direction(s) have zero length "
                         f"(first at index {first_zero_row(directions)})")


def _owned(array: np.ndarray) -> np.ndarray:
    """``array``, copied when it is read-only: kernels then see one array type, writable,
    instead of compiling a read-only variant of themselves on first use."""
    return array if array.flags.writeable else array.copy()


def as_points(name: str, values, *, allow_empty: bool = False, check_finite: bool = True,
              keep_float32: bool = False) -> np.ndarray:
    """``values`` as a C-contiguous float64 (n, 3) array, or float32 when ``keep_float32`` and
    they are float32 already, of finite coordinates unless ``check_finite`` is False (the
    caller checks them later)."""
    if _ready_points(values, keep_float32):
        array = values
    else:
        array = _converted_points(name, values, keep_float32)
    if array.shape[0] == 0 and not allow_empty:
        raise ValueError(f"{name} is empty")
    if check_finite and _first_nonfinite_row(array) >= 0:
        raise _nonfinite_error(name, array, int((~np.isfinite(array).all(axis=1)).sum()))
    return array


_FLOAT64, _FLOAT32 = np.dtype(np.float64), np.dtype(np.float32)


def _ready_points(values, keep_float32: bool) -> bool:
    """Whether ``values`` is already what :func:`as_points` returns, told from its attributes alone:
    a query runs this before its threads start, when each NumPy call costs several times its warm
    time (the caches cold after the previous walk)."""
    return (type(values) is np.ndarray and values.ndim == 2 and values.shape[1] == 3
            and (values.dtype is _FLOAT64 or (keep_float32 and values.dtype is _FLOAT32))
            and values.flags.c_contiguous and values.flags.writeable)


def _converted_points(name: str, values, keep_float32: bool) -> np.ndarray:
    """``values`` as :func:`as_points` returns them, before the checks of their count and values."""
    try:
        array = np.asarray(values)
    except Exception as exc:  # ragged nested sequences and the like
        raise TypeError(f"{name} must be an (n, 3) array of numbers: {exc}") from None
    if array.dtype == object or not (
        np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)
    ):
        raise TypeError(f"{name} must hold real numbers, got dtype {array.dtype}")
    if array.ndim == 1 and array.shape[0] == 3:
        array = array[None, :]
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {array.shape}")
    kept = np.float32 if keep_float32 and array.dtype == np.float32 else np.float64
    return _owned(np.ascontiguousarray(array, dtype=kept))


def as_index_triples(name: str, values, n_vertices: int) -> np.ndarray:
    """``values`` as a C-contiguous int64 (n, 3) array of indices into ``n_vertices``."""
    array = np.asarray(values)
    if not np.issubdtype(array.dtype, np.integer):
        if np.issubdtype(array.dtype, np.floating) and array.size and np.all(np.mod(array, 1) == 0):
            array = array.astype(np.int64)
        elif array.size:
            raise TypeError(f"{name} must hold integer vertex indices, got dtype {array.dtype}")
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {array.shape}")
    if array.shape[0] == 0:
        raise ValueError(f"{name} is empty: a scene needs at least one triangle")
    array = _owned(np.ascontiguousarray(array, dtype=np.int64))
    low, high = int(array.min()), int(array.max())
    if low < 0 or high >= n_vertices:
        bad = low if low < 0 else high
        raise ValueError(
            f"{name} index {bad} is out of range for {n_vertices} vertices "
            f"(valid: 0 .. {n_vertices - 1})"
        )
    return array


def as_per_ray(name: str, value, n_rays: int, *, shared: bool = False) -> np.ndarray:
    """A scalar or an (n_rays,) array as a float64 (n_rays,) array without NaN; a scalar as a
    (1,) array when ``shared`` (one value for every ray)."""
    if type(value) is float or type(value) is int:
        if value != value:
            raise ValueError(f"{name} contains NaN")
        return np.array((value,), dtype=np.float64) if shared else np.full(n_rays, float(value))
    array = np.asarray(value, dtype=np.float64)
    if array.ndim == 0:
        if np.isnan(array):
            raise ValueError(f"{name} contains NaN")
        return np.full(1 if shared else n_rays, float(array))
    if array.shape != (n_rays,):
        raise ValueError(f"{name} must be a scalar or have shape ({n_rays},), got {array.shape}")
    array = _owned(np.ascontiguousarray(array))
    if np.isnan(array).any():
        raise ValueError(f"{name} contains NaN")
    return array


def as_positive_int(name: str, value) -> int:
    """``value`` as an int of at least 1."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{name} must be at least 1, got {value}")
    return int(value)


def check_flag(name: str, value) -> bool:
    """``value`` of option ``name``, refused with a ``TypeError`` unless it is ``True`` or ``False``."""
    if not isinstance(value, bool):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return value


def check_number(name, value, *, integer=False, minimum=0.0, inclusive=False, maximum=None):
    """``value`` as a float (or int), or a TypeError/ValueError naming the option."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__}")
    if integer and int(value) != value:
        raise TypeError(f"{name} must be an integer, got {value!r}")
    ok = np.isfinite(value) and (value >= minimum if inclusive else value > minimum)
    if maximum is not None:
        ok = ok and value <= maximum
    if not ok:
        bound = f"at least {minimum}" if inclusive else f"greater than {minimum}"
        raise ValueError(f"{name} must be {bound}{'' if maximum is None else f' and at most {maximum}'}, got {value!r}")
    return int(value) if integer else float(value)
