"""Camera rays walked in tiles of four pixels by two (:mod:`rayaccel.ray_tiles`) give each ray the
hit brute force gives it, and only image-shaped batches are walked so."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_counts_and_lists_match, assert_same_hits, random_rays

import rayaccel as ra
from rayaccel.ray_tiles import (
    TILE_COLUMNS,
    TILE_ROWS,
    first_tile,
    image_row_length,
    lane_ray,
    next_tile,
    tile_ray,
)
from rayaccel.structures.bvh import accelerator as bvh_accelerator
from rayaccel.structures.bvh.traverse_packet import SPAN
from rayaccel.structures.kdtree import accelerator as kdtree_accelerator


def image_rays(scene, width, height, fov=40.0):
    b = scene.bounds()
    return ra.Camera.framing(b.scene_lo, b.scene_hi, fov=fov).rays(width, height)


@pytest.mark.parametrize("width, height", [(64, 48), (96, 21), (32, 16), (1024, 768)])
def test_an_image_is_recognised_by_its_rows(width, height):
    directions = image_rays(ra.load_scene("bunny"), width, height)[1]
    assert image_row_length(directions) == width
    assert image_row_length(directions, SPAN // TILE_ROWS) == width
    assert image_row_length(directions.astype(np.float32)) == width


def test_batches_that_are_not_images_are_walked_as_given(spheres):
    directions = image_rays(spheres, 64, 48)[1]
    rng = np.random.default_rng(0)
    assert image_row_length(directions[rng.permutation(len(directions))]) == 0
    assert image_row_length(random_rays(spheres, 5000)[1]) == 0
    assert image_row_length(np.repeat([[0.0, 0.0, 1.0]], 4096, axis=0)) == 0
    assert image_row_length(directions[:64]) == 0
    assert image_row_length(image_rays(spheres, 36, 20)[1], SPAN // TILE_ROWS) == 0
    assert image_row_length(image_rays(spheres, 6, 40)[1]) == 0
    tiles = directions.reshape(24, 2, 16, 4, 3).transpose(0, 2, 1, 3, 4).reshape(-1, 3)
    assert image_row_length(tiles) == 0


def test_an_image_with_rays_left_out_is_not_taken_for_one(spheres):
    """A camera's rays with a patch in the middle of the image left out (those that meet an object,
    say) keep their first rows whole, but their later rows no longer start where the first row's
    length says: tiles there would pair rays from far apart. Whole rows left out keep an image, unless
    an odd number of rows before the gap pairs a row above it with one below it in a tile."""
    directions = image_rays(spheres, 64, 48)[1].reshape(48, 64, 3)
    patch = np.zeros((48, 64), dtype=bool)
    patch[20:30, 24:40] = True
    assert image_row_length(directions[~patch]) == 0
    assert image_row_length(directions[np.r_[0:20, 30:48]].reshape(-1, 3)) == 64
    assert image_row_length(directions[np.r_[0:21, 30:48]].reshape(-1, 3)) == 0
    assert image_row_length(directions[np.r_[0:1, 9:48]].reshape(-1, 3)) == 0


@pytest.mark.parametrize("row_length", [8, 32, 1024])
def test_tile_order_visits_every_ray_of_whole_row_pairs_once(row_length):
    n = 3 * TILE_ROWS * row_length
    order = np.array([tile_ray(j, row_length) for j in range(n)])
    assert sorted(order) == list(range(n))
    packets = order.reshape(-1, TILE_COLUMNS * TILE_ROWS)
    rows, columns = packets // row_length, packets % row_length
    assert (np.ptp(rows, axis=1) == TILE_ROWS - 1).all() and (np.ptp(columns, axis=1) == TILE_COLUMNS - 1).all()
    firsts = packets[:, 0]
    lanes = np.array([[lane_ray(first, lane, first + row_length) for lane in range(8)] for first in firsts])
    np.testing.assert_array_equal(lanes, packets)
    assert [lane_ray(40, lane, 44) for lane in range(8)] == list(range(40, 48))


@pytest.mark.parametrize("row_length, columns", [(8, 4), (32, 4), (64, 32), (1024, 32)])
def test_tile_stepping_from_any_chunk_start_follows_the_tile_order(row_length, columns):
    """The walks step through the tile order without dividing (:func:`first_tile`,
    :func:`next_tile`), ``columns`` columns a step, from wherever a chunk starts; the rays of a
    last odd row lie beyond the tiled ones."""
    n = 5 * row_length + 3
    tiled_rays = 2 * TILE_ROWS * row_length
    step = columns * TILE_ROWS
    for chunk_first in range(0, tiled_rays, step):
        found, first, column = first_tile(chunk_first, row_length, n)
        assert found == tiled_rays
        for place in range(chunk_first, tiled_rays, step):
            assert first == tile_ray(place, row_length) and column == first % row_length
            first, column = next_tile(first, column, columns, row_length)
    assert first_tile(tiled_rays, row_length, n) == (tiled_rays, 0, 0)
    assert first_tile(0, 0, n) == (0, 0, 0)


@pytest.fixture
def tiles_seen(monkeypatch):
    """The row lengths the packet walks of the BVH and the kd-tree were given, call by call."""
    seen = []

    def spy(directions, multiple=TILE_COLUMNS):
        seen.append(image_row_length(directions, multiple))
        return seen[-1]

    for module in (bvh_accelerator, kdtree_accelerator):
        monkeypatch.setattr(module, "image_row_length", spy)
    return seen


@pytest.mark.parametrize("method", ["bvh-binned", "kdtree"])
@pytest.mark.parametrize("width, height, fov", [(64, 48, 30.0), (128, 65, 40.0), (96, 23, 70.0), (32, 33, 70.0)])
@pytest.mark.parametrize("limits", ["shared", "per ray"])
def test_tiled_camera_rays_match_brute_force(small_dragon, tiles_seen, method, width, height, fov, limits):
    """Images with whole pairs of rows and ones with a last row left over, which walks as given;
    narrow views, whose packets are bounded as a whole, and wide ones, whose neighbours head too
    far apart for that and are tested lane by lane; whole spans that miss the model; per-ray
    limits read in tile order too."""
    origins, directions = image_rays(small_dragon, width, height, fov=fov)
    t_min, t_max = 0.0, np.inf
    if limits == "per ray":
        rng = np.random.default_rng(5)
        t_min = rng.uniform(0.0, 0.5, len(origins))
        t_max = np.where(rng.random(len(origins)) < 0.5, np.inf, rng.uniform(0.6, 1.2, len(origins)))
    brute, packets = ra.build(small_dragon, "none"), ra.build(small_dragon, method)
    reference = brute.intersect(origins, directions, t_min, t_max)
    assert reference.hit.any() and not reference.hit.all()
    assert_same_hits(reference, packets.intersect(origins, directions, t_min, t_max))
    np.testing.assert_array_equal(packets.occluded(origins, directions, t_min, t_max), reference.hit)
    assert tiles_seen == [width, width]
    assert_counts_and_lists_match(brute, packets, origins, directions)


def test_tiled_float32_rays_match_their_float64_copy(small_dragon, tiles_seen):
    """The BVH reads float32 rays as they are, in tiles too."""
    origins, directions = image_rays(small_dragon, 64, 40)
    narrow_o, narrow_d = origins.astype(np.float32), directions.astype(np.float32)
    bvh = ra.build(small_dragon, "bvh-binned")
    assert_same_hits(bvh.intersect(narrow_o.astype(np.float64), narrow_d.astype(np.float64)),
                     bvh.intersect(narrow_o, narrow_d))
    assert tiles_seen == [64, 64]


@pytest.mark.parametrize("place", ["first tile", "second row of a tile", "last pair of rows"])
def test_an_unusable_ray_in_a_tile_is_named(small_dragon, tiles_seen, place):
    """The BVH's packet walk checks the rays it reads, in tiles too."""
    origins, directions = image_rays(small_dragon, 64, 40)
    bad = {"first tile": 1, "second row of a tile": 64 + 2, "last pair of rows": 38 * 64 + 37}[place]
    directions[bad] = 0.0
    bvh = ra.build(small_dragon, "bvh-binned")
    with pytest.raises(ValueError, match=f"first at index {bad}"):
        bvh.intersect(origins, directions)
    with pytest.raises(ValueError, match=f"first at index {bad}"):
        bvh.occluded(origins, directions)


def test_tiles_follow_chunks_of_any_length(small_dragon, tiles_seen, monkeypatch):
    """The threads' chunks start on whole spans, whatever length the batch gives them: a span
    read from the middle of a tile would pair the wrong rays."""
    from rayaccel.structures import base
    monkeypatch.setattr(base, "RAY_CHUNK", 100)
    monkeypatch.setattr(base, "CHUNKS_PER_THREAD", 5)
    origins, directions = image_rays(small_dragon, 64, 41)
    single = ra.build(small_dragon, "bvh-binned", packets=False)
    packets = ra.build(small_dragon, "bvh-binned")
    assert_same_hits(single.intersect(origins, directions), packets.intersect(origins, directions))
    np.testing.assert_array_equal(single.occluded(origins, directions), packets.occluded(origins, directions))
    assert tiles_seen == [64, 64]


@pytest.mark.parametrize("width, height", [(36, 30), (64, 40)])
def test_kdtree_tiles_rows_of_any_multiple_of_four(small_dragon, tiles_seen, monkeypatch, width, height):
    """The binary kd-tree walk's packets have no spans: rows of any multiple of four pixels go in
    tiles, over chunks of any length; packets whose rays head apart (rays through a wide view) take
    the single walk, each of their two rows."""
    from rayaccel.structures import base
    monkeypatch.setattr(base, "RAY_CHUNK", 100)
    monkeypatch.setattr(base, "CHUNKS_PER_THREAD", 5)
    origins, directions = image_rays(small_dragon, width, height, fov=120.0)
    single = ra.build(small_dragon, "kdtree", width=2, packets=False)
    packets = ra.build(small_dragon, "kdtree", width=2)
    assert_same_hits(single.intersect(origins, directions), packets.intersect(origins, directions))
    np.testing.assert_array_equal(single.occluded(origins, directions), packets.occluded(origins, directions))
    assert tiles_seen == [width, width]
