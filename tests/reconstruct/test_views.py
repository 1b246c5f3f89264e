"""Posed views: projection and back-projection agree (with and without OpenCV distortion), pixel
centres at +0.5 (checked against Drake's rendered masks), the cameras' common look-at point,
the held-out split, and the dataset checks of ``load_views``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError
from real2sim.multiview.views import (
    MIN_VIEWS,
    PosedViews,
    common_look_at_point,
    held_out_split,
    load_views,
    pixel_rays,
    project,
    undistorted_normalized,
)

W, H = 160, 120
PINHOLE = CameraIntrinsics(160, 120, 153.75, 150.0, 81.3, 58.7)
# a wide-angle lens's worth of distortion: about 7 px of radial shift in the image corners
DISTORTED = CameraIntrinsics(160, 120, 153.75, 150.0, 81.3, 58.7, k1=-0.12, k2=0.03, p1=1e-3, p2=-8e-4)


def _pose(seed: int) -> np.ndarray:
    c2w = np.eye(4)
    c2w[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    c2w[:3, 3] = np.random.default_rng(seed).normal(0.0, 0.3, 3)
    return c2w


def _points_in_view(k: CameraIntrinsics, c2w: np.ndarray, n: int = 500, seed: int = 0):
    """World points (n, 3) spread over the whole (undistorted) field of view, 0.1..1 m deep, and their depths."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-k.cx, k.width - k.cx, n) / k.fl_x
    y = rng.uniform(-k.cy, k.height - k.cy, n) / k.fl_y
    z = rng.uniform(0.1, 1.0, n)
    cam = np.column_stack([x * z, y * z, z])
    return cam @ c2w[:3, :3].T + c2w[:3, 3], z


def _opencv_distort(k: CameraIntrinsics, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's radial-tangential model, written out from its documentation (an independent reference)."""
    r2 = x * x + y * y
    radial = 1 + k.k1 * r2 + k.k2 * r2 ** 2
    xd = x * radial + 2 * k.p1 * x * y + k.p2 * (r2 + 2 * x * x)
    yd = y * radial + k.p1 * (r2 + 2 * y * y) + 2 * k.p2 * x * y
    return k.fl_x * xd + k.cx, k.fl_y * yd + k.cy


@pytest.mark.parametrize("k", [PINHOLE, DISTORTED], ids=["pinhole", "distorted"])
def test_projected_point_lies_on_its_pixel_ray(k):
    c2w = _pose(3)
    points, depth = _points_in_view(k, c2w)
    uv, z = project(k, c2w[None], points)
    assert uv.shape == (1, len(points), 2) and z.shape == (1, len(points))
    np.testing.assert_allclose(z[0], depth, atol=1e-6)  # float32: measured 8e-8 m
    origins, dirs = pixel_rays(k, c2w, uv[0, :, 0], uv[0, :, 1])
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(origins, np.broadcast_to(c2w[:3, 3], origins.shape))
    v = points - origins
    along = np.einsum("nd,nd->n", v, dirs)
    assert along.min() > 0, "the point must be in front of the camera along its ray"
    off_ray = np.linalg.norm(v - along[:, None] * dirs, axis=1)
    assert off_ray.max() < 1e-6  # measured 1e-7 m at up to 1 m depth (float32 pixel positions)


def test_distortion_follows_opencv_model():
    c2w = np.eye(4)
    points, depth = _points_in_view(DISTORTED, c2w, seed=1)
    uv, _ = project(DISTORTED, c2w[None], points)
    x, y = points[:, 0] / points[:, 2], points[:, 1] / points[:, 2]
    u_ref, v_ref = _opencv_distort(DISTORTED, x, y)
    np.testing.assert_allclose(uv[0, :, 0], u_ref, atol=1e-3)
    np.testing.assert_allclose(uv[0, :, 1], v_ref, atol=1e-3)
    # the distortion is not a no-op: far from the centre the pixels move by several px
    uv_pinhole, _ = project(PINHOLE, c2w[None], points)
    assert np.abs(uv - uv_pinhole).max() > 3.0
    # and undistortion inverts it (fixed-point iterations): back to the ideal normalized coordinates
    xu, yu = undistorted_normalized(DISTORTED, u_ref, v_ref)
    np.testing.assert_allclose(xu, x, atol=1e-7)
    np.testing.assert_allclose(yu, y, atol=1e-7)


def test_pixel_centres_are_at_half_integers():
    k = CameraIntrinsics(160, 120, 153.75, 153.75, 80.0, 60.0)
    c2w = _pose(5)
    # the optical axis meets the image at (cx, cy) = (w/2, h/2): the corner between four pixels
    on_axis = c2w[:3, 3] + 0.7 * c2w[:3, 2]
    uv, _ = project(k, c2w[None], on_axis[None])
    np.testing.assert_allclose(uv[0, 0], [80.0, 60.0], atol=1e-4)
    _, d = pixel_rays(k, c2w, np.array([80.0]), np.array([60.0]))
    np.testing.assert_allclose(d[0], c2w[:3, 2], atol=1e-12)
    # the ray through the centre of pixel (0, 0), at (0.5, 0.5), in camera axes
    _, d = pixel_rays(k, np.eye(4), np.array([0.5]), np.array([0.5]))
    expected = np.array([(0.5 - 80.0) / 153.75, (0.5 - 60.0) / 153.75, 1.0])
    np.testing.assert_allclose(d[0], expected / np.linalg.norm(expected), atol=1e-12)


def test_true_object_projects_onto_drakes_masks(can_capture):
    """The true can's silhouette, projected with ``project``, spans the same pixels as Drake's masks.

    A mask pixel is set where its centre (u + 0.5) is inside the silhouette, so the projected
    extreme u minus the first mask column lies in (-0.5, 0.5], with mean ~0; a pixel-centre
    convention off by half a pixel would shift that mean by 0.5. Measured over 60 views x 4
    sides: mean -0.05 px, range -0.49..0.52 px, standard deviation 0.28 px (uniform: 0.29).
    """
    from real2sim.reconstruct.truth import load_truth

    views = load_views(can_capture)
    truth = load_truth(can_capture)  # the can's sides are flat facets: vertices are the silhouette's extremes
    uv, z = project(views.intrinsics, views.c2w_cv, truth.vertices)
    assert (z > 0).all()
    residuals = []
    for i in range(views.count):
        mask = views.mask[i] > 0.5
        rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
        assert 0 < cols[0] and cols[-1] < W - 1 and 0 < rows[0] and rows[-1] < H - 1, "object cut by the image edge"
        u, v = uv[i, :, 0], uv[i, :, 1]
        residuals += [u.min() - cols[0], u.max() - (cols[-1] + 1), v.min() - rows[0], v.max() - (rows[-1] + 1)]
    residuals = np.asarray(residuals)
    assert abs(residuals.mean()) < 0.15
    assert np.abs(residuals).max() < 0.75


def _views_looking_at(target: np.ndarray, centres: np.ndarray, k: CameraIntrinsics = PINHOLE) -> PosedViews:
    """PosedViews (tiny blank images) whose cameras sit at ``centres`` and look at ``target``."""
    poses = []
    for c in centres:
        forward = (target - c) / np.linalg.norm(target - c)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        pose = np.eye(4)
        pose[:3, :3] = np.column_stack([right, down, forward])
        pose[:3, 3] = c
        poses.append(pose)
    n = len(poses)
    return PosedViews(np.zeros((n, 2, 2, 3), np.float32), np.zeros((n, 2, 2), np.float32), np.stack(poses), k,
                      tuple(f"f{i}" for i in range(n)))


def _ring(n: int, radius: float, height: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    az = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(-0.1, 0.1, n)
    return np.column_stack([radius * np.cos(az), radius * np.sin(az), height + rng.uniform(-0.1, 0.1, n)])


def test_common_look_at_point_finds_the_target():
    target = np.array([0.12, -0.05, 0.04])
    views = _views_looking_at(target, target + _ring(12, 0.3, 0.15))
    np.testing.assert_allclose(common_look_at_point(views), target, atol=1e-9)


def test_common_look_at_point_of_the_capture(can_capture):
    # the capture aims every camera at (0, 0, 0.45 x the can's height); the can is about 10 cm tall
    point = common_look_at_point(load_views(can_capture))
    np.testing.assert_allclose(point[:2], 0.0, atol=1e-9)
    assert 0.04 < point[2] < 0.05


def test_cameras_looking_in_different_directions_are_refused():
    rng = np.random.default_rng(4)
    views = _views_looking_at(np.zeros(3), _ring(12, 0.3, 0.15))
    poses = views.c2w_cv.copy()
    poses[:, :3, :3] = Rotation.random(len(poses), random_state=4).as_matrix()  # aim every camera anywhere
    scattered = PosedViews(views.rgb, views.mask, poses, views.intrinsics, views.names)
    with pytest.raises(UserInputError, match="common region"):
        common_look_at_point(scattered)
    # parallel optical axes: no point is nearest to all of them
    poses = views.c2w_cv.copy()
    poses[:, :3, :3] = np.diag([1.0, -1.0, -1.0])  # all look straight down
    poses[:, :3, 3] = np.column_stack([rng.uniform(-1, 1, (len(poses), 2)), np.ones(len(poses))])
    parallel = PosedViews(views.rgb, views.mask, poses, views.intrinsics, views.names)
    with pytest.raises(UserInputError, match="parallel"):
        common_look_at_point(parallel)


@pytest.mark.parametrize("every", [2, 3, 5, 10, 12])
def test_held_out_split_never_overlaps(every):
    for count in range(1, 101):
        train, held = held_out_split(count, every)
        assert np.intersect1d(train, held).size == 0
        np.testing.assert_array_equal(np.union1d(train, held), np.arange(count))
        np.testing.assert_array_equal(held, [i for i in range(count) if i % every == every // 2])
        if count >= MIN_VIEWS:
            assert len(train) >= count // 2  # training keeps most of the views


def test_load_views_arrays(can_capture):
    views = load_views(can_capture)
    n = views.count
    assert n == 60 and views.rgb.shape == (n, H, W, 3) and views.mask.shape == (n, H, W)
    assert views.rgb.dtype == np.float32 and 0.0 <= views.rgb.min() and views.rgb.max() <= 1.0
    assert set(np.unique(views.mask)) == {0.0, 1.0}
    # the can fills 6-17 % of each 160x120 image (measured)
    assert 0.03 < views.mask.mean(axis=(1, 2)).min() and views.mask.mean(axis=(1, 2)).max() < 0.3
    rot = views.c2w_cv[:, :3, :3]
    np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rot.shape), atol=1e-9)
    sub = views.subset(np.array([3, 7]))
    assert sub.count == 2 and sub.names == (views.names[3], views.names[7])
    np.testing.assert_array_equal(sub.rgb[1], views.rgb[7])


def test_large_images_are_reduced_with_their_camera(can_capture, tmp_path):
    """A capture stored at 3x its size (each pixel repeated 3x3, the camera scaled) loads back as the
    original at ``max_side_px`` = the original's width: the same pixels, masks and camera."""
    from PIL import Image

    from tests.reconstruct.conftest import copy_dataset, edit_transforms

    big = copy_dataset(can_capture, tmp_path / "big")
    for folder in ("images", "masks"):
        for path in sorted((big / folder).iterdir()):
            with Image.open(path) as im:
                im.resize((3 * im.width, 3 * im.height), Image.NEAREST).save(path)

    def tripled(data):
        for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            data[key] = 3 * data[key]
        return data

    edit_transforms(big, tripled)
    original = load_views(can_capture)
    reduced = load_views(big, max_side_px=W)
    assert load_views(big).rgb.shape[1:3] == (3 * H, 3 * W)  # None: as captured
    assert reduced.intrinsics.width == W and reduced.intrinsics.height == H
    for name in ("fl_x", "fl_y", "cx", "cy"):
        assert getattr(reduced.intrinsics, name) == pytest.approx(getattr(original.intrinsics, name), rel=1e-12)
    np.testing.assert_allclose(reduced.rgb, original.rgb, atol=1e-5)
    np.testing.assert_array_equal(reduced.mask, original.mask)


def test_working_size_keeps_the_aspect_ratio():
    from real2sim.multiview.views import working_size

    phone = CameraIntrinsics(4032, 3024, 3000.0, 3000.0, 2016.0, 1512.0)
    assert working_size(phone, 640) == (640, 480)
    assert working_size(phone, None) == (4032, 3024)
    assert working_size(PINHOLE, 640) == (160, 120)  # never enlarged


def test_frames_refine_poses_could_not_refine_are_named(can_capture, tmp_path):
    """Frames marked unrefined by refine-poses are kept and named; a subset names those it keeps."""
    from real2sim.formats.dataset import POSE_REFINED_KEY

    from tests.reconstruct.conftest import copy_dataset, edit_transforms

    def marked(data):
        for i, frame in enumerate(data["frames"]):
            frame[POSE_REFINED_KEY] = i >= 5
        return data

    all_views = load_views(can_capture)
    some = load_views(edit_transforms(copy_dataset(can_capture, tmp_path / "some"), marked))
    assert some.names == all_views.names and some.unrefined == all_views.names[:5]
    np.testing.assert_array_equal(some.c2w_cv, all_views.c2w_cv)
    assert some.subset(np.arange(3, 10)).unrefined == all_views.names[3:5]
    assert all_views.unrefined == ()
