import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from real2sim.formats.collision import CollisionGeometry, CollisionShape, read_collision_json, write_collision_json
from real2sim.formats.rotations import matrix_to_quaternion, quaternion_to_matrix


def test_quaternion_round_trip():
    for seed in range(20):
        rot = Rotation.random(random_state=seed).as_matrix()
        q = matrix_to_quaternion(rot)
        assert q[0] >= 0
        np.testing.assert_allclose(quaternion_to_matrix(q), rot, atol=1e-12)


def test_json_round_trip(tmp_path):
    q = matrix_to_quaternion(Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix())
    shapes = (
        CollisionShape("sphere", (0.01,), (0.0, 0.0, 0.01)),
        CollisionShape("box", (0.02, 0.03, 0.04), (0.1, 0.0, 0.0), q),
        CollisionShape("cylinder", (0.01, 0.05), (0.0, 0.1, 0.0), q),
        CollisionShape("ellipsoid", (0.01, 0.02, 0.03), (0.0, 0.0, 0.1)),
        CollisionShape("capsule", (0.01, 0.04), (0.0, 0.0, -0.1), q),
        CollisionShape("convex", (), mesh_file="pieces/piece_000.obj"),
    )
    geometry = CollisionGeometry("mixed", "boxes:1+spheres:1", shapes)
    write_collision_json(geometry, tmp_path / "collision.json")
    back = read_collision_json(tmp_path / "collision.json")
    assert back.name == geometry.name and back.spec == geometry.spec
    for a, b in zip(back.shapes, shapes):
        assert a.kind == b.kind and a.mesh_file == b.mesh_file
        np.testing.assert_allclose(a.size_m, b.size_m)
        np.testing.assert_allclose(a.position_m, b.position_m)
        np.testing.assert_allclose(a.quaternion_wxyz, b.quaternion_wxyz)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(kind="pyramid", size_m=(1.0,)),
        dict(kind="sphere", size_m=(0.0,)),
        dict(kind="box", size_m=(1.0, 1.0)),
        dict(kind="sphere", size_m=(1.0,), quaternion_wxyz=(1.0, 1.0, 0.0, 0.0)),
        dict(kind="convex", size_m=()),
        dict(kind="cylinder", size_m=(float("nan"), 1.0)),
    ],
)
def test_invalid_shapes_rejected(kwargs):
    with pytest.raises(ValueError):
        CollisionShape(**kwargs)
