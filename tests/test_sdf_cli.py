"""``rayaccel sdf``: the signed distance grid and its picture, end to end on a small resolution."""

from __future__ import annotations

import numpy as np
from PIL import Image

from rayaccel.cli import main


def test_sdf_writes_the_grid_and_the_slices(tmp_path, capsys):
    out = tmp_path / "sphere.npy"
    assert main(["--quiet", "sdf", "sphere", "--resolution", "24", "--out", str(out)]) == 0
    sdf = np.load(out)
    assert sdf.shape == (24, 24, 24)
    assert sdf.min() < 0 < sdf.max()
    assert sdf[12, 12, 12] < 0 and sdf[0, 0, 0] > 0
    assert "spacing" in capsys.readouterr().out
    image = np.asarray(Image.open(tmp_path / "sphere.png"))
    assert image.ndim == 3 and image.std() > 5


def test_sdf_bad_resolution(capsys):
    assert main(["--quiet", "sdf", "sphere", "--resolution", "1"]) != 0
    assert "resolution" in capsys.readouterr().err
