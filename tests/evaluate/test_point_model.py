"""Each representation's point-contact model (model_point.urdf): written with the point dissipation, found by
the evaluation, and the one its point-contact rows simulate."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET

import pytest

from real2sim.asset.export.writers import write_representation
from real2sim.evaluate.discovery import discover_representations
from real2sim.evaluate.sweep import EvaluationConfig, evaluate
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import POINT_URDF_NAME, ContactProperties
from real2sim.formats.physical import read_physical_properties
from tests.evaluate.test_sweep import BOX_EXTENTS_M, SHORT_SCENE, make_box_asset


def _dissipation(urdf) -> list[float]:
    root = ET.parse(urdf).getroot()
    return [float(e.get("value")) for e in root.iter() if e.tag.endswith("hunt_crossley_dissipation")]


def test_point_model_written_beside_the_model_and_removed_when_not_wanted(tmp_path):
    asset = make_box_asset(tmp_path / "box", reps=("boxes_1",))
    rep = asset / "boxes_1"
    assert _dissipation(rep / "model.urdf") == [1.0]
    assert _dissipation(rep / POINT_URDF_NAME) == [ContactProperties().point_dissipation_s_per_m] == [20.0]
    # Everything else is the same model.
    same = (rep / "model.urdf").read_text().replace("dissipation value=\"1.0\"", "dissipation value=\"20.0\"")
    assert same == (rep / POINT_URDF_NAME).read_text()
    geometry = CollisionGeometry("boxes_1", "boxes_1", (CollisionShape("box", tuple(map(float, BOX_EXTENTS_M))),))
    props = read_physical_properties(asset / "physical_properties.json")
    for none in (ContactProperties(point_dissipation_s_per_m=None), ContactProperties(point_dissipation_s_per_m=1.0)):
        write_representation(rep, geometry, props, none)
        assert not (rep / POINT_URDF_NAME).exists()
    with pytest.raises(ValueError):
        ContactProperties(point_dissipation_s_per_m=-1.0)


def test_point_rows_simulate_the_point_model(tmp_path):
    """The same asset twice, once with its point model swapped for a box 1.2x too large: only the point row
    changes, and for the worse; the hydroelastic row is the same."""
    right = make_box_asset(tmp_path / "right" / "box", reps=("boxes_1",))
    (rep,) = discover_representations([right])
    assert rep.urdf_for("point") == rep.point_urdf_path == right / "boxes_1" / POINT_URDF_NAME
    assert rep.urdf_for("hydroelastic") == rep.urdf_path == right / "boxes_1" / "model.urdf"
    wrong = make_box_asset(tmp_path / "wrong" / "box", reps=("boxes_1", "boxes_1_x1p2"))
    shutil.copy(wrong / "boxes_1_x1p2" / POINT_URDF_NAME, wrong / "boxes_1" / POINT_URDF_NAME)
    shutil.rmtree(wrong / "boxes_1_x1p2")
    config = EvaluationConfig(tasks=("push",), runs=1, jobs=1, scene=SHORT_SCENE)
    rows = {}
    for name, asset in (("right", right), ("wrong", wrong)):
        result = evaluate([asset], tmp_path / f"res_{name}", config)
        rows[name] = {r["contact_model"]: r for r in result.runs}
        assert not any(r["error"] for r in result.runs)
    assert rows["wrong"]["point"]["ocae_m"] > 2 * rows["right"]["point"]["ocae_m"] + 1e-4, rows
    assert rows["wrong"]["hydroelastic"]["ocae_m"] == pytest.approx(rows["right"]["hydroelastic"]["ocae_m"], abs=1e-12)
