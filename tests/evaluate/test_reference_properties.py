"""A reference with its own mass properties: the true object simulated as it is (issue: truth dynamics)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from real2sim.evaluate.sweep import EvaluationConfig, evaluate
from real2sim.plumbing.errors import UserInputError
from real2sim.formats.physical import PhysicalProperties, read_physical_properties, write_physical_properties
from tests.evaluate.test_sweep import SHORT_SCENE, make_box_asset

PUSH = EvaluationConfig(tasks=("push",), contact_models=("point",), runs=1, jobs=1, scene=SHORT_SCENE)


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> Path:
    return make_box_asset(tmp_path_factory.mktemp("refprops") / "box", reps=("boxes_1",))


def _ocae(result) -> float:
    (row,) = result.runs
    assert not row["error"], row["error"]
    return row["ocae_m"]


def test_reference_properties_are_the_ones_simulated(box, tmp_path):
    default = evaluate([box], tmp_path / "default", PUSH)
    same = evaluate([box], tmp_path / "same", PUSH,
                    reference_properties=box / "physical_properties.json")
    assert _ocae(same) == _ocae(default)  # the asset's own properties, given explicitly: the same sweep
    props = read_physical_properties(box / "physical_properties.json")
    heavier_side = PhysicalProperties(props.mass_kg, (0.012, 0.0, -0.01), props.inertia_kg_m2)
    other = tmp_path / "other_physical_properties.json"
    write_physical_properties(heavier_side, other)
    moved = evaluate([box], tmp_path / "moved", PUSH, reference_properties=other)
    assert _ocae(moved) != pytest.approx(_ocae(default), rel=1e-3)  # another object moves otherwise
    record = json.loads((tmp_path / "moved" / "config.json").read_text())
    assert record["reference_properties"]["file"] == other.name and len(record["reference_properties"]["sha1"]) == 40
    assert json.loads((tmp_path / "default" / "config.json").read_text())["reference_properties"] == "asset"
    # A resume may not mix references with different mass properties.
    with pytest.raises(UserInputError, match="reference_properties"):
        evaluate([box], tmp_path / "moved", PUSH)


def test_reference_properties_are_checked_and_belong_to_one_asset(box, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"mass_kg": float("nan"), "com_m": [0, 0, 0], "inertia_kg_m2": np.eye(3).tolist()}))
    with pytest.raises(UserInputError, match="bad.json"):
        evaluate([box], tmp_path / "r1", PUSH, reference_properties=bad)
    other = make_box_asset(tmp_path / "box2", reps=("boxes_1",))
    with pytest.raises(UserInputError, match="one object"):
        evaluate([box, other], tmp_path / "r2", PUSH,
                 reference_properties=box / "physical_properties.json")
    assert not (tmp_path / "r1").exists() and not (tmp_path / "r2").exists()


def test_cli_reference_inertia_from_the_reference_mesh(box, tmp_path, capsys):
    import trimesh

    from real2sim.cli import main

    common = ["evaluate", str(box), "--tasks", "push", "--contact", "point", "--runs", "1", "--jobs", "1",
              "--duration-scale", "0.2"]
    assert main(common + ["--out", str(tmp_path / "r0"), "--reference-inertia", "mesh"]) == 2
    assert "--reference" in capsys.readouterr().err
    # A true object 20 % longer than the asset's box: its own inertia, not the asset's.
    longer = trimesh.load(box / "visual" / "model.obj", force="mesh")
    longer.apply_scale((1.2, 1.0, 1.0))
    longer.export(tmp_path / "longer.obj")
    code = main(common + ["--out", str(tmp_path / "r1"), "--reference", str(tmp_path / "longer.obj"),
                          "--reference-inertia", "mesh"])
    assert code == 0, capsys.readouterr().err
    record = json.loads((tmp_path / "r1" / "config.json").read_text())
    assert record["reference_properties"]["file"] == "reference_physical_properties.json"
