"""The Python front door: `import real2sim; real2sim.build_asset(...)` as the README shows it."""

from __future__ import annotations

import subprocess
import sys

import pytest

import real2sim
from tests.cli_helpers import run_cli


@pytest.fixture(scope="module")
def can_obj(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mesh")
    from real2sim.cli import main

    assert main(["objects", "export", "can", str(folder / "can.obj")]) == 0
    return folder / "can.obj"


def test_build_asset_from_python(can_obj, tmp_path):
    asset = real2sim.build_asset(can_obj, tmp_path / "can_asset", mass_kg=0.4, collision=["spheres:4", "boxes:2"],
                                 formats=["urdf", "mjcf"], max_iterations=30)
    assert [r.name for r in asset.representations] == ["spheres_4", "boxes_2"]
    assert asset.physical_properties.mass_kg == pytest.approx(0.4)
    assert asset.model_for("drake") == tmp_path / "can_asset" / "spheres_4" / "model.urdf"
    assert asset["boxes:2"].model_for("mujoco").name == "scene.xml"
    assert asset["boxes_2"].fit_report["num_primitives"] == 2
    with pytest.raises(real2sim.UserInputError, match="--format usd"):
        asset.model_for("isaac")
    again = real2sim.load_asset(tmp_path / "can_asset")
    assert again.representations == asset.representations


@pytest.mark.parametrize("kwargs, words", [
    ({"collision": "cylinders:abc"}, "malformed collision SPEC"),
    ({"collision": []}, "at least one SPEC"),
    ({"formats": ["obj"]}, "unknown format"),
    ({"mass_kg": None}, "mass_kg is required"),
])
def test_a_bad_argument_is_the_clis_one_line(can_obj, tmp_path, kwargs, words):
    args = {"mass_kg": 0.4, **kwargs}
    with pytest.raises(real2sim.UserInputError, match=words):
        real2sim.build_asset(can_obj, tmp_path / "x", **args)
    assert not (tmp_path / "x").exists()


def test_the_same_spec_mistake_reads_the_same_on_the_command_line(can_obj, tmp_path, capsys):
    with pytest.raises(real2sim.UserInputError) as caught:
        real2sim.build_asset(can_obj, tmp_path / "x", mass_kg=0.4, collision="cylinders:abc")
    code, _, err = run_cli(capsys, "asset", can_obj, "--mass-kg", "0.4", "--collision", "cylinders:abc",
                           "--out", tmp_path / "y")
    assert code == 2 and str(caught.value) in err


def test_import_real2sim_stays_light():
    code = ("import sys, real2sim\n"
            "print(sorted(m for m in ('torch', 'pydrake', 'trimesh', 'real2sim.api') if m in sys.modules))\n"
            "print(sorted(real2sim.__all__))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[0] == "[]"
    assert "build_asset" in out.splitlines()[1]
