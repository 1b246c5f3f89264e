import numpy as np
import pytest
import trimesh

from real2sim.plumbing.errors import UserInputError
from real2sim.geometry.objects import (OBJECTS, REFERENCE_SAGITTA_M, ROUND_SAGITTA_M, export_object, make_object,
                                       make_textured_object)
from real2sim.geometry.tessellation import sections_for


@pytest.mark.parametrize("name", list(OBJECTS))
def test_objects_are_watertight_solids_standing_on_the_table(name):
    mesh = make_object(name)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0
    assert mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)


def test_object_sizes_match_their_descriptions():
    bottle, can, mug = make_object("bottle"), make_object("can"), make_object("mug")
    assert bottle.bounds[1, 2] == pytest.approx(0.19, abs=0.005)
    # tapered: the body is wider low than near the shoulder
    section_low = bottle.section(plane_origin=[0, 0, 0.05], plane_normal=[0, 0, 1]).bounds
    section_high = bottle.section(plane_origin=[0, 0, 0.15], plane_normal=[0, 0, 1]).bounds
    assert np.ptp(section_low[:, 0]) > 1.3 * np.ptp(section_high[:, 0])
    assert can.bounds[1, 2] == pytest.approx(0.10, abs=1e-6)
    assert np.ptp(can.bounds[:, 0]) / 2 == pytest.approx(0.034, abs=1e-4)
    assert OBJECTS["bottle"].mass_kg == pytest.approx(0.6) and OBJECTS["can"].mass_kg == pytest.approx(0.35)
    # the mug is clearly non-convex: its hull holds much more than it does
    assert mug.convex_hull.volume > 2.0 * mug.volume


def test_sections_keep_the_flats_within_the_sagitta():
    for radius_m in (0.005, 0.034, 0.2):
        for sagitta_m in (1e-6, 2.5e-6, 3e-5):
            n = sections_for(radius_m, sagitta_m)
            assert n % 8 == 0 and radius_m * (1 - np.cos(np.pi / n)) <= sagitta_m
            if n > 8:  # and not many more sections than that takes
                assert radius_m * (1 - np.cos(np.pi / (n - 8))) > sagitta_m
    with pytest.raises(ValueError):
        sections_for(0.01, 0.02)


def _side_flat_depth_m(can) -> float:
    """Deepest point of the can's side faces below the 34 mm circle, m."""
    side = can.triangles_center[np.abs(can.face_normals[:, 2]) < 1e-6]
    assert len(side) > 0
    return float((0.034 - np.hypot(side[:, 0], side[:, 1])).max())


def test_the_round_can_is_round_and_a_finer_one_is_finer():
    # The bundled can is 0.1.0's (72 sections, flats 32 um deep); its round reference's flats lie
    # REFERENCE_SAGITTA_M inside the circle at most; bench_tessellation builds it finer still.
    assert 25e-6 < _side_flat_depth_m(make_object("can")) < 35e-6
    bundled = make_object("can", rolling_sagitta_m=REFERENCE_SAGITTA_M)
    assert _side_flat_depth_m(bundled) <= REFERENCE_SAGITTA_M
    finer = make_object("can", rolling_sagitta_m=ROUND_SAGITTA_M / 4)
    assert finer.is_watertight and _side_flat_depth_m(finer) <= ROUND_SAGITTA_M / 4
    assert finer.volume == pytest.approx(bundled.volume, rel=2e-4)
    textured = make_textured_object("can", rolling_sagitta_m=ROUND_SAGITTA_M / 4)
    assert textured.bounds == pytest.approx(finer.bounds)


def test_objects_are_deterministic():
    a, b = make_object("bottle"), make_object("bottle")
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_textured_export_has_normals_uvs_and_texture(tmp_path):
    textured = make_textured_object("can")
    assert textured.visual.uv.shape == (len(textured.vertices), 2)
    path = export_object("can", tmp_path / "can" / "model.obj")
    text = path.read_text()
    assert "vn " in text and "vt " in text and "mtllib model.mtl" in text
    assert (tmp_path / "can" / "model.mtl").exists()
    assert any(p.suffix == ".png" for p in (tmp_path / "can").iterdir())
    back = trimesh.load(path, force="mesh")
    merged = trimesh.Trimesh(back.vertices, back.faces, process=True)
    assert merged.is_watertight
    assert merged.volume == pytest.approx(make_object("can").volume, rel=1e-4)


def test_unknown_object():
    with pytest.raises(UserInputError):
        make_object("teapot")
