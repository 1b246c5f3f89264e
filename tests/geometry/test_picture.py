"""Ray-cast pictures: the right pixels are covered, nearer meshes hide farther ones, textures show."""

from __future__ import annotations

import numpy as np
import trimesh

from real2sim.geometry.picture import look_at_camera, render_picture


def test_a_cube_fills_the_middle_and_leaves_the_corners_white():
    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    camera = look_at_camera(cube.bounds, width_px=64, height_px=48)
    image = render_picture([(cube, (1.0, 0.0, 0.0))], camera)
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    assert (image[0, 0] == 255).all() and (image[-1, -1] == 255).all()
    centre = image[24, 32].astype(int)
    assert centre[0] > 80 and centre[1] < 10 and centre[2] < 10  # red, shaded
    covered = (image != 255).any(axis=2)
    assert 0.15 < covered.mean() < 0.7


def test_the_nearer_mesh_wins_whatever_the_order():
    far = trimesh.creation.box((0.1, 0.1, 0.1))
    near = trimesh.creation.box((0.1, 0.1, 0.1))
    camera = look_at_camera(far.bounds, azimuth_deg=0.0, elevation_deg=0.0, width_px=32, height_px=24)
    near.apply_translation(0.06 * -np.asarray(camera.forward))  # towards the camera
    for parts in ([(far, (0.0, 0.0, 1.0)), (near, (0.0, 1.0, 0.0))], [(near, (0.0, 1.0, 0.0)), (far, (0.0, 0.0, 1.0))]):
        pixel = render_picture(parts, camera)[12, 16]
        assert pixel[1] > pixel[2]


def test_a_textured_mesh_shows_its_texture():
    from real2sim.geometry.objects import make_textured_object

    can = make_textured_object("can")
    camera = look_at_camera(can.bounds, width_px=80, height_px=60)
    textured = render_picture([(can, None)], camera)
    flat = render_picture([(can, (0.5, 0.5, 0.5))], camera)
    covered = (flat != 255).any(axis=2)
    # The flat grey picture has one hue; the textured one has several colours.
    assert len(np.unique(textured[covered] // 32, axis=0)) > len(np.unique(flat[covered] // 32, axis=0))
