"""Camera rays in tiles: packets of four pixels by two instead of eight in a row.

A packet walk (:mod:`.structures.bvh.traverse_packet`) bounds eight rays together and
culls a node only where all of them miss it, so the tighter the eight, the more it culls
and the later its rays part. A user's camera rays come row after row; eight consecutive
ones span eight pixels of a row, a tile of :data:`TILE_COLUMNS` by :data:`TILE_ROWS`
four columns of two rows, whose directions spread 0.61 times as far (the sum over the
axes of their ranges, median of 1024 tiles of the benchmark's 1024^2 camera). Packets of
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
tiles in place from the rows as given: full dragon 1.12-1.14 / 1.15-1.16, forest
1.04-1.06 / 0.98-0.99 (three runs of nine to eleven rounds; the rays put in tile
order before the call 1.16-1.18 / 1.12-1.20 and 1.14-1.17 / 1.08-1.12 in the same
runs). Copying each span's rays into a buffer of the thread in tile order instead
cost more than it gained (full dragon 1.01 / 1.05, forest 0.86 / 0.67, with a slower
test for the row length then).
"""

from __future__ import annotations

import numpy as np

from ._jit import inline_kernel, kernel
from .selection import median_in_place

__all__ = ["TILE_COLUMNS", "TILE_ROWS", "image_row_length", "tile_ray", "first_tile", "next_tile", "lane_ray",
           "run_rays"]

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


@inline_kernel
def _squared_step(directions, i, apart=1):
    """The squared distance from direction ``i`` to direction ``i + apart``."""
    step = 0.0
    for axis in range(3):
        step += (np.float64(directions[i + apart, axis]) - np.float64(directions[i, axis])) ** 2
    return step


@kernel
def _first_row_length(directions, longest, jump):
    """Where the squared step between consecutive directions first exceeds ``jump`` squared times
    the step before it, plus one; 0 when the first step is zero or no such jump comes within
    ``longest`` rays. Steps along a row change slowly, even across a wide view (normalised
    directions step less toward its edges), and the step back to the next row's start is the
    row's width of them."""
    before = 0.0
    for i in range(min(directions.shape[0] - 1, longest)):
        step = _squared_step(directions, i)
        if i == 0 and not step > 0.0:
            return 0
        if i > 0 and step > jump * jump * before:
            return i + 1
        before = step
    return 0


@kernel
def _breaks_at_every_row(directions, width, jump):
    """Whether the squared step into every row ``width`` rays long exceeds ``jump`` squared times
    the step before it, as the step into the second row did (:func:`_first_row_length`)."""
    for row in range(2, directions.shape[0] // width):
        i = row * width - 1
        if not _squared_step(directions, i) > jump * jump * _squared_step(directions, i - 1):
            return False
    return True


@kernel
def _row_pairs_alike(directions, width, jump):
    """Whether the squared step from each even row's first ray to the next row's first ray (the two
    rows of a tile) stays within ``jump`` squared times that of the pair before it and the pair
    before it within as much of it: a batch of an image's rows with an odd number of rows left out
    somewhere pairs two rows from either side of the gap, whose tiles would span it."""
    before = 0.0
    for pair in range(directions.shape[0] // (TILE_ROWS * width)):
        step = _squared_step(directions, pair * TILE_ROWS * width, width)
        if pair > 0 and (step > jump * jump * before or before > jump * jump * step):
            return False
        before = step
    return True


@kernel
def _tile_and_row_spreads(directions, width, samples):
    """The medians, over ``samples`` tiles spread evenly over the image, of how far the directions
    of a tile spread and of how far eight consecutive ones of a row from the same pixel spread
    (the sum over the axes of their ranges)."""
    rows = directions.shape[0] // width - (TILE_ROWS - 1)
    places = width // TILE_COLUMNS - 1
    count = min(samples, rows * places)
    tile_spread = np.empty(count)
    row_spread = np.empty(count)
    for k in range(count):
        place = (k * (rows * places - 1)) // max(1, count - 1)
        first = (place // places) * width + (place % places) * TILE_COLUMNS
        tile_spread[k] = 0.0
        row_spread[k] = 0.0
        for axis in range(3):
            tile_lo, tile_hi = np.inf, -np.inf
            row_lo, row_hi = np.inf, -np.inf
            for lane in range(TILE_COLUMNS * TILE_ROWS):
                in_tile = np.float64(directions[first + (lane // TILE_COLUMNS) * width + lane % TILE_COLUMNS, axis])
                in_row = np.float64(directions[first + lane, axis])
                tile_lo, tile_hi = min(tile_lo, in_tile), max(tile_hi, in_tile)
                row_lo, row_hi = min(row_lo, in_row), max(row_hi, in_row)
            tile_spread[k] += tile_hi - tile_lo
            row_spread[k] += row_hi - row_lo
    return median_in_place(tile_spread), median_in_place(row_spread)


def image_row_length(directions: np.ndarray, multiple: int = TILE_COLUMNS) -> int:
    """The length of the rows of a batch whose rays are an image's pixels row after row, as a
    camera's are, when its packets would be tighter in tiles of :data:`TILE_COLUMNS` x
    :data:`TILE_ROWS`; 0 when the batch is not laid out so, its rows are not a multiple of
    ``multiple`` long (a multiple of :data:`TILE_COLUMNS`), or it has fewer than two rows.

    The row length is where the step between consecutive directions first jumps to
    :data:`_ROW_JUMP` times the step before it or more; it is kept when the steps into
    every later row jump so too, and, over up to :data:`_SAMPLED_TILES` places spread over
    the batch, the directions of a tile there spread at most :data:`_TIGHTER` times as far
    as eight of a row (medians): a batch that is not an image fails those tests whatever
    its row length read. A camera's rays with some left out (those that miss the scene's
    box, say) keep their first rows whole and passed the tiles' test alone: its tiles then
    paired rays from places far apart, whose packets crossed the whole tree (the forest's
    878,537 camera rays that miss its box, two threads, closest hit: 129 ms in such tiles,
    8 ms walked one by one). Whole rows left out keep the rows' steps alike, but an odd number of
    them before the gap pairs a row above it with one below it in every tile of that pair of rows;
    the steps between the first rays of each tile's two rows must then stay alike too
    (:func:`_row_pairs_alike`): the forest's 747,520 camera rays in the 730 image rows that miss its
    box (407 above it, 323 below; two threads, medians of 5) took 5.43 ms for an any hit and 6.33 ms
    for a closest hit in tiles, 1.91 and 2.76 ms as packets of a row's rays (2026-12-07). Four small
    kernels read the rays, each called only when the one before passes (a batch that is not an image
    compiles the first alone): 8 us for 1024^2 camera rays, of which the row check takes 4 (medians
    of 50, 2026-12-06), 72 us in a query, after its walk (2026-12-07); with two of the steps in NumPy,
    160 us. The check of the row pairs added 7.4 us (20.4 against 27.8 us, medians of 200, warm,
    2026-12-07)."""
    n = len(directions)
    if n < 2 * TILE_COLUMNS + 1:
        return 0
    width = _first_row_length(directions, _LONGEST_ROW, _ROW_JUMP)
    if width < 2 * TILE_COLUMNS or width % multiple or n < TILE_ROWS * width:
        return 0
    if not _breaks_at_every_row(directions, width, _ROW_JUMP) or not _row_pairs_alike(directions, width, _ROW_JUMP):
        return 0
    tile_spread, row_spread = _tile_and_row_spreads(directions, width, _SAMPLED_TILES)
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
def first_tile(ray_first, row_length, n_rays):
    """Where a chunk of the tile order from place ``ray_first`` starts, for :func:`next_tile`:
    ``(tiled_rays, first, column)``, the rays of the whole pairs of rows of ``n_rays`` rays in rows
    of ``row_length`` (0 when that is 0), and the ray and column of the place when it lies among
    them."""
    if row_length == 0:
        return 0, 0, 0
    tiled_rays = (n_rays // (TILE_ROWS * row_length)) * (TILE_ROWS * row_length)
    if ray_first >= tiled_rays:
        return tiled_rays, 0, 0
    first = tile_ray(ray_first, row_length)
    return tiled_rays, first, first % row_length


@inline_kernel
def next_tile(first, column, columns, row_length):
    """The ray and column ``columns`` columns on from ``first`` along its pair of rows, or the next
    pair's first ray at the end of it: the tile order without a division a step."""
    first += columns
    column += columns
    if column == row_length:
        return first + (TILE_ROWS - 1) * row_length, 0
    return first, column


@inline_kernel
def lane_ray(first, lane, second):
    """The ray in lane ``lane`` of a packet whose lanes 0-3 are the rays from ``first`` on and
    lanes 4-7 those from ``second`` on (``first + 4`` for eight consecutive rays)."""
    return (first if lane < TILE_COLUMNS else second - TILE_COLUMNS) + lane


@inline_kernel
def run_rays(first, second, n_rays, run_length, run):
    """The rays ``(first, end)`` of run ``run`` (0 or 1) of a tile or span of ``n_rays`` rays laid
    out as two runs of up to ``run_length`` rays, from ``first`` and from ``second`` on (a row
    apart in an image, or one after the other); the second run is empty when ``n_rays`` fits in
    the first."""
    if run == 0:
        return first, first + min(n_rays, run_length)
    return second, second + max(0, n_rays - run_length)
