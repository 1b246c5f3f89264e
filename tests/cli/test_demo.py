"""`real2sim demo --quick`: the whole job end to end (asset -> Drake evaluation -> plots, report)."""

from __future__ import annotations

import csv

from real2sim.cli import main
from real2sim.cli.demo import QUICK


def test_quick_demo_builds_evaluates_and_reports(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--quick", "--out", str(out), "--jobs", "2"]) == 0
    stdout = capsys.readouterr().out
    assert "report.html" in stdout
    names = sorted(p.parent.name for p in (out / "bottle_asset").glob("*/model.urdf"))
    assert names == sorted(s.replace(":", "_").replace("+", "_") for s in QUICK.specs)
    with open(out / "results" / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    labels = {r["representation"] for r in rows}
    assert labels == {f"{n}_{c}" for n in names for c in QUICK.contact_models}
    for r in rows:
        assert int(r["runs_failed"]) == 0
        assert 0 <= float(r["ate_m"]) < 0.5 and float(r["sim_time_s"]) > 0
    assert len(list((out / "results").glob("pareto_*.png"))) == 4
    html = (out / "results" / "report.html").read_text()
    assert "coacd" in html and "<table" in html
