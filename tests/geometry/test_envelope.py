"""The solid with its open cavities filled (geometry/envelope.py) and `asset --fill-cavities-m`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from real2sim.asset.build import AssetConfig, build_asset
from real2sim.plumbing.errors import UserInputError
from real2sim.formats.physical import read_physical_properties
from real2sim.formats.spec import parse_spec
from real2sim.geometry.envelope import filled_envelope
from real2sim.geometry.inside import inside_mask

OUTER_R, HEIGHT, WALL, FLOOR = 0.04, 0.09, 0.004, 0.008


def _cup() -> trimesh.Trimesh:
    """A cup without a handle: 40 mm radius, 90 mm tall, 4 mm wall, 8 mm floor, open at the top."""
    outer = trimesh.creation.cylinder(radius=OUTER_R, height=HEIGHT, sections=48)
    outer.apply_translation([0, 0, HEIGHT / 2])
    cavity = trimesh.creation.cylinder(radius=OUTER_R - WALL, height=HEIGHT, sections=48)
    cavity.apply_translation([0, 0, FLOOR + HEIGHT / 2])
    return trimesh.boolean.difference([outer, cavity], engine="manifold")


@pytest.fixture(scope="module")
def cup():
    return _cup()


def _closed_cup_volume(radius_m: float) -> float:
    """The cup closed by a ball of ``radius_m``: the solid cylinder less the cap the ball, resting on the
    rim, dips into the opening (depth R - sqrt(R^2 - a^2), a the opening's radius)."""
    a = OUTER_R - WALL
    depth = radius_m - math.sqrt(radius_m**2 - a**2)
    return math.pi * OUTER_R**2 * HEIGHT - math.pi * depth**2 * (3 * radius_m - depth) / 3


def test_a_ball_wider_than_the_opening_fills_the_cup(cup):
    envelope = filled_envelope(cup, 0.045, voxels=64)
    assert envelope.is_watertight
    expected = _closed_cup_volume(0.045)
    assert cup.volume < 0.4 * expected
    assert envelope.volume == pytest.approx(expected, rel=0.03)  # the voxels lose under 3 %
    # it holds the cup: a point just inside each of its faces is inside the envelope
    assert inside_mask(envelope, cup.triangles_center - 1e-5 * cup.face_normals).all()
    # and fills its middle
    assert inside_mask(envelope, np.array([[0.0, 0.0, HEIGHT / 2]]))[0]


def test_a_ball_narrower_than_the_opening_leaves_the_cavity_open(cup):
    envelope = filled_envelope(cup, 0.01, voxels=64)
    # the cavity's middle stays empty; only the floor's inner corner fills a little
    assert not inside_mask(envelope, np.array([[0.0, 0.0, HEIGHT / 2]]))[0]
    assert envelope.volume < 1.1 * cup.volume


def test_a_convex_solid_comes_back_as_it_was():
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    envelope = filled_envelope(box, 0.03, voxels=48)
    assert envelope.volume == pytest.approx(box.volume, rel=1e-6)
    np.testing.assert_allclose(envelope.bounds, box.bounds, atol=1e-9)


def test_a_ball_out_of_range_is_a_user_error(cup):
    for radius in (0.0, -0.01, float("nan"), 1.0, 0.001):
        with pytest.raises(UserInputError):
            filled_envelope(cup, radius, voxels=64)


@pytest.mark.slow  # an asset build end to end (86 s on 2 busy cores); the envelope's own tests stay in the default suite
def test_asset_fits_the_filled_cup_and_keeps_the_true_one_everywhere_else(cup, tmp_path):
    mesh = tmp_path / "cup.obj"
    cup.export(mesh)
    config = AssetConfig(mass_kg=0.3, specs=(parse_spec("ellipsoids:2"),), fill_cavities_m=0.045,
                         fit_config=None)
    result = build_asset(mesh, tmp_path / "filled", config)
    report = json.loads((tmp_path / "filled" / "ellipsoids_2" / "fit_report.json").read_text())
    assert "0.045 m ball" in report["fitted_to"]
    assert report["filled_volume_m3"] == pytest.approx(_closed_cup_volume(0.045) - cup.volume, rel=0.05)
    # two ellipsoids fit the filled cup far better than the thin-walled one they are also judged against
    assert report["filled_solid"]["iou"] > 0.6 and report["filled_solid"]["iou"] > 1.5 * report["iou"], report
    # the evaluation's reference and the mass properties are the true cup's
    reference = trimesh.load(tmp_path / "filled" / "visual" / "collision_reference.obj", force="mesh")
    assert reference.volume == pytest.approx(cup.volume, rel=1e-6)
    props = read_physical_properties(tmp_path / "filled" / "physical_properties.json")
    assert props.mass_kg == 0.3 and result.physical.com_m[2] < -0.005  # the heavy floor: CoM below the middle
    assert json.loads((tmp_path / "filled" / "asset_config.json").read_text())["fill_cavities_m"] == 0.045
