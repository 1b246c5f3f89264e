"""`real2sim view`: serves an asset in Meshcat (loopback only) and exits after --seconds."""

from __future__ import annotations

from real2sim.cli import main
from real2sim.geometry.objects import export_object


def test_view_serves_asset_then_exits(tmp_path, capsys):
    mesh = export_object("can", tmp_path / "can" / "model.obj")
    asset = tmp_path / "asset"
    assert main(["asset", str(mesh), "--mass", "0.35", "--out", str(asset), "--collision", "mesh"]) == 0
    capsys.readouterr()
    assert main(["view", str(asset), "--seconds", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "mesh/model.urdf" in out and "http://" in out


def test_view_bad_input(tmp_path, capsys):
    assert main(["view", str(tmp_path / "nope")]) == 2
    assert "asset folder not found" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["view", str(tmp_path / "empty")]) == 2
    assert "no representation" in capsys.readouterr().err
