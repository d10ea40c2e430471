"""``rayaccel compile``: the kernels of the chosen methods compiled (or found) ahead of use."""

from __future__ import annotations

import json

from rayaccel import precompile
from rayaccel.cli import main


def test_compile_command_records_what_it_compiled(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(precompile, "_stamp_path", lambda: tmp_path / "stamp.json")
    assert main(["--quiet", "compile", "none", "grid", "--kinds", "spheres", "--workers", "2"]) == 0
    assert "kernels of none, grid for spheres compiled" in capsys.readouterr().out
    stamp = json.loads((tmp_path / "stamp.json").read_text())
    assert sorted(map(tuple, stamp["compiled"])) == [("grid", 1), ("none", 1)]
    calls = []
    monkeypatch.setattr(precompile, "ProcessPoolExecutor", lambda *a, **k: calls.append(a))
    assert main(["--quiet", "compile", "grid", "none", "--kinds", "spheres"]) == 0
    assert calls == []


def test_compile_command_rejects_unknown_methods(capsys):
    assert main(["--quiet", "compile", "bsp"]) == 2
    assert "unknown method" in capsys.readouterr().err
