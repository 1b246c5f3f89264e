"""Point-contact stiffness shared among the pieces that touch a plane together (asset/export/point_contact.py)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from real2sim.asset.export.point_contact import representation_contact, touching_pieces
from real2sim.asset.export.writers import write_representation
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import ContactProperties
from real2sim.formats.physical import PhysicalProperties
from tests.asset.test_drake_rest import RestObject, simulate_drop

SIZE_M = np.array([0.08, 0.08, 0.06])


def _columns(n_side: int) -> CollisionGeometry:
    """The box SIZE_M as n_side x n_side columns standing side by side (n_side**2 pieces)."""
    a, b, c = SIZE_M
    w, d = a / n_side, b / n_side
    shapes = tuple(CollisionShape("box", (w, d, c), (-a / 2 + (i + 0.5) * w, -b / 2 + (j + 0.5) * d, 0.0))
                   for i in range(n_side) for j in range(n_side))
    return CollisionGeometry(f"boxes_{n_side * n_side}", f"boxes:{n_side * n_side}", shapes)


def test_touching_pieces_counts_the_pieces_a_plane_meets():
    one = _columns(1)
    assert touching_pieces(one) == pytest.approx(1.0)
    # Two coincident pieces touch every plane together.
    assert touching_pieces(CollisionGeometry("x", "x", one.shapes * 2)) == pytest.approx(2.0)
    # 2 x 2 columns 8 x 8 x 6 cm: the bottom and top (64 cm^2 each) meet all 4, each side (48 cm^2) 2.
    a, b, c = SIZE_M
    expected = (2 * a * b * 4 + 2 * (a * c + b * c) * 2) / (2 * a * b + 2 * (a * c + b * c))
    assert touching_pieces(_columns(2)) == pytest.approx(expected, rel=1e-6)
    # A can as 10 stacked cylinders: its round side (3/4 of the hull's area) meets all 10.
    r, h = 0.034, 0.10
    stack = CollisionGeometry("x", "x", tuple(CollisionShape("cylinder", (r, h / 10), (0.0, 0.0, (i + 0.5) * h / 10))
                                              for i in range(10)))
    side, caps = 2 * np.pi * r * h, 2 * np.pi * r * r
    assert touching_pieces(stack) == pytest.approx((10 * side + caps) / (side + caps), rel=0.02)
    # Two balls 10 cm apart: a plane along the hull's straight middle touches both, one at its round ends.
    apart = CollisionGeometry("x", "x", (CollisionShape("sphere", (0.02,)), CollisionShape("sphere", (0.02,), (0.1, 0, 0))))
    middle, ends = 2 * np.pi * 0.02 * 0.1, 4 * np.pi * 0.02**2
    assert touching_pieces(apart) == pytest.approx((2 * middle + ends) / (middle + ends), rel=0.03)


def test_representation_contact_divides_the_stiffness():
    contact = ContactProperties(point_contact_stiffness_n_per_m=1.2e4)
    four = _columns(2)
    split = representation_contact(contact, four)
    assert split.point_contact_stiffness_n_per_m == pytest.approx(1.2e4 / touching_pieces(four))
    assert replace(split, point_contact_stiffness_n_per_m=1.2e4) == contact  # nothing else changes
    assert representation_contact(contact, _columns(1)).point_contact_stiffness_n_per_m == pytest.approx(1.2e4)


def _props() -> PhysicalProperties:
    mass_kg = 0.5
    a, b, c = SIZE_M
    inertia = mass_kg / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    return PhysicalProperties(mass_kg, (0.0, 0.0, 0.0), tuple(tuple(r) for r in inertia), method="closed form")


def _urdf_stiffness(path) -> list[float]:
    root = ET.parse(path).getroot()
    return [float(e.get("value")) for e in root.iter() if e.tag.endswith("point_contact_stiffness")]


def test_written_urdf_carries_the_share_by_default(tmp_path):
    four, props = _columns(2), _props()
    write_representation(tmp_path / "split", four, props, ContactProperties(), formats=("urdf",))
    write_representation(tmp_path / "same", four, props, ContactProperties(point_stiffness_per_piece=False),
                         formats=("urdf",))
    share = 1.0e4 / touching_pieces(four)
    assert _urdf_stiffness(tmp_path / "split" / "model.urdf") == pytest.approx([share] * 4)
    assert _urdf_stiffness(tmp_path / "same" / "model.urdf") == pytest.approx([1.0e4] * 4)


def test_a_union_rests_about_as_deep_as_the_object_in_one_piece(tmp_path):
    """Drake, point contact, a half-space floor: 4 columns each with the whole stiffness sink about a
    quarter as deep as the one box; with the stiffness shared they sink within a factor 1.6 of it
    (the share is averaged over directions, so it is not exactly the 4 that rest on the floor)."""
    pytest.importorskip("pydrake")
    props = _props()
    mesh = trimesh.creation.box(SIZE_M)
    (tmp_path / "visual").mkdir()
    mesh.export(tmp_path / "visual" / "model.obj")
    depth = {}
    for name, geometry, contact in (("one", _columns(1), ContactProperties()),
                                    ("split", _columns(2), ContactProperties()),
                                    ("same", _columns(2), ContactProperties(point_stiffness_per_piece=False))):
        write_representation(tmp_path / name, geometry, props, contact, formats=("urdf",))
        drop = simulate_drop(tmp_path / name / "model.urdf", RestObject(name, mesh, props, geometry), "point")
        rotation = drop.pose.rotation().matrix()
        depth[name] = float(-(mesh.vertices @ rotation.T + drop.pose.translation())[:, 2].min())
    expected_m = 0.5 * 9.81 / 1.0e4  # one point of 1e4 N/m under 0.5 kg
    assert depth["one"] == pytest.approx(expected_m, rel=0.15), depth
    assert depth["same"] < 0.4 * depth["one"], depth
    assert depth["one"] / 1.6 < depth["split"] < depth["one"] * 1.6, depth


def test_an_asset_config_from_before_the_share_reads_as_unshared(tmp_path):
    """asset_config.json files written before ``point_stiffness_per_piece`` existed were built with the
    whole stiffness on every piece; reading one back must say so, not take today's default."""
    import dataclasses
    import json

    from real2sim.formats.asset_config import read_asset_contact
    from real2sim.plumbing.errors import UserInputError

    old = dataclasses.asdict(ContactProperties())
    del old["point_stiffness_per_piece"]
    (tmp_path / "asset_config.json").write_text(json.dumps({"contact": old}))
    assert read_asset_contact(tmp_path).point_stiffness_per_piece is False
    (tmp_path / "asset_config.json").write_text(json.dumps({"contact": dataclasses.asdict(ContactProperties())}))
    assert read_asset_contact(tmp_path).point_stiffness_per_piece is True
    (tmp_path / "asset_config.json").write_text(json.dumps({"contact": [1, 2]}))
    with pytest.raises(UserInputError, match="no readable contact properties"):
        read_asset_contact(tmp_path)
