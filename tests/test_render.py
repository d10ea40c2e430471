"""The renderer: a sample of pixels renders exactly as in the whole frame."""

from __future__ import annotations

import numpy as np
import pytest

import rayaccel as ra
from rayaccel.render import render


def test_rendering_a_pixel_subset_matches_the_whole_frame(spheres):
    grid = ra.build(spheres, "grid")
    whole = render(grid, width=40, height=30)
    subset = np.random.default_rng(0).choice(40 * 30, 500, replace=False)
    sample = render(grid, width=40, height=30, pixels=subset)
    chosen = np.zeros(40 * 30, dtype=bool)
    chosen[subset] = True
    np.testing.assert_array_equal(sample.image.reshape(-1, 3)[chosen], whole.image.reshape(-1, 3)[chosen])
    np.testing.assert_array_equal(sample.nodes.ravel()[chosen], whole.nodes.ravel()[chosen])
    assert not sample.image.reshape(-1, 3)[~chosen].any() and not sample.tests.ravel()[~chosen].any()
    assert sample.primary_rays == 500 and whole.primary_rays == 1200


@pytest.mark.parametrize("pixels", [[0, 1200], [-1, 3]])
def test_render_rejects_pixels_outside_the_image(spheres, pixels):
    with pytest.raises(ValueError, match="pixels"):
        render(ra.build(spheres, "grid"), width=40, height=30, pixels=pixels)
