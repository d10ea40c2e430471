"""The SAH cost of a kd-tree split, with Wald & Havran's empty-space bonus.

Wald & Havran, "On building fast kd-Trees for Ray Tracing, and on doing that
in O(N log N)", IEEE Symposium on Interactive Ray Tracing 2006, section 3
(after MacDonald & Booth 1990): splitting a cell of area ``S`` at a plane with
``N_L``/``N_R`` primitives on sides of areas ``S_L``/``S_R`` costs::

    lambda * (K_T + K_I * (S_L N_L + S_R N_R) / S)

where ``lambda = 1 - empty_bonus`` when one side is empty (a ray that crosses
only empty space leaves early, so cutting it off pays) and 1 otherwise. The
bonus scales the whole cost, traversal step included, as the paper has it;
scaling only the intersection term favours empty cuts less where the cell's
primitives are few.
"""

from __future__ import annotations

from ..._jit import inline_kernel

__all__ = ["split_cost"]


@inline_kernel
def split_cost(traversal_cost, scale, area_left, n_left, area_right, n_right, empty_bonus):
    """Cost of a split; ``scale`` is ``K_I`` over the area of the cell being split, in the units
    of ``area_left`` and ``area_right``."""
    cost = traversal_cost + scale * (area_left * n_left + area_right * n_right)
    if n_left == 0 or n_right == 0:
        return (1.0 - empty_bonus) * cost
    return cost
