"""Camera rays in tiles: packets of four pixels by two instead of eight in a row.

A packet walk (:mod:`.structures.bvh.traverse_packet`) bounds eight rays together and
culls a node only where all of them miss it, so the tighter the eight, the more it culls
and the later its rays part. A user's camera rays come row after row; eight consecutive
ones span eight pixels of a row, a tile of :data:`TILE_COLUMNS` by :data:`TILE_ROWS`
four columns of two rows, whose directions spread about half as far. Packets of
neighbouring pixels rather than of a row's are how Wald, Slusallek, Benthin & Wagner
("Interactive Rendering with Coherent Ray Tracing", Eurographics 2001) trace primary
rays. The answers do not change, only which rays share a packet: each ray's hit is
still written to its own row.

:func:`image_row_length` recognises such a batch from its directions: neighbouring
rays of a row step alike, the step jumps back at the end of each row, and four by two
of its rays then spread less than eight in a row. The packet walk then takes the
places of the tile order (:func:`tile_ray`) as its threads' chunks, and reads each
packet in place, lanes 0-3 from one row and 4-7 from the next (:func:`lane_ray`).

With the 1024^2 camera rays put in tile order before the call (bvh-binned, two
threads, medians of seven rounds, time as given over time in tiles): full dragon
closest hit 1.18, any hit 1.20; forest-small-chair 1.17 and 1.10. The walk reading
tiles in place from the rows as given: full dragon 1.12 / 1.15, forest 1.04 / 0.99
(nine rounds, the rays put in tile order before the call 1.17 / 1.17 and 1.17 / 1.12
in the same run). Copying each span's rays into a buffer of the thread in tile order
instead cost more than it gained (full dragon 1.01 / 1.05, forest 0.86 / 0.67, with a
slower test for the row length then).
"""

from __future__ import annotations

import numpy as np

from ._jit import inline_kernel

__all__ = ["TILE_COLUMNS", "TILE_ROWS", "image_row_length", "tile_ray", "lane_ray"]

TILE_COLUMNS = 4
TILE_ROWS = 2
"""A packet's pixels: :data:`TILE_COLUMNS` columns of :data:`TILE_ROWS` rows."""
_LONGEST_ROW = 1 << 15
"""Rows longer than this are not looked for."""
_ROW_JUMP = 4.0
"""How many times the step before it the step from a row's last ray to the next row's first must be."""
_TIGHTER = 0.8
"""How much less than eight rays of a row the rays of a tile must spread for tiles to be used."""
_SAMPLED_TILES = 64


def _spread(directions: np.ndarray) -> np.ndarray:
    """The sum over the axes of the range of ``directions`` (..., k, 3) over its ``k`` rays."""
    return np.sum(directions.max(axis=-2) - directions.min(axis=-2), axis=-1)


def _first_row_length(directions: np.ndarray) -> int:
    """Where the squared step between consecutive directions first exceeds :data:`_ROW_JUMP`
    squared times the step before it, plus one; 0 when it does not within :data:`_LONGEST_ROW`
    rays. Steps along a row change slowly, even across a wide view (normalised directions step
    less toward its edges), and the step back to the next row's start is the row's width of
    them. Looked for in probes of growing length, so that a common image's first row is read
    once."""
    probed = 0
    for length in (1 << 10, 1 << 12, _LONGEST_ROW):
        probe = np.asarray(directions[max(0, probed - 1):min(len(directions), length + 1)], dtype=np.float64)
        if len(probe) < 3:
            return 0
        moves = np.diff(probe, axis=0)
        steps = np.einsum("ij,ij->i", moves, moves)
        if probed == 0 and not steps[0] > 0.0:
            return 0
        jumps = np.flatnonzero(steps[1:] > _ROW_JUMP ** 2 * steps[:-1])
        if len(jumps):
            return max(0, probed - 1) + int(jumps[0]) + 2
        probed = max(0, probed - 1) + len(probe) - 1
    return 0


def image_row_length(directions: np.ndarray, multiple: int = TILE_COLUMNS) -> int:
    """The length of the rows of a batch whose rays are an image's pixels row after row, as a
    camera's are, when its packets would be tighter in tiles of :data:`TILE_COLUMNS` x
    :data:`TILE_ROWS`; 0 when the batch is not laid out so, its rows are not a multiple of
    ``multiple`` long (a multiple of :data:`TILE_COLUMNS`), or it has fewer than two rows.

    The row length is where the step between consecutive directions first jumps to
    :data:`_ROW_JUMP` times the step before it or more; it is kept when, over up to
    :data:`_SAMPLED_TILES` places spread over the batch, the directions of a tile there
    spread at most :data:`_TIGHTER` times as far as eight of a row (medians): a batch
    that is not an image fails that test whatever its row length read."""
    n = len(directions)
    if n < 2 * TILE_COLUMNS + 1:
        return 0
    width = _first_row_length(directions)
    if width < 2 * TILE_COLUMNS or width % multiple or n < TILE_ROWS * width:
        return 0
    rows = n // width - (TILE_ROWS - 1)
    places = width // TILE_COLUMNS - 1
    sample = np.linspace(0, rows * places - 1, min(_SAMPLED_TILES, rows * places)).astype(np.int64)
    firsts = (sample // places) * width + (sample % places) * TILE_COLUMNS
    in_row = firsts[:, None] + np.arange(2 * TILE_COLUMNS)
    in_tile = (firsts[:, None] + (np.arange(TILE_ROWS)[:, None] * width + np.arange(TILE_COLUMNS)).ravel())
    row_spread = np.median(_spread(np.asarray(directions[in_row], dtype=np.float64)))
    tile_spread = np.median(_spread(np.asarray(directions[in_tile], dtype=np.float64)))
    return width if tile_spread <= _TIGHTER * row_spread else 0


@inline_kernel
def tile_ray(j, row_length):
    """The ray at place ``j`` of the tile order of an image whose rows are ``row_length`` long:
    tile after tile along each pair of rows (each tile's first row, then its second), the
    pairs of rows in turn."""
    pair_length = TILE_ROWS * row_length
    pair = j // pair_length
    place = j - pair * pair_length
    tile = place // (TILE_COLUMNS * TILE_ROWS)
    lane = place - tile * (TILE_COLUMNS * TILE_ROWS)
    return pair * pair_length + (lane // TILE_COLUMNS) * row_length + tile * TILE_COLUMNS + lane % TILE_COLUMNS


@inline_kernel
def lane_ray(first, lane, second):
    """The ray in lane ``lane`` of a packet whose lanes 0-3 are the rays from ``first`` on and
    lanes 4-7 those from ``second`` on (``first + 4`` for eight consecutive rays)."""
    return (first if lane < TILE_COLUMNS else second - TILE_COLUMNS) + lane
