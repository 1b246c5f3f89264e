"""Views the image border cuts, aligned to the others' hull when every pose is off.

A view that sees only one side edge of a tall object (the rest runs off the image) tells its roll only by
how that edge leans. The one-sided silhouette fit that suits views aligned to a hull of refined views
(uncovered mask costly, the hull's spill past the mask almost free: ``SPILL_WEIGHT``) lets such a view roll
until the hull covers a few more mask pixels at the price of hundreds spilled: on a second capture of the
long-lens bottle one cut view ended 5.5 degrees rolled (11 px off) and carved the bottle's lower body
1-1.5 mm thin (Chamfer 1.52 mm). ``align_all`` weighs the spill ``ALL_SPILL_WEIGHT``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from real2sim.multiview.views import load_views, project


@pytest.fixture(scope="module")
def cut_ring(tmp_path_factory):
    """(true-posed views, indices of the views whose mask reaches the image border, points on the true
    bottle, metres) of a 48-view level ring of the bottle at 320x240 through a 1650 px lens, no table, a
    quarter of the views turned so the bottle runs off the image."""
    import trimesh

    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.formats.dataset import read_ground_truth
    from real2sim.geometry.objects import make_textured_object
    from real2sim.reconstruct.poses.centring import mask_centres
    from real2sim.reconstruct.truth import load_truth

    out = tmp_path_factory.mktemp("cut_ring") / "bottle"
    capture(make_textured_object("bottle"), out, CaptureConfig(views=48, width=320, height=240, pose_noise_mm=0,
                                                                pose_noise_deg=0, ring_elevation_deg=0.0,
                                                                focal_px=1650.0, no_table=True,
                                                                cut_off_fraction=0.25))
    views = load_views(out)
    truth = read_ground_truth(out)
    true = dict(zip((f.file_path for f in truth.frames), truth.poses_c2w_cv()))
    views = replace(views, c2w_cv=np.stack([true[n] for n in views.names]))
    _, whole, _ = mask_centres(views)
    cut = np.nonzero(~whole.all(axis=1))[0]
    points = trimesh.sample.sample_surface(load_truth(out), 300, seed=0)[0]
    return views, cut, points


def test_views_cut_by_the_border_are_not_rolled_off(cut_ring):
    """Each cut view, moved by the robot's noise (5 mm / 1 deg) in three draws, is aligned to the true
    others' hull with the weights ``align_all`` uses: the true bottle lands within a few pixels of where the
    true camera sees it. Measured (the worst pixel of each view, 36 fits): p90 3.5 px, max 7.7 px; with
    ``SPILL_WEIGHT`` (0.03) p90 12.6 px, max 22.8 px."""
    from real2sim.capture.sim.wrist_camera import perturb_poses
    from real2sim.reconstruct.poses.others_hull import leave_one_out_surfaces
    from real2sim.reconstruct.poses.silhouette import ALL_OUTLIER_FRACTION, ALL_SPILL_WEIGHT
    from real2sim.reconstruct.poses.view_fit import align_view

    views, cut, points = cut_ring
    assert len(cut) >= 10
    surfaces, _ = leave_one_out_surfaces(views, outlier_fraction=ALL_OUTLIER_FRACTION, table_z_m=None)
    true_uv, _ = project(views.intrinsics, views.c2w_cv, points)
    worst_px = []
    for draw in range(3):
        noisy = perturb_poses(views.c2w_cv, 5.0, 1.0, seed=100 + draw)
        for i in cut:
            start = views.c2w_cv.copy()
            start[i] = noisy[i]
            c2w, _ = align_view(replace(views, c2w_cv=start), int(i), surfaces[i], along_axis=False,
                                spill_weight=ALL_SPILL_WEIGHT)
            uv, _ = project(views.intrinsics, c2w[None], points)
            worst_px.append(float(np.linalg.norm(uv[0] - true_uv[i], axis=-1).max()))
    worst_px = np.array(worst_px)
    assert np.quantile(worst_px, 0.9) < 6.0 and worst_px.max() < 12.0, np.round(np.sort(worst_px), 1)
