"""Hard captures (issue #28, part 7): turntable ring, long lens, cut-off views, no table, exposure and
white-balance jitter, JPEG, at small sizes. Each renders a few tiny views with Drake and checks the
images, the masks (the object's exact pixels) and ground_truth/ against the mesh itself."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from PIL import Image

from real2sim.capture.sim.hard_rigs import apply_colour_gains, cut_off_views
from real2sim.capture.sim.wrist_camera import CaptureConfig, camera_poses, capture, object_frame
from real2sim.formats.dataset import (CV_FROM_GL, TABLE_PLANE_KEY, has_table_plane, load_mask, read_dataset,
                                      read_ground_truth, stated_support_z_m)
from real2sim.plumbing.errors import UserInputError

W, H = 96, 72


def _can():
    from real2sim.geometry.objects import make_textured_object

    return make_textured_object("can")


def _object_in_world(root) -> trimesh.Trimesh:
    mesh = trimesh.load(root / "ground_truth/mesh.obj", force="mesh")
    pose = np.array(json.loads((root / "ground_truth/object_pose.json").read_text())["world_from_mesh"])
    return mesh.apply_transform(pose)


def _silhouette(mesh: trimesh.Trimesh, c2w_gl: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: pixels whose centre (u + 0.5, v + 0.5) a projected triangle of ``mesh`` covers -- an
    independent rasterisation of the object with the written pose and intrinsics."""
    w2c = np.linalg.inv(c2w_gl @ CV_FROM_GL)
    pc = mesh.vertices @ w2c[:3, :3].T + w2c[:3, 3]
    uv = (pc @ K.T)[:, :2] / pc[:, 2:]
    out = np.zeros(size[::-1], dtype=bool)
    for a, b, c in uv[mesh.faces]:
        lo = np.maximum(np.floor(np.minimum(np.minimum(a, b), c) - 0.5), 0).astype(int)
        hi = np.minimum(np.ceil(np.maximum(np.maximum(a, b), c) - 0.5), np.array(size) - 1).astype(int)
        if np.any(hi < lo):
            continue
        x, y = np.meshgrid(np.arange(lo[0], hi[0] + 1) + 0.5, np.arange(lo[1], hi[1] + 1) + 0.5)
        e = [(q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0]) for p, q in ((a, b), (b, c), (c, a))]
        inside = ((e[0] >= 0) & (e[1] >= 0) & (e[2] >= 0)) | ((e[0] <= 0) & (e[1] <= 0) & (e[2] <= 0))
        out[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] |= inside
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def _masks_match_object(root) -> None:
    """Every mask is the object's silhouette seen with the exact pose (:func:`_silhouette`); only pixels
    whose centre lies on a triangle's edge may go either way."""
    from scipy import ndimage

    gt = read_ground_truth(root)
    mesh = _object_in_world(root)
    k = gt.intrinsics
    for f in gt.frames:
        mask = load_mask(root / f.mask_path)
        sil = _silhouette(mesh, f.transform_matrix, k.matrix(), (k.width, k.height))
        assert _iou(mask, sil) > 0.98, f.file_path
        assert not (mask & ~ndimage.binary_dilation(sil)).any() and not (sil & ~ndimage.binary_dilation(mask)).any()


def _elevations_deg(c2w: np.ndarray, target: np.ndarray) -> np.ndarray:
    rel = c2w[:, :3, 3] - target
    return np.degrees(np.arctan2(rel[:, 2], np.linalg.norm(rel[:, :2], axis=1)))


@pytest.mark.parametrize("elevation_deg", [0.0, 35.0, -40.0])
def test_ring_cameras_at_the_elevation_asked(elevation_deg):
    mesh = trimesh.creation.cylinder(radius=0.035, height=0.12)
    _, target, radius = object_frame(mesh)
    cfg = CaptureConfig(views=10, width=W, height=H, ring_elevation_deg=elevation_deg, no_table=True)
    poses = camera_poses(cfg, target, radius)
    assert np.allclose(_elevations_deg(poses, target), elevation_deg, atol=1e-9)
    rel = poses[:, :3, 3] - target
    az = np.sort(np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360)
    assert np.allclose(np.diff(az), 36.0) and np.ptp(np.linalg.norm(rel, axis=1)) < 1e-12
    look = -poses[:, :3, 2]  # OpenGL: the camera looks along -z, at the target
    assert np.allclose(np.einsum("ij,ij->i", look, -rel / np.linalg.norm(rel, axis=1, keepdims=True)), 1.0)


def test_level_ring_capture_sees_the_object_from_its_middle(tmp_path):
    out = tmp_path / "ring"
    capture(_can(), out, CaptureConfig(views=8, width=W, height=H, ring_elevation_deg=0.0, seed=1))
    gt = read_ground_truth(out)
    mesh = _object_in_world(out)
    middle = np.array([0.0, 0.0, mesh.bounds[:, 2].mean()])
    assert np.allclose(_elevations_deg(gt.poses_c2w_gl(), middle), 0.0, atol=1e-9)
    top = mesh.bounds[1, 2]
    assert np.all(gt.poses_c2w_gl()[:, 2, 3] < top), "level cameras stand below the object's top"
    _masks_match_object(out)
    meta = json.loads((out / "transforms.json").read_text())["real2sim"]
    assert meta["hard_rig"]["ring_elevation_deg"] == 0.0


def test_ring_below_table_is_refused(tmp_path):
    with pytest.raises(UserInputError, match="below the table top.*--no-table"):
        capture(_can(), tmp_path / "x", CaptureConfig(views=8, width=W, height=H, ring_elevation_deg=-40.0))
    assert list(tmp_path.iterdir()) == []


def test_long_lens_intrinsics_and_distance(tmp_path):
    """fx = 3300 px at 640x480 is fx = 495 px at 96x72: the camera stands back and the object still fills
    the view (neither lost nor spilling over the border)."""
    fl = 3300.0 * W / 640
    out = tmp_path / "long"
    capture(_can(), out, CaptureConfig(views=8, width=W, height=H, focal_px=fl, pose_noise_mm=0, pose_noise_deg=0))
    data = json.loads((out / "transforms.json").read_text())
    assert (data["fl_x"], data["fl_y"], data["cx"], data["cy"], data["w"], data["h"]) == (fl, fl, W / 2, H / 2, W, H)
    gt = read_ground_truth(out)
    mesh = _object_in_world(out)
    dist = np.linalg.norm(gt.poses_c2w_gl()[:, :3, 3] - mesh.bounds.mean(axis=0), axis=1)
    _, target, radius = object_frame(mesh)
    default = camera_poses(CaptureConfig(views=8, width=W, height=H), target, radius)
    assert dist.min() > 4.0 * np.linalg.norm(default[:, :3, 3] - target, axis=1).min()
    spans = []
    for f in gt.frames:
        v, u = np.nonzero(load_mask(out / f.mask_path))
        assert u.min() > 0 and u.max() < W - 1 and v.min() > 0 and v.max() < H - 1, "the border cuts the object"
        spans.append(max(np.ptp(u), np.ptp(v)) + 1)
    assert max(spans) > 0.5 * H, "the object is lost in the distance"
    _masks_match_object(out)
    cfg = CaptureConfig(width=W, height=H, fov_deg=60.0)
    assert cfg.camera().fl_x == pytest.approx(W / 2 / np.tan(np.radians(30.0))) == cfg.camera().fl_y


def test_cut_off_views_cross_the_border_and_masks_match(tmp_path):
    out = tmp_path / "cut"
    capture(_can(), out, CaptureConfig(views=8, width=W, height=H, cut_off_fraction=0.5, seed=4))
    gt = read_ground_truth(out)
    cut = [f.extra["real2sim_cut_off"] for f in gt.frames]
    assert cut == [i in cut_off_views(8, 0.5) for i in range(8)] and sum(cut) == 4
    vertices = _object_in_world(out).vertices
    for f, is_cut in zip(gt.frames, cut):
        m = load_mask(out / f.mask_path)
        on_border = m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any()
        assert on_border == is_cut, f.file_path
        w2c = np.linalg.inv(f.transform_matrix @ CV_FROM_GL)
        uv = ((vertices @ w2c[:3, :3].T + w2c[:3, 3]) @ gt.intrinsics.matrix().T)
        uv = uv[:, :2] / uv[:, 2:]
        inside = np.mean((uv[:, 0] > 0) & (uv[:, 0] < W) & (uv[:, 1] > 0) & (uv[:, 1] < H))
        assert (0.4 < inside < 0.95) if is_cut else inside == 1.0, (f.file_path, inside)
    _masks_match_object(out)
    # Its poses are what the images show: the reported ones are the exact ones plus the usual noise.
    from real2sim.formats.dataset import pose_errors

    rot, trans_mm = pose_errors(read_dataset(out).poses_c2w_gl(), gt.poses_c2w_gl())
    assert rot.max() < 4.0 and trans_mm.max() < 20.0


def test_no_table_stand_not_in_masks_and_dataset_says_so(tmp_path):
    from PIL import Image as PILImage

    out = tmp_path / "stand"
    capture(_can(), out, CaptureConfig(views=8, width=W, height=H, no_table=True, seed=2))
    ds = read_dataset(out)
    assert ds.extra[TABLE_PLANE_KEY] is False and not has_table_plane(ds)
    assert stated_support_z_m(ds) == 0.0  # the stand's top, where the object's lowest point is
    assert read_ground_truth(out).extra[TABLE_PLANE_KEY] is False
    mesh = _object_in_world(out)
    assert abs(mesh.bounds[0, 2]) < 1e-9, "the object's lowest point is z = 0"
    gt = read_ground_truth(out)
    k_inv = np.linalg.inv(gt.intrinsics.matrix())
    stand_px = 0
    for f in gt.frames:
        depth_m = np.asarray(PILImage.open(out / "ground_truth/depth" / f"{f.file_path[7:-4]}.png")) / 1000.0
        mask = load_mask(out / f.mask_path)
        v, u = np.nonzero(depth_m > 0)
        pc = (np.c_[u + 0.5, v + 0.5, np.ones_like(u)] @ k_inv.T) * depth_m[v, u, None]
        c2w = f.transform_matrix @ CV_FROM_GL
        pw = pc @ c2w[:3, :3].T + c2w[:3, 3]
        below = pw[:, 2] < -0.01  # the stand: returns under the object, near its axis
        assert np.all(np.hypot(pw[below, 0], pw[below, 1]) < 0.01)
        assert not mask[v[below], u[below]].any(), "the stand is not the object"
        stand_px += int(below.sum())
        # No table: what is neither object nor stand is the empty, dark background.
        rgb = np.asarray(PILImage.open(out / f.file_path))
        from scipy import ndimage

        empty = ~ndimage.binary_dilation((depth_m > 0) | mask, iterations=1)  # edges blend with the object
        assert empty.mean() > 0.5 and rgb[empty].max() < 20
    assert stand_px > 0, "the stand is seen"
    _masks_match_object(out)


def test_jitter_changes_images_per_view_not_masks(tmp_path):
    base, jit = tmp_path / "base", tmp_path / "jit"
    cfg = CaptureConfig(views=8, width=W, height=H, seed=5)
    capture(_can(), base, cfg)
    capture(_can(), jit, CaptureConfig(views=8, width=W, height=H, seed=5, exposure_jitter_stops=0.5,
                                       white_balance_jitter=0.1))
    gt = read_ground_truth(jit)
    assert np.array_equal(read_dataset(base).poses_c2w_gl(), read_dataset(jit).poses_c2w_gl())
    ratios = []
    for f in gt.frames:
        assert (base / f.mask_path).read_bytes() == (jit / f.mask_path).read_bytes()
        a = np.asarray(Image.open(base / f.file_path))
        b = np.asarray(Image.open(jit / f.file_path))
        gains = np.array(f.extra["real2sim_colour_gains"])
        assert np.array_equal(b, apply_colour_gains(a, gains)), "each view is the plain render times its gains"
        mask = load_mask(jit / f.mask_path)
        ratios.append(b[mask].astype(float).mean(axis=0) / a[mask].astype(float).mean(axis=0))
    ratios = np.array(ratios)
    assert np.std(np.log(ratios[:, 1])) > 0.1, "exposure differs between views"
    assert np.std(np.log(ratios[:, 0] / ratios[:, 1])) > 0.02, "white balance differs between views"


def test_all_flags_together_jpeg_at_low_resolution_load(tmp_path):
    """Every flag at once, JPEG at 64x48: the files are JPEG, masks PNG, and the reconstruction's reader takes it."""
    from real2sim.multiview.views import load_views

    out = tmp_path / "hard"
    cfg = CaptureConfig(views=10, width=64, height=48, ring_elevation_deg=0.0, focal_px=3300.0 / 10,
                        cut_off_fraction=0.3, no_table=True, exposure_jitter_stops=0.4, white_balance_jitter=0.1,
                        jpeg_quality=80, with_background=True, seed=6)
    capture(_can(), out, cfg)
    ds = read_dataset(out)
    for f in ds.frames:
        assert f.file_path.endswith(".jpg") and f.mask_path.endswith(".png")
        assert (out / f.file_path).read_bytes()[:3] == b"\xff\xd8\xff"
        with Image.open(out / f.file_path) as im:
            assert im.format == "JPEG" and im.size == (64, 48)
        with Image.open(out / f.mask_path) as im:
            assert im.format == "PNG"
        assert (out / "background" / f.file_path.split("/")[1]).is_file()
    views = load_views(out)
    assert views.count == 10 and views.rgb.shape[1:] == (48, 64, 3)
    assert sum(f.extra["real2sim_cut_off"] for f in read_ground_truth(out).frames) == 3
    _masks_match_object(out)


def test_cli_help_units_and_bad_values(tmp_path, capsys, monkeypatch):
    from real2sim.cli import main

    monkeypatch.setenv("COLUMNS", "2000")  # one line per option: no word broken at a hyphen
    with pytest.raises(SystemExit) as exc:
        main(["capture", "--help"])
    assert exc.value.code == 0
    lines: dict[str, str] = {}  # each option's entry, its continuation lines joined
    flag = None
    for line in capsys.readouterr().out.splitlines():
        if line.startswith("  --"):
            flag = line.split()[0]
            lines[flag] = line
        elif flag and line.startswith("   "):
            lines[flag] += " " + line.strip()
        else:
            flag = None
    for flag, unit in [("--ring-elevation-deg", "degrees"), ("--focal-px", "pixels"), ("--fov-deg", "degrees"),
                       ("--cut-off-fraction", "fraction"), ("--exposure-jitter-stops", "stops"),
                       ("--white-balance-jitter", "fraction"), ("--jpeg-quality", "1-100"), ("--no-table", "z = 0")]:
        assert unit in lines[flag], flag
    base = ["capture", "can", "--out", str(tmp_path / "o"), "--views", "8", "--width-px", "64", "--height-px", "48"]
    for bad in (["--ring-elevation-deg", "95"], ["--focal-px", "0"], ["--fov-deg", "180"],
                ["--cut-off-fraction", "1.5"], ["--exposure-jitter-stops", "-1"], ["--white-balance-jitter", "nan"],
                ["--jpeg", "--jpeg-quality", "0"], ["--focal-px", "500", "--fov-deg", "40"]):
        with pytest.raises(SystemExit) as exc:
            main(base + bad)
        assert exc.value.code == 2, bad
        err = capsys.readouterr().err
        assert "error: argument" in err and any(flag in err for flag in bad if flag.startswith("--")), err
    # Refused after parsing: one line, exit 2, nothing written.
    assert main(base + ["--jpeg-quality", "50"]) == 2
    assert main(base + ["--ring-elevation-deg", "-40"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "--jpeg-quality needs --jpeg" in err[0] and "--no-table" in err[1]
    assert not (tmp_path / "o").exists()
    assert main(base + ["--no-table", "--ring-elevation-deg", "-40", "--jpeg", "--cut-off-fraction", "0.25"]) == 0
    assert read_dataset(tmp_path / "o").extra[TABLE_PLANE_KEY] is False
