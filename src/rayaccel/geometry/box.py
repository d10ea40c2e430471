"""Ray-box slab test (Kay & Kajiya 1986) that is exact for zero direction components.

A component of +0 or -0 makes ``1/d`` infinite and ``(lo - o) / d`` NaN when the
origin lies on the slab's plane; such an axis is instead tested directly:
the ray runs parallel to the slab and is inside it for all ``t`` exactly when
``lo <= o <= hi``. Boxes are closed: touching a face counts as a hit.
"""

from __future__ import annotations

from .._jit import kernel

__all__ = ["clip_to_box"]


@kernel
def _clip_axis(lo, hi, o, d, t_enter, t_exit):
    if d == 0.0:
        if o < lo or o > hi:
            return 1.0, 0.0
        return t_enter, t_exit
    inv = 1.0 / d
    t0 = (lo - o) * inv
    t1 = (hi - o) * inv
    if t0 > t1:
        t0, t1 = t1, t0
    return max(t_enter, t0), min(t_exit, t1)


@kernel
def clip_to_box(lo, hi, ox, oy, oz, dx, dy, dz, t_min, t_max):
    """The part ``[t_enter, t_exit]`` of ``[t_min, t_max]`` where the ray is inside
    the box ``lo``..``hi`` (3-arrays); ``t_enter > t_exit`` when it misses."""
    t_enter, t_exit = _clip_axis(lo[0], hi[0], ox, dx, t_min, t_max)
    t_enter, t_exit = _clip_axis(lo[1], hi[1], oy, dy, t_enter, t_exit)
    t_enter, t_exit = _clip_axis(lo[2], hi[2], oz, dz, t_enter, t_exit)
    return t_enter, t_exit
