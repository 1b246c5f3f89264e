"""Contact-aware fitting: the hull-band weights, and that they fit the support region tighter."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from real2sim.collision.fit.config import FitConfig
from real2sim.collision.fit.contact_weights import contact_weights, hull_planes, hull_signed_distance
from real2sim.collision.fit.convert import to_collision_geometry
from real2sim.collision.fit.loop import fit_primitives
from real2sim.collision.sdf_sampling import SdfSamplingConfig, sample_sdf
from real2sim.formats.rotations import quaternion_to_matrix


def _notched_cube() -> trimesh.Trimesh:
    """A 0.1 m cube (z from 0 to 0.1) with a 0.04 x 0.04 m pocket 0.05 m deep cut into its top."""
    cube = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    cube.apply_translation([0.0, 0.0, 0.05])
    pocket = trimesh.creation.box(extents=[0.04, 0.04, 0.1])
    pocket.apply_translation([0.0, 0.0, 0.1])  # from z = 0.05 up through the top
    return trimesh.boolean.difference([cube, pocket], engine="manifold")


def _tray() -> trimesh.Trimesh:
    """An upturned tray 0.10 x 0.07 x 0.06 m standing on its rim: a 0.07 x 0.04 x 0.015 m recess
    in its bottom, so it touches the floor only on a 15 mm wide rim around the recess."""
    outer = trimesh.creation.box(extents=[0.10, 0.07, 0.06])
    outer.apply_translation([0.0, 0.0, 0.03])
    recess = trimesh.creation.box(extents=[0.07, 0.04, 0.03])
    return trimesh.boolean.difference([outer, recess], engine="manifold")


@pytest.fixture(scope="module")
def notched_cube_samples():
    mesh = _notched_cube()
    return sample_sdf(mesh, SdfSamplingConfig(num_surface_samples=40_000), cache_dir=None)


def test_hull_band_weights_faces_not_interior_or_notch(notched_cube_samples):
    s = notched_cube_samples
    band, gain = 0.02, 5.0
    # Probe points in metres (the cube spans x, y in [-0.05, 0.05], z in [0, 0.1]).
    probes_m = {
        "bottom face": ([0.01, -0.02, 0.0], True),
        "side face, just inside": ([0.0495, 0.01, 0.03], True),
        "side face, just outside": ([-0.01, -0.0505, 0.07], True),
        "top face beside the pocket": ([0.035, 0.035, 0.1], True),
        "edge the cube tips over": ([0.05, 0.0, 0.0], True),
        "deep interior": ([0.0, 0.0, 0.025], False),
        "notch floor": ([0.0, 0.0, 0.05], False),
        "notch wall": ([0.02, 0.0, 0.07], False),
        "far outside": ([0.0, 0.0, -0.03], False),
    }
    pts_unit = (np.array([p for p, _ in probes_m.values()]) - s.centre_m) / s.scale_m
    planes = hull_planes(s.points, s.sdf, band)
    weights = contact_weights(pts_unit, None, band, gain, planes=planes)
    for (name, (_, on_hull)), w in zip(probes_m.items(), weights):
        assert w == pytest.approx(1.0 + gain if on_hull else 1.0), name
    # The samples' hull is the cube's: its faces are 0.05 m from the centre of the bottom half.
    centre_unit = (np.array([[0.0, 0.0, 0.05]]) - s.centre_m) / s.scale_m
    assert hull_signed_distance(centre_unit, planes)[0] * s.scale_m == pytest.approx(-0.05, abs=0.001)
    # Computed from the samples themselves, most of them (near the surface) get the gain.
    own = contact_weights(s.points, s.sdf, band, gain)
    assert own.dtype == np.float32 and set(np.unique(own)) == {1.0, 1.0 + gain}
    assert 0.3 < np.mean(own > 1) < 0.95


def test_zero_gain_or_flat_samples_weigh_one(notched_cube_samples):
    s = notched_cube_samples
    assert np.all(contact_weights(s.points, s.sdf, 0.02, 0.0) == 1.0)
    flat = np.column_stack([np.random.default_rng(0).random((100, 2)), np.zeros(100)])
    assert np.all(contact_weights(flat, np.full(100, -0.01), 0.02, 5.0) == 1.0)  # no volume, no hull
    with pytest.raises(ValueError):
        contact_weights(s.points, s.sdf, 0.02, -1.0)
    with pytest.raises(ValueError):
        FitConfig(contact_weight=-1.0)
    with pytest.raises(ValueError):
        FitConfig(contact_band=0.0)


def _down_support_error_mm(mesh: trimesh.Trimesh, result, samples) -> float:
    """Mean |h_fit(u) - h_mesh(u)| (mm) over directions within 30 deg of straight down, where
    h(u) is the support function (the largest u . x over the body); the fit here is boxes only."""
    geometry = to_collision_geometry(result, samples.centre_m, samples.scale_m, "boxes:1")
    rng = np.random.default_rng(0)
    u = rng.normal(size=(2000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u = u[u[:, 2] < -np.cos(np.radians(30))]
    h_mesh = (u @ mesh.vertices.T).max(1)
    h_fit = np.full(len(u), -np.inf)
    for shape in geometry.shapes:
        rotation = quaternion_to_matrix(shape.quaternion_wxyz)
        h_box = u @ np.asarray(shape.position_m) + np.abs(u @ rotation) @ (0.5 * np.asarray(shape.size_m))
        h_fit = np.maximum(h_fit, h_box)
    return float(1000 * np.abs(h_fit - h_mesh).mean())


def test_contact_weighting_fits_the_support_rim_tighter():
    # One box cannot be both the tray's rim and its recess: unweighted, the many samples in and
    # around the recess lift the box's bottom off the rim; weighted, the rim (on the hull) wins.
    mesh = _tray()
    samples = sample_sdf(mesh, SdfSamplingConfig(num_surface_samples=20_000), cache_dir=None)
    base = FitConfig(batch_size=2048, max_iterations=120, min_iterations=120, revive_dead=False)
    errors = {}
    for gain in (0.0, 5.0):
        config = dataclasses.replace(base, contact_weight=gain, contact_band=0.02)
        result = fit_primitives(samples.points, samples.sdf, (("boxes", 1),), config)
        errors[gain] = _down_support_error_mm(mesh, result, samples)
    assert errors[5.0] < 0.6 * errors[0.0], errors


def test_the_default_gain_is_by_family_and_an_explicit_one_wins():
    default = FitConfig()
    assert default.contact_weight is None
    assert default.contact_gain(("cylinder",)) == 5.0 and default.contact_gain(("ellipsoid", "cylinder")) == 5.0
    # boxes and spheres lost in the Table I protocol: they stay unweighted, mixed with the others too
    assert default.contact_gain(("box",)) == 0.0 and default.contact_gain(("sphere",)) == 0.0
    assert default.contact_gain(("cylinder", "box")) == 0.0 and default.contact_gain(()) == 0.0
    assert FitConfig(contact_weight=0.0).contact_gain(("cylinder",)) == 0.0
    assert FitConfig(contact_weight=2.0).contact_gain(("box",)) == 2.0


def test_a_default_fit_weights_cylinders_and_not_boxes_and_says_so():
    mesh = _notched_cube()
    samples = sample_sdf(mesh, SdfSamplingConfig(num_surface_samples=5_000, num_uniform_samples=500), cache_dir=None)
    config = FitConfig(batch_size=1024, max_iterations=5, min_iterations=5, revive_dead=False)
    cylinders = fit_primitives(samples.points, samples.sdf, (("cylinders", 2),), config)
    boxes = fit_primitives(samples.points, samples.sdf, (("boxes", 2),), config)
    assert cylinders.contact_weight == 5.0 and boxes.contact_weight == 0.0
    # gain 0 is eq. 9's plain mean, bit for bit: the default box fit is the explicit unweighted one
    plain = fit_primitives(samples.points, samples.sdf, (("boxes", 2),), dataclasses.replace(config, contact_weight=0.0))
    assert plain.parameters == boxes.parameters
    # ... and the cylinders' default is the explicit gain 5, not the plain mean
    weighted = fit_primitives(samples.points, samples.sdf, (("cylinders", 2),),
                              dataclasses.replace(config, contact_weight=5.0))
    unweighted = fit_primitives(samples.points, samples.sdf, (("cylinders", 2),),
                                dataclasses.replace(config, contact_weight=0.0))
    assert weighted.parameters == cylinders.parameters != unweighted.parameters
