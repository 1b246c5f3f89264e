"""Canonical pose: invariance to the input pose, axis order, handedness, upright bottles."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from real2sim.asset.canonical import canonical_transform, canonicalize


def _lumpy_box() -> trimesh.Trimesh:
    """A box (4 x 7 x 15 cm) with a side lump and an off-centre top knob: no symmetry at all."""
    body = trimesh.creation.box(extents=(0.04, 0.07, 0.15))
    lump = trimesh.creation.box(extents=(0.02, 0.04, 0.06), transform=trimesh.transformations.translation_matrix((0.028, 0.01, -0.02)))
    knob = trimesh.creation.box(extents=(0.02, 0.02, 0.03), transform=trimesh.transformations.translation_matrix((0.005, -0.015, 0.09)))
    return trimesh.boolean.union([body, lump, knob], engine="manifold")


def _bottle() -> trimesh.Trimesh:
    """A squeeze-bottle-like solid of revolution standing on z = 0: wide body, shoulder, thin nozzle."""
    profile = np.array(
        [[0.0, 0.0], [0.032, 0.0], [0.034, 0.01], [0.034, 0.13], [0.02, 0.155], [0.009, 0.16], [0.009, 0.185], [0.004, 0.19], [0.0, 0.19]]
    )
    return trimesh.creation.revolve(profile, sections=64)


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    pose[:3, 3] = rng.uniform(-0.5, 0.5, 3)
    return pose


def test_same_canonical_mesh_from_any_input_pose():
    base = _lumpy_box()
    reference, _ = canonicalize(base)
    rng = np.random.default_rng(3)
    for _ in range(6):
        moved = base.copy()
        moved.apply_transform(_random_pose(rng))
        canon, transform = canonicalize(moved)
        np.testing.assert_allclose(canon.vertices, reference.vertices, atol=1e-9)
        # the transform really maps the moved input onto the canonical mesh
        mapped = moved.vertices @ transform[:3, :3].T + transform[:3, 3]
        np.testing.assert_allclose(mapped, canon.vertices, atol=1e-12)


def test_axis_order_and_right_handed():
    canon, transform = canonicalize(_lumpy_box())
    rotation = transform[:3, :3]
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    extents = canon.bounds[1] - canon.bounds[0]
    assert extents[2] > extents[1] > extents[0]  # longest along z, shortest along x
    # centred: the area-weighted surface centroid is at the origin
    assert np.linalg.norm(np.asarray(canon.triangles_center).T @ canon.area_faces / canon.area) < 1e-12


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_bottle_ends_upright(seed):
    bottle = _bottle()
    moved = bottle.copy()
    pose = _random_pose(np.random.default_rng(seed))
    if seed == 0:
        pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # explicitly upside down
    moved.apply_transform(pose)
    canon, _ = canonicalize(moved)
    z = canon.vertices[:, 2]
    radial = np.linalg.norm(canon.vertices[:, :2], axis=1)
    top = z > z.max() - 0.02
    bottom = z < z.min() + 0.02
    assert radial[top].max() < 0.012  # the nozzle is up
    assert radial[bottom].max() > 0.03  # the wide base is down


def test_upright_symmetric_can_stays_upright():
    # a plain cylinder gives no cue from its shape; an upright input stays upright
    can = trimesh.creation.cylinder(radius=0.034, height=0.10, sections=48)
    can.apply_translation((0.2, -0.1, 0.05))
    transform = canonical_transform(can)
    assert transform[2, 2] == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(transform[:3, :3] @ [0.2, -0.1, 0.05] + transform[:3, 3], 0.0, atol=1e-9)


def test_empty_mesh_rejected():
    with pytest.raises(ValueError):
        canonical_transform(trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=[[0, 1, 2]]))


def test_up_axis_keeps_the_world_up():
    # a wide, short mug-like shape: PCA would pick a horizontal axis as the longest
    body = trimesh.creation.cylinder(radius=0.05, height=0.06, sections=48)
    handle = trimesh.creation.box(extents=(0.05, 0.012, 0.04), transform=trimesh.transformations.translation_matrix((0.07, 0.0, 0.0)))
    mug = trimesh.util.concatenate([body, handle])
    pca = canonical_transform(mug)
    assert abs(pca[2, 2]) < 0.5  # PCA's z is horizontal here
    kept = canonical_transform(mug, up_axis=(0.0, 0.0, 2.0))
    np.testing.assert_allclose(kept[2, :3], (0.0, 0.0, 1.0), atol=1e-12)  # asset z = input z
    assert np.linalg.det(kept[:3, :3]) == pytest.approx(1.0)
    # x is the horizontal direction of least spread: across the handle (input y)
    assert abs(kept[0, 1]) == pytest.approx(1.0, abs=1e-6)
