"""Simulated capture: dataset layout, camera conventions (checked against rendered masks and
depth), reachable poses, pose noise statistics, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from real2sim.capture.sim.capture_config import ReachabilityModel
from real2sim.capture.sim.wrist_camera import (
    CaptureConfig,
    camera_poses,
    capture,
    object_frame,
    perturb_poses,
)
from real2sim.formats.dataset import CV_FROM_GL, load_mask, read_dataset, read_ground_truth, rotation_angle_deg
from real2sim.plumbing.errors import UserInputError

W, H = 160, 120


@pytest.fixture(scope="module")
def bottle_capture(tmp_path_factory):
    from real2sim.geometry.objects import make_textured_object

    out = tmp_path_factory.mktemp("cap") / "bottle"
    capture(make_textured_object("bottle"), out, CaptureConfig(views=10, width=W, height=H, seed=3))
    return out


def _project(c2w_gl: np.ndarray, K: np.ndarray, pts_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (continuous, pixel centres at +0.5) and depths of world points."""
    w2c = np.linalg.inv(c2w_gl @ CV_FROM_GL)
    pc = pts_w @ w2c[:3, :3].T + w2c[:3, 3]
    uv = pc @ K.T
    return uv[:, :2] / uv[:, 2:], pc[:, 2]


def test_dataset_layout_and_schema(bottle_capture):
    root = bottle_capture
    data = json.loads((root / "transforms.json").read_text())
    assert data["camera_model"] == "OPENCV"
    assert (data["w"], data["h"]) == (W, H)
    # D435-like: 615 px at 640 wide, scaled with the image; principal point at the centre.
    assert data["fl_x"] == pytest.approx(615 * W / 640) and data["fl_y"] == pytest.approx(615 * H / 480)
    assert (data["cx"], data["cy"]) == (W / 2, H / 2)
    assert len(data["frames"]) == 10
    for i, fr in enumerate(data["frames"]):
        assert fr["file_path"] == f"images/frame_{i:05d}.png"
        assert fr["mask_path"] == f"masks/frame_{i:05d}.png"
        assert np.asarray(fr["transform_matrix"]).shape == (4, 4)
    ds = read_dataset(root)
    gt = read_ground_truth(root)
    assert [f.file_path for f in gt.frames] == [f.file_path for f in ds.frames]
    for sub in ("ground_truth/mesh.obj", "ground_truth/object_pose.json", "ground_truth/depth/frame_00000.png",
                "ground_truth/masks/frame_00009.png", "ground_truth/capture_config.json"):
        assert (root / sub).is_file(), sub
    assert not (root / "background").exists()
    assert not [p for p in root.parent.iterdir() if p.name.startswith(".")], "temporary folders left behind"
    from PIL import Image

    im = Image.open(root / "images/frame_00000.png")
    assert im.size == (W, H) and im.mode == "RGB"
    depth = np.asarray(Image.open(root / "ground_truth/depth/frame_00000.png"))
    assert depth.dtype == np.uint16 and depth.shape == (H, W)


def test_default_capture_has_no_hard_rig_marks(bottle_capture):
    """Without hard-rig flags the capture is as before (issue #28 keeps it byte for byte): PNG images,
    a table (no ``table_plane`` key), no hard_rig record, no per-frame extras, the D435 lens."""
    data = json.loads((bottle_capture / "transforms.json").read_text())
    gt = json.loads((bottle_capture / "ground_truth/transforms.json").read_text())
    assert "table_plane" not in data and "table_plane" not in gt and "hard_rig" not in data["real2sim"]
    assert data["real2sim"]["world_frame"] == "table top z=0, z up, metres"
    assert all(set(fr) == {"file_path", "transform_matrix", "mask_path"} for fr in data["frames"] + gt["frames"])
    assert all(fr["file_path"].endswith(".png") for fr in data["frames"])
    assert read_dataset(bottle_capture).extra.get("table_plane", True) is True


def test_object_centre_projects_onto_mask(bottle_capture):
    """OpenGL camera-to-world + intrinsics: the object's centre lands inside its rendered mask."""
    root = bottle_capture
    gt = read_ground_truth(root)
    mesh = trimesh.load(root / "ground_truth/mesh.obj", force="mesh")
    world_from_mesh = np.array(json.loads((root / "ground_truth/object_pose.json").read_text())["world_from_mesh"])
    centre_w = (world_from_mesh @ np.r_[mesh.bounds.mean(axis=0), 1.0])[:3]
    K = gt.intrinsics.matrix()
    for f in gt.frames:
        uv, z = _project(f.transform_matrix, K, centre_w[None])
        assert z[0] > 0, "object behind the camera: the camera must look along -z (OpenGL)"
        u, v = np.floor(uv[0]).astype(int)
        mask = load_mask(root / f.mask_path)
        assert mask[v, u], f"{f.file_path}: centre projects to ({u}, {v}), outside the object mask"
        # And the camera looks roughly at it: near the image centre.
        assert abs(uv[0, 0] - W / 2) < 0.3 * W and abs(uv[0, 1] - H / 2) < 0.3 * H


def test_table_depth_backprojects_to_table_plane(bottle_capture):
    """Depth + intrinsics + pose: table pixels back-project onto z = 0 (sub-millimetre consistency)."""
    from PIL import Image

    root = bottle_capture
    gt = read_ground_truth(root)
    K_inv = np.linalg.inv(gt.intrinsics.matrix())
    for f in gt.frames[::3]:
        depth_m = np.asarray(Image.open(root / "ground_truth/depth" / f.file_path.split("/")[-1])) / 1000.0
        mask = load_mask(root / f.mask_path)
        v, u = np.nonzero((depth_m > 0) & ~mask)
        pix = np.c_[u + 0.5, v + 0.5, np.ones_like(u)]
        pc = (pix @ K_inv.T) * depth_m[v, u, None]
        c2w = f.transform_matrix @ CV_FROM_GL
        pw = pc @ c2w[:3, :3].T + c2w[:3, 3]
        table = np.abs(pw[:, 2]) < 0.01
        assert table.mean() > 0.5
        # Depth is stored in whole millimetres: the plane is recovered to about that.
        assert np.median(np.abs(pw[table, 2])) < 1.5e-3


def test_pixel_centre_convention_subpixel(tmp_path):
    """A small sphere's mask centroid (pixel centres at u + 0.5) matches its projection to < 0.2 px."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.03)
    out = tmp_path / "sphere"
    capture(sphere, out, CaptureConfig(views=4, width=W, height=H, pose_noise_mm=0, pose_noise_deg=0))
    gt = read_ground_truth(out)
    world_from_mesh = np.array(json.loads((out / "ground_truth/object_pose.json").read_text())["world_from_mesh"])
    centre_w = world_from_mesh[:3, 3]  # the sphere's centre is its mesh origin
    for f in gt.frames:
        uv, _ = _project(f.transform_matrix, gt.intrinsics.matrix(), centre_w[None])
        v, u = np.nonzero(load_mask(out / f.mask_path))
        assert np.hypot(u.mean() + 0.5 - uv[0, 0], v.mean() + 0.5 - uv[0, 1]) < 0.2


def test_noise_applied_relative_to_ground_truth(bottle_capture):
    ds = read_dataset(bottle_capture)
    gt = read_ground_truth(bottle_capture)
    a, b = ds.poses_c2w_gl(), gt.poses_c2w_gl()
    rot = rotation_angle_deg(a[:, :3, :3], b[:, :3, :3])
    trans_mm = 1000 * np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)
    assert np.all(rot > 0) and np.all(trans_mm > 0)
    assert rot.max() < 4.0 and trans_mm.max() < 20.0


@pytest.mark.parametrize("noise_mm,noise_deg", [(5.0, 1.0), (2.0, 0.25)])
def test_noise_statistics(noise_mm, noise_deg):
    """RMS of the injected rotation / translation matches the configured magnitudes."""
    mesh = trimesh.creation.cylinder(radius=0.04, height=0.19)
    _, target, radius = object_frame(mesh)
    exact = camera_poses(CaptureConfig(views=200), target, radius)
    exact = np.concatenate([exact] * 10)
    noisy = perturb_poses(exact, noise_mm, noise_deg, seed=1)
    rot = rotation_angle_deg(noisy[:, :3, :3], exact[:, :3, :3])
    trans_mm = 1000 * np.linalg.norm(noisy[:, :3, 3] - exact[:, :3, 3], axis=1)
    assert np.sqrt(np.mean(rot ** 2)) == pytest.approx(noise_deg, rel=0.05)
    assert np.sqrt(np.mean(trans_mm ** 2)) == pytest.approx(noise_mm, rel=0.05)
    # Still rigid, and seeded.
    r = noisy[:, :3, :3]
    assert np.allclose(np.swapaxes(r, 1, 2) @ r, np.eye(3), atol=1e-9)
    assert np.array_equal(noisy, perturb_poses(exact, noise_mm, noise_deg, seed=1))
    assert not np.array_equal(noisy, perturb_poses(exact, noise_mm, noise_deg, seed=2))


def test_poses_reachable_above_table_and_uneven():
    mesh = trimesh.creation.cylinder(radius=0.04, height=0.19)
    _, target, radius = object_frame(mesh)
    cfg = CaptureConfig(views=200)
    poses = camera_poses(cfg, target, radius)
    assert poses.shape == (200, 4, 4)
    pos = poses[:, :3, 3]
    assert np.all(pos[:, 2] > 0.0), "a camera below the table top"
    rel = pos - target
    elev = np.degrees(np.arctan2(rel[:, 2], np.linalg.norm(rel[:, :2], axis=1)))
    assert elev.min() >= cfg.reach.min_elevation_deg and elev.max() >= 75.0, "needs views looking down into the object"
    assert np.all(cfg.reach.reachable(pos, target))
    # Every camera looks at the object (OpenGL: along -z).
    look = -poses[:, :3, 2]
    to_target = (target - pos) / np.linalg.norm(target - pos, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", look, to_target) > 0.999)
    # The arm stands at -x: the far side (+x) is seen from fewer, higher views.
    near = rel[:, 0] < -0.05
    far = rel[:, 0] > 0.05
    assert far.sum() < 0.8 * near.sum()
    assert elev[far].mean() > elev[near].mean()
    # No duplicates.
    assert len(np.unique(np.round(pos, 6), axis=0)) == 200


def test_reachability_model_filters():
    reach = ReachabilityModel()
    target = np.zeros(3)
    pts = np.array([[0.0, 0.0, -0.05],     # below the table
                    [1.5, 0.0, 0.3],       # far beyond the arm's reach
                    [-0.55, 0.0, 0.40],    # at the shoulder, too close
                    [-0.2, 0.0, 0.35]])    # fine
    assert reach.reachable(pts, target).tolist() == [False, False, False, True]


def test_bad_inputs_raise_and_leave_nothing(tmp_path):
    out = tmp_path / "ds"
    with pytest.raises(UserInputError, match="not found"):
        capture(tmp_path / "missing.obj", out, CaptureConfig(views=2, width=W, height=H))
    with pytest.raises(UserInputError, match="views"):
        capture(trimesh.creation.box(), out, CaptureConfig(views=0, width=W, height=H))
    with pytest.raises(UserInputError, match="noise"):
        capture(trimesh.creation.box(), out, CaptureConfig(views=2, width=W, height=H, pose_noise_mm=-1))
    with pytest.raises(UserInputError, match="reach"):
        capture(trimesh.creation.box(extents=(3.0, 3.0, 3.0)), out, CaptureConfig(views=5, width=W, height=H))
    assert list(tmp_path.iterdir()) == []
    out.mkdir()
    with pytest.raises(UserInputError, match="exists"):
        capture(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), out, CaptureConfig(views=2, width=W, height=H))
    assert list(out.iterdir()) == []


def test_with_background_renders_empty_table(tmp_path):
    from PIL import Image

    out = tmp_path / "bg"
    capture(trimesh.creation.box(extents=(0.08, 0.08, 0.12)), out,
            CaptureConfig(views=3, width=W, height=H, with_background=True))
    for i in range(3):
        img = np.asarray(Image.open(out / f"images/frame_{i:05d}.png")).astype(int)
        bg = np.asarray(Image.open(out / f"background/frame_{i:05d}.png")).astype(int)
        mask = load_mask(out / f"masks/frame_{i:05d}.png")
        diff = np.abs(img - bg).max(axis=2)
        assert diff[mask].mean() > 10  # the object is gone
        from scipy import ndimage

        far = ~ndimage.binary_dilation(mask, iterations=3)
        assert (diff[far] > 0).mean() < 0.01  # the rest is the same scene


def test_cli_capture(tmp_path, capsys):
    from real2sim.cli import main

    out = tmp_path / "cli"
    assert main(["capture", "can", "--out", str(out), "--views", "3", "--width-px", "96", "--height-px", "72",
                 "--seed", "2"]) == 0
    ds = read_dataset(out)
    assert len(ds.frames) == 3 and ds.intrinsics.width == 96
    assert main(["capture", str(tmp_path / "nope.obj"), "--out", str(tmp_path / "x")]) == 2
    with pytest.raises(SystemExit) as exc:  # a bad number is refused where argparse parses it
        main(["capture", "can", "--out", str(tmp_path / "y"), "--views", "0"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "mesh file not found" in err and "argument --views" in err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
