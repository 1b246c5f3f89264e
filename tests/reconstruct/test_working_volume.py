"""The working volume comes from the views alone: rings, long lenses, cut-off views, no table, one bad mask.

The synthetic views here are a sphere seen by cameras whose masks are computed exactly
(ray-sphere tests), so every expectation is known in closed form; the temple test reads
the real Middlebury photographs in ``../shared/data/real/temple_ring`` (skipped without them).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.multiview.views import PosedViews

RADIUS_M = 0.04
CENTRE_M = np.array([0.01, -0.02, 0.05])
TEMPLE = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real" / "temple_ring"


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world, OpenCV axes (z forward, y down), world z up."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([right, down, forward], axis=1)
    c2w[:3, 3] = eye
    return c2w


def ring_views(*, azimuths_deg, elevation_deg: float = 0.0, distance_m: float = 0.6, fx_px: float = 1600.0,
               width: int = 160, height: int = 120, aim_offset_m=None) -> PosedViews:
    """Views of the sphere from a ring of cameras at one elevation; masks are the sphere's exact silhouette."""
    k = CameraIntrinsics(width, height, fx_px, fx_px, width / 2, height / 2)
    poses, masks = [], []
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rays_cam = np.stack([(u - k.cx) / k.fl_x, (v - k.cy) / k.fl_y, np.ones_like(u)], axis=-1)
    rays_cam /= np.linalg.norm(rays_cam, axis=-1, keepdims=True)
    for i, az in enumerate(np.radians(np.asarray(azimuths_deg, dtype=float))):
        el = np.radians(elevation_deg)
        eye = CENTRE_M + distance_m * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        aim = CENTRE_M + (0.0 if aim_offset_m is None else np.asarray(aim_offset_m[i]))
        c2w = _look_at(eye, aim)
        rays = rays_cam @ c2w[:3, :3].T
        to_centre = CENTRE_M - eye
        along = rays @ to_centre
        miss_sq = to_centre @ to_centre - along ** 2
        masks.append(((miss_sq <= RADIUS_M ** 2) & (along > 0)).astype(np.float32))
        poses.append(c2w)
    n = len(poses)
    rgb = np.repeat(np.stack(masks)[..., None], 3, axis=-1) * 0.8
    return PosedViews(rgb.astype(np.float32), np.stack(masks), np.stack(poses), k, tuple(f"v{i}" for i in range(n)))


def _within(lo, hi, tolerance_m):
    true_lo, true_hi = CENTRE_M - RADIUS_M, CENTRE_M + RADIUS_M
    return np.all(np.abs(lo - true_lo) <= tolerance_m) and np.all(np.abs(hi - true_hi) <= tolerance_m)


def test_a_level_ring_with_a_long_lens_bounds_the_object():
    """19 cameras over 135 degrees of one ring level with the object, fx 1600 px at 160x120 (a 6 degree
    field of view: the temple's rig). The three views at either end of the arc see long thin cones
    together; counted, they let the region run off far past the object (the bug this guards)."""
    from real2sim.multiview.hull import object_region

    views = ring_views(azimuths_deg=np.linspace(135, 270, 19), distance_m=1.2)
    lo, hi = object_region(views, table_z_m=None)
    assert _within(lo, hi, 0.012), (lo, hi)
    # The rule that makes it so: without the views' spread, the same masks leave it unbounded or loose.
    from real2sim.multiview import hull

    loose = hull.silhouette_scores(views, np.array([CENTRE_M + [0.0, 0.0, 0.0]]), 0.03, min_spread_deg=0.0)
    assert loose[0] == pytest.approx(1.0)


def test_points_seen_only_by_neighbouring_views_are_not_inside():
    """Every view is cut by its image's left and right edges (fx 2600 px at 160x120: the sphere is wider
    than the image), so beyond those edges no view can tell. A point on the last camera's axis, 10 cm
    in front of the sphere's centre, is then inside the masks of the few neighbouring views that see it, and of no other:
    nothing bounds it, so it is not inside."""
    import torch

    from real2sim.multiview.hull import border_touched, seen_together, silhouette_scores, view_spread_deg

    views = ring_views(azimuths_deg=np.linspace(135, 270, 19), distance_m=1.2, fx_px=2600)
    assert border_touched(views.mask)[:, :2].all()
    end = views.c2w_cv[-1, :3, 3]
    # 10 cm from the centre towards the last camera: in the masks of the last three views (15 degrees)
    stray = CENTRE_M + 0.1 * (end - CENTRE_M) / np.linalg.norm(end - CENTRE_M)
    with_rule = silhouette_scores(views, stray[None], 0.03)
    without = silhouette_scores(views, stray[None], 0.03, min_spread_deg=0.0)
    assert without[0] >= 0.5 and with_rule[0] == 0.0
    assert silhouette_scores(views, CENTRE_M[None], 0.03)[0] >= 0.5
    assert not seen_together(views, stray[None])[0] and seen_together(views, CENTRE_M[None])[0]
    two = torch.tensor([[[1.0, 0.0, 0.0]], [[np.cos(np.radians(40)), np.sin(np.radians(40)), 0.0]]])
    assert float(view_spread_deg(two, torch.ones(2, 1, dtype=torch.bool))[0]) == pytest.approx(40.0, abs=0.01)


@pytest.mark.parametrize("offset_m", [0.0, 250.0])
def test_the_spread_from_camera_centres_is_the_spread_of_the_directions(offset_m):
    """camera_spread_deg (three matrix products) against view_spread_deg on the (V, P, 3) unit directions, for
    random cameras and points, also in a frame far from the origin (a COLMAP model's): within 0.01 degree."""
    import torch

    from real2sim.multiview.hull import camera_spread_deg, view_spread_deg

    rng = np.random.default_rng(4)
    centres = rng.normal(size=(40, 3)) * [0.4, 0.4, 0.2] + [0.0, 0.0, 0.4] + offset_m
    pts = rng.uniform(-0.08, 0.08, size=(500, 3)) + offset_m
    seen = torch.from_numpy(rng.random((40, 500)) < 0.3)
    directions = centres[:, None] - pts[None]
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    expected = view_spread_deg(torch.from_numpy(directions), seen)
    got = camera_spread_deg(torch.from_numpy(centres).float(), torch.from_numpy(pts).float(), seen)
    assert float((got - expected).abs().max()) < 0.01


def test_a_point_beyond_an_edge_the_mask_stays_clear_of_is_outside():
    """With the whole sphere in every image, a view the point projects outside of votes against it."""
    from real2sim.multiview.hull import border_touched, silhouette_scores

    views = ring_views(azimuths_deg=np.linspace(135, 270, 19), distance_m=1.2)
    assert not border_touched(views.mask).any()
    end = views.c2w_cv[-1, :3, 3]
    assert silhouette_scores(views, (0.5 * (end + CENTRE_M))[None], 0.03, min_spread_deg=0.0)[0] == 0.0


def test_views_cut_by_the_image_border_do_not_cut_the_object():
    """A third of the views aim 10 cm off, so the sphere leaves their image: where a view cannot see,
    it casts no vote, and the hull keeps the whole sphere."""
    from real2sim.multiview.hull import border_touched, carve, object_region
    from real2sim.multiview.voxel_grid import VoxelGrid

    az = np.linspace(0, 360, 24, endpoint=False)
    offsets = [np.array([0.0, 0.0, 0.1]) if i % 3 == 0 else np.zeros(3) for i in range(len(az))]
    views = ring_views(azimuths_deg=az, elevation_deg=30, distance_m=0.8, fx_px=400, aim_offset_m=offsets)
    cut = views.mask[::3].reshape(8, -1)
    assert border_touched(views.mask[::3]).any(axis=1).all() and not border_touched(views.mask[1::3]).any()
    assert cut.mean() < views.mask[1::3].reshape(16, -1).mean()
    lo, hi = object_region(views, table_z_m=None)
    assert _within(lo, hi, 0.012), (lo, hi)
    grid = VoxelGrid.covering(lo, hi, 48, None)
    scores = carve(views, grid).reshape(-1)
    centres = grid.centres()
    inside_true = np.linalg.norm(centres - CENTRE_M, axis=1) < RADIUS_M - 1.5 * grid.voxel_m
    assert scores[inside_true].min() >= 0.5


def _ring_with_one_wrong_mask():
    """A 20-view ring of the sphere whose first mask lost the sphere's upper half, and a 40-voxel grid
    around the sphere."""
    from real2sim.multiview.voxel_grid import VoxelGrid

    views = ring_views(azimuths_deg=np.linspace(0, 360, 20, endpoint=False), elevation_deg=25, distance_m=0.8,
                       fx_px=400)
    masks = views.mask.copy()
    masks[0, : views.intrinsics.height // 2] = 0.0
    grid = VoxelGrid.covering(CENTRE_M - 1.3 * RADIUS_M, CENTRE_M + 1.3 * RADIUS_M, 40, None)
    return replace(views, mask=masks), grid


def test_one_wrong_mask_does_not_cut_the_object():
    """One view's mask loses the sphere's upper half (a threshold that ate it): enough other views
    see that half, so it stays."""
    from real2sim.multiview.hull import carve

    broken, grid = _ring_with_one_wrong_mask()
    centres = grid.centres()
    inside_true = np.linalg.norm(centres - CENTRE_M, axis=1) < RADIUS_M - 1.5 * grid.voxel_m
    assert carve(broken, grid).reshape(-1)[inside_true].min() >= 0.5


def test_a_result_beyond_what_the_views_see_together_is_refused():
    from real2sim.reconstruct.stage import UnboundedReconstruction, check_seen_together

    views = ring_views(azimuths_deg=np.linspace(135, 270, 19), distance_m=1.2)
    region = (CENTRE_M - 1.2 * RADIUS_M, CENTRE_M + 1.2 * RADIUS_M)
    good = trimesh.creation.icosphere(subdivisions=2, radius=RADIUS_M)
    good.apply_translation(CENTRE_M)
    check_seen_together(good, views, region)
    runaway = trimesh.creation.box(extents=(2.5, 2.5, 0.1))
    runaway.apply_translation(CENTRE_M)
    with pytest.raises(UnboundedReconstruction, match="beyond the region the views see together"):
        check_seen_together(runaway, views, region)


@pytest.fixture(scope="module")
def temple_views():
    if not (TEMPLE / "transforms.json").is_file():
        pytest.skip(f"the real temple photographs are not at {TEMPLE}")
    from real2sim.multiview.views import load_views

    return load_views(TEMPLE, max_side_px=160)


def test_temple_region_is_the_object(temple_views):
    """19 real photographs (fx 1520 px at 640x480, one level ring over 135 degrees, rough thresholded
    masks): the region the views bound is the temple's box, not the 2.5 m it used to be."""
    from real2sim.multiview.hull import object_region

    truth = json.loads((TEMPLE / "truth_bbox.json").read_text())
    lo, hi = object_region(temple_views, table_z_m=0.0)
    voxel_m = 0.012  # the coarse search grid's cells, about
    assert np.all(np.abs(lo - truth["bbox_min_m"]) < voxel_m) and np.all(np.abs(hi - truth["bbox_max_m"]) < voxel_m), (lo, hi)


def test_temple_hull_reconstruction_matches_the_true_box(temple_views, tmp_path):
    """The hull backend end to end on the temple photographs reduced to 160x120: its box within 5 mm of the
    authors' (a pixel is 1.5 mm at the temple at this size)."""
    from real2sim.reconstruct.stage import ReconstructConfig, reconstruct

    truth = json.loads((TEMPLE / "truth_bbox.json").read_text())
    cfg = ReconstructConfig(backend="hull", hull_voxels=64, texture_px=64, max_faces=4000, max_image_side_px=160)
    result = reconstruct(TEMPLE, cfg)
    lo, hi = np.asarray(result.mesh.bounds)
    assert np.all(np.abs(lo - truth["bbox_min_m"]) < 0.005) and np.all(np.abs(hi - truth["bbox_max_m"]) < 0.005), (lo, hi)
    assert result.report["region_m"]


def test_a_view_whose_mask_lost_part_of_the_object_is_not_trusted_alone():
    """Views whose masks agree with the robust hull carve alone; the one whose mask lost the sphere's
    upper half does not (it would remove a volume, not a sliver of skin)."""
    from real2sim.multiview.hull import consistent_views, silhouette_scores

    broken, grid = _ring_with_one_wrong_mask()
    inside = silhouette_scores(broken, grid.centres(), 0.03).reshape(grid.shape) >= 0.5
    trusted = consistent_views(broken, grid, inside)
    assert not trusted[0] and trusted[1:].all(), trusted


def test_trusted_views_trim_the_skin_that_robust_carving_leaves():
    """Six views along a 135-degree arc, as the temple's: without opposite views, a side of the
    sphere is bounded by one view's silhouette only, so the rule that two views must agree leaves a
    skin there; views whose masks all agree with each other carve alone and the hull's box error
    falls by two thirds (9 -> 3 mm here; what is left is six views' polygon around a sphere)."""
    from real2sim.multiview.hull import carve
    from real2sim.multiview.voxel_grid import VoxelGrid

    views = ring_views(azimuths_deg=np.linspace(135, 270, 6), elevation_deg=20, distance_m=0.6, fx_px=800)
    grid = VoxelGrid.covering(CENTRE_M - 1.5 * RADIUS_M, CENTRE_M + 1.5 * RADIUS_M, 60, None)
    centres = grid.centres()

    def box_error_m(scores):
        inside = centres[scores.reshape(-1) >= 0.5]
        return max(np.abs(inside.min(axis=0) - (CENTRE_M - RADIUS_M)).max(),
                   np.abs(inside.max(axis=0) - (CENTRE_M + RADIUS_M)).max())

    robust = box_error_m(carve(views, grid, trust_consistent=False))
    trusted = box_error_m(carve(views, grid))
    assert trusted <= 1.5 * grid.voxel_m and trusted <= 0.5 * robust, (trusted, robust, grid.voxel_m)


def test_temple_at_320_px_every_side_within_2_mm(temple_views):
    """The issue's temple target on the real photographs reduced to 320x240, hull backend with the
    default mask edges (moved to the photos' colour edges): every side of the mesh's box within
    2 mm of the authors' tight box. With the masks as given (a threshold at 0.3 and a 2 px
    dilation: a halo) the sides were up to 1.9 mm out at this size and 3.7 mm at 640x480."""
    from real2sim.reconstruct.stage import ReconstructConfig, reconstruct

    truth = json.loads((TEMPLE / "truth_bbox.json").read_text())
    cfg = ReconstructConfig(backend="hull", hull_voxels=128, texture_px=64, max_faces=4000, max_image_side_px=320)
    result = reconstruct(TEMPLE, cfg)
    lo, hi = np.asarray(result.mesh.bounds)
    errors_m = np.concatenate([np.asarray(truth["bbox_min_m"]) - lo, hi - np.asarray(truth["bbox_max_m"])])
    assert np.abs(errors_m).max() <= 0.002, errors_m
    assert result.report["mask_edges"]["method"] == "colour" and result.report["mask_edges"]["band_px"] == 2


@pytest.mark.cuda
def test_cuda_carves_as_the_cpu():
    """The silhouette scores counted on a GPU (the field's hull and its occupancy, on its device) are the
    CPU's: the same votes, float32 bilinear mask values in another order."""
    import torch

    from real2sim.multiview.hull import carve
    from real2sim.multiview.voxel_grid import VoxelGrid

    if not torch.cuda.is_available():
        pytest.skip("needs a CUDA GPU")
    rings = [ring_views(azimuths_deg=np.linspace(start, start + 330, 12), elevation_deg=elevation,
                        distance_m=0.4, fx_px=200.0) for start, elevation in ((0, 30.0), (15, -10.0))]
    views = replace(rings[0], **{f: np.concatenate([getattr(r, f) for r in rings]) for f in ("rgb", "mask", "c2w_cv")},
                    names=tuple(f"v{i}" for i in range(24)))
    grid = VoxelGrid.covering(CENTRE_M - 1.3 * RADIUS_M, CENTRE_M + 1.3 * RADIUS_M, 40, None)
    cpu = carve(views, grid, 0.03, device="cpu")
    gpu = carve(views, grid, 0.03, device="cuda")
    assert 0.1 < (cpu >= 0.5).mean() < 0.6  # the sphere, not an empty or full grid
    np.testing.assert_allclose(gpu, cpu, atol=1e-5)
