"""The command line: every subcommand end to end on small inputs, and one-line errors."""

from __future__ import annotations

import numpy as np
from PIL import Image

from rayaccel.cli import main


def test_render_with_heatmaps(tmp_path, capsys):
    out = tmp_path / "balls.png"
    assert main(["--quiet", "render", "spheres:300", "--method", "grid", "--size", "48", "--heatmap", "both",
                 "--out", str(out), "-o", "density=4", "-o", "insert=exact"]) == 0
    image = np.asarray(Image.open(out))
    assert image.shape == (48, 48, 3) and image.std() > 5
    assert (tmp_path / "balls-nodes.png").exists() and (tmp_path / "balls-tests.png").exists()
    assert "Mrays/s" in capsys.readouterr().out


def test_render_with_camera_and_lights(tmp_path):
    out = tmp_path / "teapot.png"
    assert main(["--quiet", "render", "teapot", "--size", "32", "--eye", "0,3,9", "--target", "0,1,0",
                 "--light", "5,5,5", "--light=-5,5,5", "--out", str(out)]) == 0
    assert out.exists()


def test_stats(capsys):
    assert main(["--quiet", "stats", "dragon-11k", "--method", "grid"]) == 0
    out = capsys.readouterr().out
    assert "references" in out and "expected_cost" in out and "avg_nodes_per_ray" in out


def test_demo(tmp_path, capsys):
    assert main(["--quiet", "demo", "--scene", "teapot", "--size", "40", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "grid.png").exists() and (tmp_path / "none.png").exists()
    out = capsys.readouterr().out
    assert "grid" in out and "none" in out


def test_experiment(tmp_path, capsys):
    assert main(["--quiet", "experiment", "grid-vs-none", "--max-n", "1000", "--size", "24",
                 "--out", str(tmp_path)]) == 0
    table = (tmp_path / "grid-vs-none.md").read_text()
    assert "| 1,000 |" in table and "| 10 |" in table
    assert (tmp_path / "grid-vs-none.png").exists()


def test_methods(capsys):
    assert main(["methods"]) == 0
    assert "grid" in capsys.readouterr().out


def test_errors_are_one_line(tmp_path, capsys):
    assert main(["--quiet", "render", str(tmp_path / "missing.obj")]) == 2
    assert main(["--quiet", "render", "spheres:10", "--method", "bsp"]) == 2
    assert main(["--quiet", "render", "spheres:10", "-o", "bogus=1"]) == 2
    assert main(["--quiet", "render", "spheres:10", "--eye", "1,2"]) == 2
    err = capsys.readouterr().err
    assert err.count("rayaccel: error:") == 4
    assert all(line.startswith("rayaccel: error:") for line in err.strip().splitlines())


def test_bvh_experiment(tmp_path):
    assert main(["--quiet", "experiment", "bvh", "--scenes", "spheres:300", "--size", "16",
                 "--out", str(tmp_path)]) == 0
    table = (tmp_path / "bvh.md").read_text()
    for method in ("bvh-agglomerative", "bvh-median-space", "bvh-median-object", "bvh-sah", "bvh-binned", "bvh-lbvh"):
        assert method in table
        assert (tmp_path / f"bvh-heatmap-spheres-300-{method}.png").exists()
    assert (tmp_path / "bvh.png").exists()


def test_bounding_volume_experiment(tmp_path):
    assert main(["--quiet", "experiment", "bounding-volumes", "--scenes", "dragon-11k", "--size", "16",
                 "--out", str(tmp_path)]) == 0
    table = (tmp_path / "bounding-volumes.md").read_text()
    assert "14-DOP" in table and "sphere (Ritter over primitives)" in table and "aabb" in table
    assert (tmp_path / "bounding-volumes.png").exists()


def test_grid_resolution_experiment(tmp_path):
    assert main(["--quiet", "experiment", "grid-resolution", "--scenes", "spheres:500", "--size", "16",
                 "--out", str(tmp_path)]) == 0
    table = (tmp_path / "grid-resolution.md").read_text()
    assert "cost model optimum" in table and "| spheres:500 | 64 |" in table
    assert (tmp_path / "grid-resolution.png").exists()


def test_kdtree_table_experiment(tmp_path):
    assert main(["--quiet", "experiment", "kdtree-table", "--scenes", "cornell-box", "spheres:300", "--size", "16",
                 "--out", str(tmp_path)]) == 0
    table = (tmp_path / "kdtree-table-kdtree.md").read_text()
    from rayaccel.experiments.kdtree_table import ROWS

    for label, _, _ in ROWS:
        assert f"| {label} |" in table
    assert "| cornell-box | spheres:300 |" in table
    assert (tmp_path / "kdtree-table-kdtree.png").exists()
    assert main(["--quiet", "experiment", "kdtree-table", "--method", "octree", "--scenes", "cornell-box",
                 "--size", "16", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "kdtree-table-octree.md").exists()
    assert main(["--quiet", "experiment", "kdtree-table", "--method", "bsp", "--out", str(tmp_path)]) == 2


def test_structures_and_leaf_size_experiments(tmp_path):
    assert main(["--quiet", "experiment", "structures", "--scenes", "spheres:300", "--size", "16",
                 "--out", str(tmp_path)]) == 0
    table = (tmp_path / "structures-spheres-300.md").read_text()
    for method in ("grid", "hgrid", "grid-bvh", "kdtree", "octree", "bvh-binned"):
        assert f"| {method} |" in table
        assert (tmp_path / f"structures-spheres-300-{method}-nodes.png").exists()
    assert main(["--quiet", "experiment", "leaf-size", "--scenes", "cornell-box", "--size", "16",
                 "--out", str(tmp_path)]) == 0
    table = (tmp_path / "leaf-size.md").read_text()
    assert "| cornell-box | kdtree | 32 |" in table and "| cornell-box | bvh-binned | 1 |" in table
    assert (tmp_path / "leaf-size.png").exists()
