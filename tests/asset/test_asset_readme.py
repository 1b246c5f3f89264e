"""Every asset folder carries its own README.md and preview.png (issue #65, part 6).

The bundled can built with two cheap representations (one cylinder fitted for a few iterations: the README
reports the fit, whatever its quality; the mesh itself), then rebuilt with another mass reusing the fit; the slow test reruns `run` over a
run folder from before the README existed.
"""

from __future__ import annotations

import json
import re
import shutil
import sys
from pathlib import Path

import pytest
from PIL import Image

from real2sim.asset.build import AssetConfig, build_asset
from real2sim.asset.export.writers import SIMULATOR_FILES
from real2sim.asset.readme import PREVIEW_NAME, PREVIEW_PANEL_PX, README_NAME, invocation, png_size
from real2sim.collision.fit.config import FitConfig
from real2sim.formats.spec import parse_spec

QUICK_FIT = FitConfig(max_iterations=20, min_iterations=10)


def _config(mass_kg: float, specs: tuple[str, ...]) -> AssetConfig:
    return AssetConfig(mass_kg=mass_kg, specs=tuple(parse_spec(s) for s in specs), formats=("urdf", "mjcf"),
                       fit_config=QUICK_FIT)


@pytest.fixture(scope="module")
def can_obj(tmp_path_factory) -> Path:
    from real2sim.geometry.objects import export_object

    return export_object("can", tmp_path_factory.mktemp("can") / "can.obj")


@pytest.fixture(scope="module")
def can_asset(can_obj, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("can_asset") / "asset"
    build_asset(can_obj, out, _config(0.35, ("cylinders:1", "mesh")))
    return out


def _fit_rows(readme: str) -> dict[str, list[str]]:
    section = readme.split("## Representations and their fit", 1)[1]
    rows = [line.strip("|").split("|") for line in section.splitlines() if line.startswith("| ")]
    return {cells[0].strip(): [c.strip() for c in cells] for cells in rows[1:]}


def test_readme_names_the_mass_the_simulator_files_and_each_representation(can_asset, can_obj):
    readme = (can_asset / README_NAME).read_text()
    config = json.loads((can_asset / "asset_config.json").read_text())
    assert "| mass | 0.35 kg |" in readme
    assert "uniform density from the measured mass 0.35 kg" in readme
    assert config["input_mesh_sha256"] in readme and str(can_obj) in readme
    assert f"real2sim {config['software']['real2sim']}" in readme
    # every simulator file the folder holds is named, and none it does not hold
    for name, _ in SIMULATOR_FILES.values():
        held = all((can_asset / rep / name).is_file() for rep in ("cylinders_1", "mesh"))
        assert (f"`{name}`" in readme) == held, name
    assert "`scene.xml`" in readme and "`model.sdf`" not in readme and "`model.usda`" not in readme
    rows = _fit_rows(readme)
    assert sorted(rows) == ["cylinders_1", "mesh"]
    for rep, cells in rows.items():
        report = json.loads((can_asset / rep / "fit_report.json").read_text())
        assert cells[1] == f"`{report['spec']}`" and cells[2] == str(report["num_primitives"])
        assert cells[3] == f"{report['iou']:.3f}" and cells[4] == f"{report['chamfer_mm']:.2f}"
        assert cells[6].endswith(" s") and cells[5] == report["method"]


def test_preview_is_a_png_of_the_size_the_readme_states(can_asset):
    preview = can_asset / PREVIEW_NAME
    with Image.open(preview) as image:
        image.verify()
    with Image.open(preview) as image:
        assert image.format == "PNG"
        size = image.size
    # the visual mesh and two representations, one row of square panels
    assert size == (3 * PREVIEW_PANEL_PX, PREVIEW_PANEL_PX) == png_size(preview)
    assert f"`{PREVIEW_NAME}` ({size[0]} x {size[1]} px)" in (can_asset / README_NAME).read_text()
    with Image.open(preview) as image:  # not a blank sheet: the panels hold the object
        assert len(set(image.convert("RGB").getdata())) > 50


def test_a_rebuild_that_reuses_a_fit_describes_what_the_folder_holds(can_asset, can_obj, tmp_path):
    out = tmp_path / "again"
    build_asset(can_obj, out, _config(0.4, ("cylinders:1",)), reuse_from=can_asset)
    readme = (out / README_NAME).read_text()
    rows = _fit_rows(readme)
    assert sorted(rows) == ["cylinders_1"] and "| mesh |" not in readme and "`mesh/" not in readme
    assert rows["cylinders_1"][6] == "reused from an earlier build"
    before = _fit_rows((can_asset / README_NAME).read_text())["cylinders_1"]
    assert rows["cylinders_1"][1:5] == before[1:5]  # the same fit, the same figures
    assert "| mass | 0.4 kg |" in readme
    assert png_size(out / PREVIEW_NAME) == (2 * PREVIEW_PANEL_PX, PREVIEW_PANEL_PX)


def test_invocation_is_the_command_line_of_the_real2sim_command(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/venv/bin/real2sim", "asset", "my can.obj", "--mass-kg", "0.35"])
    assert invocation() == "real2sim asset 'my can.obj' --mass-kg 0.35"
    monkeypatch.setattr(sys, "argv", ["/venv/bin/pytest", "-q"])
    assert invocation() is None


@pytest.mark.slow
def test_run_over_a_folder_from_before_the_readme_replaces_it_cleanly(tmp_path, capsys):
    """A run folder whose asset has no README.md or preview.png (and whose run.json never owned them):
    a rerun that rebuilds the asset writes both, owns them, and leaves the user's files alone."""
    from tests.cli_helpers import run_cli
    from tests.pipeline.test_rerun_keeps import FAST, _capture

    ds = _capture(tmp_path / "ds", ground_truth=False)
    out = tmp_path / "A"
    code, _, err = run_cli(capsys, "run", ds, "--mass-kg", "0.35", "--out", out, *FAST, "--collision", "spheres:4")
    assert code == 0, err
    (out / README_NAME).unlink()
    (out / PREVIEW_NAME).unlink()
    record = json.loads((out / ".run" / "run.json").read_text())
    for name in (README_NAME, PREVIEW_NAME):
        record["owned"].pop(name, None)
        for stage in record.get("stages", {}).values():
            if isinstance(stage, dict) and isinstance(stage.get("owned"), (list, dict)):
                stage["owned"] = type(stage["owned"])(n for n in stage["owned"] if n != name) \
                    if isinstance(stage["owned"], list) else {k: v for k, v in stage["owned"].items() if k != name}
    (out / ".run" / "run.json").write_text(json.dumps(record))
    (out / "MY_NOTES.txt").write_text("mine")
    code, _, err = run_cli(capsys, "run", ds, "--mass-kg", "0.36", "--out", out, *FAST, "--collision", "spheres:4")
    assert code == 0, err
    readme = (out / README_NAME).read_text()
    assert "| mass | 0.36 kg |" in readme and re.search(r"\| spheres_4 \| `spheres:4` \|", readme)
    assert "reused from an earlier build" in readme
    assert png_size(out / PREVIEW_NAME) == (2 * PREVIEW_PANEL_PX, PREVIEW_PANEL_PX)
    owned = json.loads((out / ".run" / "run.json").read_text())["owned"]
    assert README_NAME in owned and PREVIEW_NAME in owned and "MY_NOTES.txt" not in owned
    assert (out / "MY_NOTES.txt").read_text() == "mine"
    assert not [p.name for p in out.iterdir() if p.name.startswith(".") and p.name not in (".run", ".real2sim")]
    shutil.rmtree(out)
