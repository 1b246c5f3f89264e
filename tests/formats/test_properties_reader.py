"""The one reader of properties files (``--properties``, physical_properties.json): every unphysical or
malformed field refused in one line naming the file and the field; a centre of mass outside the object
and a --mass-kg that disagrees with the file refused before any fitting."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from real2sim.asset.checks import COM_MARGIN_FRACTION, check_given_com
from real2sim.asset.config import MASS_AGREEMENT_RTOL, AssetConfig, mass_agreement_kg
from real2sim.plumbing.errors import UserInputError
from real2sim.formats.physical import (MAX_MASS_KG, PhysicalProperties, read_given_properties,
                                       read_physical_properties, write_physical_properties)
from real2sim.formats.spec import parse_spec
from real2sim.identify.solve import PARAMETER_NAMES
from tests.cli_helpers import run_cli

BOX_EXTENTS_M = (0.06, 0.08, 0.1)
INERTIA = [[5.5e-4, 0.0, 0.0], [0.0, 4.5e-4, 0.0], [0.0, 0.0, 3.3e-4]]


def identify_output(mass_kg: float = 0.40003, mass_se_kg: float = 2e-4, com_m=(0.0, 0.0, 0.01)) -> dict:
    """A props.json as `real2sim identify` writes it (identify/stage.py run_identify): mesh frame, standard errors."""
    return {"mass_kg": mass_kg, "com_m": list(com_m), "inertia_kg_m2": INERTIA,
            "method": "identified from joint torques (real2sim identify: weighted least squares, clarabel)",
            "samples_kept": 9000, "frame": "mesh",
            "identification": {"standard_errors": dict(zip(PARAMETER_NAMES, [mass_se_kg] + [1e-5] * 9)),
                               "parameters": dict(zip(PARAMETER_NAMES, [mass_kg] + [0.0] * 9)),
                               "condition_number": 3.0, "solver": "clarabel"}}


GOOD = {"mass_kg": 0.4, "com_m": [0.0, 0.0, 0.0], "inertia_kg_m2": INERTIA, "samples_kept": 10}


def _with(**fields) -> str:
    return json.dumps({**GOOD, **fields})


def _without(key: str) -> str:
    return json.dumps({k: v for k, v in GOOD.items() if k != key})


#: name -> (file bytes or text, what the one line must say: the field and what is wrong with it)
BAD = {
    "mass true": (_with(mass_kg=True), "mass_kg must be a JSON number"),
    "mass string": (_with(mass_kg="0.4"), "mass_kg must be a JSON number"),
    "mass NaN": (_with(mass_kg=float("nan")), "mass_kg must be a finite number > 0, got nan"),
    "mass Infinity": (_with(mass_kg=float("inf")), "mass_kg must be a finite number > 0"),
    "mass zero": (_with(mass_kg=0), "mass_kg must be a finite number > 0"),
    "mass negative": (_with(mass_kg=-0.4), "mass_kg must be a finite number > 0"),
    "mass over the --mass-kg range": (_with(mass_kg=MAX_MASS_KG * 1.001), f"mass_kg must be at most {MAX_MASS_KG:g} kg"),
    "mass missing": (_without("mass_kg"), "mass_kg is missing"),
    "com a string": (_with(com_m="123"), "com_m must be a list of 3 finite numbers"),
    "com two values": (_with(com_m=[0.0, 0.0]), "com_m must be a list of 3 finite numbers"),
    "com a bool": (_with(com_m=[0.0, 0.0, True]), "com_m must be a list of 3 finite numbers"),
    "com NaN": (_with(com_m=[0.0, float("nan"), 0.0]), "com_m must be a list of 3 finite numbers"),
    "inertia ragged": (_with(inertia_kg_m2=[[1e-4, 0, 0], [0, 1e-4], [0, 0, 1e-4]]), "inertia_kg_m2 must be 3 rows of 3"),
    "inertia 2x2": (_with(inertia_kg_m2=[[1e-4, 0], [0, 1e-4]]), "inertia_kg_m2 must be 3 rows of 3"),
    "inertia a string row": (_with(inertia_kg_m2=["1e-4", [0, 1e-4, 0], [0, 0, 1e-4]]), "inertia_kg_m2 must be 3 rows of 3"),
    "inertia all zero": (_with(inertia_kg_m2=[[0, 0, 0]] * 3), "inertia_kg_m2 is zero"),
    "inertia not symmetric": (_with(inertia_kg_m2=[[1e-4, 5e-5, 0], [0, 1e-4, 0], [0, 0, 1e-4]]),
                              "inertia_kg_m2 is not symmetric"),
    "inertia singular": (_with(inertia_kg_m2=[[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 0]]), "inertia_kg_m2 is not a physical"),
    "inertia negative moment": (_with(inertia_kg_m2=[[2e-4, 0, 0], [0, 2e-4, 0], [0, 0, -1e-5]]),
                                "inertia_kg_m2 is not a physical"),
    "inertia triangle inequality": (_with(inertia_kg_m2=[[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 5e-4]]),
                                    "break the triangle inequality"),
    "samples 1e999": (_without("samples_kept")[:-1] + ', "samples_kept": 1e999}', "samples_kept must be an integer >= 0"),
    "samples negative": (_with(samples_kept=-1), "samples_kept must be an integer >= 0"),
    "samples fractional": (_with(samples_kept=2.5), "samples_kept must be an integer >= 0"),
    "samples a bool": (_with(samples_kept=True), "samples_kept must be an integer >= 0"),
    "method not a string": (_with(method=3), "method must be a string"),
    "frame unknown": (_with(frame="robot"), "frame must be 'mesh' or 'asset'"),
    "mass standard error negative": (json.dumps({**identify_output(), "identification": {"standard_errors": {
        "mass_kg": -1.0}}}), "identification.standard_errors.mass_kg must be a finite number >= 0"),
    "not UTF-8": (b'{"mass_kg": 0.4, "method": "\xff\xfe"}', "not UTF-8"),
    "not JSON": ('{"mass_kg": 0.4, "com_m": [0, 0', "not JSON"),
    "not a JSON object": ("[0.4, [0, 0, 0]]", "not a JSON object"),
    "nested too deep": ("[" * 100_000 + "]" * 100_000, "nested too deep"),
}


def _write(path, content) -> None:
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)


def _one_line(code: int, err: str) -> str:
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def box_obj(tmp_path_factory):
    path = tmp_path_factory.mktemp("box") / "box.obj"
    trimesh.creation.box(extents=BOX_EXTENTS_M).export(path)
    return path


@pytest.mark.parametrize("case", sorted(BAD))
def test_asset_refuses_a_bad_properties_file_in_one_line(tmp_path, capsys, box_obj, case):
    content, needle = BAD[case]
    props = tmp_path / "props.json"
    _write(props, content)
    code, _, err = run_cli(capsys, "asset", box_obj, "--properties", props, "--out", tmp_path / "asset",
                           "--collision", "mesh")
    line = _one_line(code, err)
    assert needle in line and "--properties" in line and str(props) in line, line
    assert not (tmp_path / "asset").exists()


@pytest.mark.parametrize("case", sorted(BAD))
def test_read_physical_properties_refuses_with_the_same_rules(tmp_path, case):
    content, needle = BAD[case]
    path = tmp_path / "physical_properties.json"
    _write(path, content)
    with pytest.raises(UserInputError) as caught:
        read_physical_properties(path)
    message = str(caught.value)
    assert needle in message and str(path) in message and "\n" not in message, message


def test_a_missing_file_is_one_line(tmp_path):
    with pytest.raises(UserInputError, match="does not exist"):
        read_given_properties(tmp_path / "nope.json")


def test_identify_output_is_read_with_its_mass_standard_error(tmp_path):
    path = tmp_path / "props.json"
    path.write_text(json.dumps(identify_output()))
    props, frame = read_given_properties(path)
    assert frame == "mesh" and props.mass_kg == 0.40003 and props.samples_kept == 9000
    assert props.mass_standard_error_kg == 2e-4 and props.com_m == (0.0, 0.0, 0.01)
    np.testing.assert_array_equal(props.inertia, INERTIA)


def test_a_written_physical_properties_json_reads_back(tmp_path):
    path = tmp_path / "physical_properties.json"
    written = PhysicalProperties(mass_kg=0.4, com_m=(0.001, 0.0, -0.002), inertia_kg_m2=tuple(map(tuple, INERTIA)),
                                 samples_kept=12345)
    write_physical_properties(written, path, {"source": "x", "uniform_density": written.to_json()})
    assert "mass_standard_error_kg" not in json.loads(path.read_text())  # none given, none written
    assert read_physical_properties(path) == written
    assert read_given_properties(path) == (written, "asset")


def test_mass_within_three_standard_errors_or_the_relative_tolerance_agrees():
    specs = (parse_spec("mesh"),)
    identified = PhysicalProperties(0.40003, (0.0, 0.0, 0.0), tuple(map(tuple, INERTIA)), mass_standard_error_kg=2e-4)
    AssetConfig(mass_kg=0.4, specs=specs, given_properties=identified)  # 3e-5 kg apart: one mass
    wide = PhysicalProperties(0.41, (0.0, 0.0, 0.0), tuple(map(tuple, INERTIA)), mass_standard_error_kg=5e-3)
    assert mass_agreement_kg(wide) == pytest.approx(0.015)
    AssetConfig(mass_kg=0.4, specs=specs, given_properties=wide)  # 0.01 kg apart, within 3 x 5 g
    exact = PhysicalProperties(0.41, (0.0, 0.0, 0.0), tuple(map(tuple, INERTIA)))
    assert mass_agreement_kg(exact) == pytest.approx(MASS_AGREEMENT_RTOL * 0.41)
    with pytest.raises(UserInputError) as caught:
        AssetConfig(mass_kg=0.4, specs=specs, given_properties=exact)
    assert "3 x its standard error" in str(caught.value) and "0.1 % of it" in str(caught.value)


def test_com_margin_is_a_tenth_of_the_largest_extent():
    box = trimesh.creation.box(extents=BOX_EXTENTS_M).vertices  # z spans -0.05 .. 0.05 m; margin 0.01 m
    assert COM_MARGIN_FRACTION == 0.1

    def config(com):
        props = PhysicalProperties(0.4, com, tuple(map(tuple, INERTIA)))
        return AssetConfig(mass_kg=0.4, specs=(parse_spec("mesh"),), given_properties=props,
                           given_properties_frame="mesh", given_properties_source="props.json")

    check_given_com(config((0.0, 0.0, 0.0595)), box, "box.obj")
    check_given_com(config((-0.0395, 0.0, 0.0)), box, "box.obj")
    with pytest.raises(UserInputError, match=r"--properties props.json: the centre of mass .* lies outside box.obj"):
        check_given_com(config((0.0, 0.0, 0.0605)), box, "box.obj")


@pytest.mark.parametrize("frame", ["mesh", "asset"])
def test_asset_refuses_a_com_outside_the_object_before_fitting(tmp_path, capsys, box_obj, frame):
    props = identify_output(com_m=(0.0, 0.0, 0.2))  # 0.15 m above a 0.1 m tall box
    if frame == "asset":
        del props["frame"]
    path = tmp_path / "props.json"
    path.write_text(json.dumps(props))
    cache = tmp_path / "sdf_cache"
    code, _, err = run_cli(capsys, "asset", box_obj, "--properties", path, "--out", tmp_path / "asset",
                           "--collision", "spheres:8", "--sdf-cache", cache)
    line = _one_line(code, err)
    assert f"--properties {path}" in line and "centre of mass" in line and "10 % of its largest extent" in line, line
    assert not (tmp_path / "asset").exists()
    assert not cache.exists() or not any(cache.rglob("*"))  # nothing was sampled for a fit


@pytest.fixture(scope="module")
def identified_asset(tmp_path_factory, box_obj):
    """An asset built with --mass-kg 0.4 and identify's 0.40003 +- 0.0002 kg: (props.json, asset folder, stderr)."""
    import contextlib
    import io

    from real2sim.cli import main

    root = tmp_path_factory.mktemp("identified")
    path = root / "props.json"
    path.write_text(json.dumps(identify_output()))
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["asset", str(box_obj), "--mass-kg", "0.4", "--properties", str(path), "--out", str(root / "asset"),
                     "--collision", "mesh"])
    assert code == 0, err.getvalue()
    return path, root / "asset"


def test_asset_builds_with_a_mass_that_agrees_within_the_standard_error(identified_asset):
    _, asset = identified_asset
    written = read_physical_properties(asset / "physical_properties.json")  # the asset's own file reads back
    assert written.mass_kg == 0.40003 and written.mass_standard_error_kg == 2e-4


def test_a_mass_further_than_three_standard_errors_is_refused(tmp_path, capsys, box_obj, identified_asset):
    path, _ = identified_asset
    code, _, err = run_cli(capsys, "asset", box_obj, "--mass-kg", "0.401", "--properties", path, "--out",
                           tmp_path / "asset", "--collision", "mesh")
    line = _one_line(code, err)
    assert "disagrees with the properties' mass" in line and "3 x its standard error, 0.0002 kg" in line, line
    assert not (tmp_path / "asset").exists()


def test_identify_shape_reads_the_asset_through_the_one_reader(tmp_path, identified_asset):
    import shutil

    from real2sim.identify.shape import shape_prior_from_asset

    _, asset = identified_asset
    broken = tmp_path / "asset"
    shutil.copytree(asset, broken)
    record = json.loads((broken / "physical_properties.json").read_text())
    (broken / "physical_properties.json").write_text(json.dumps({**record, "mass_kg": True}))
    with pytest.raises(UserInputError, match=r"--shape .*physical_properties.json: mass_kg must be a JSON number"):
        shape_prior_from_asset(broken)
