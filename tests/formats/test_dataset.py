"""nerfstudio transforms.json datasets: round trip, validation errors, COLMAP model import."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from real2sim.formats.dataset import (
    CV_FROM_GL,
    CameraIntrinsics,
    Dataset,
    Frame,
    check_rigid,
    pose_errors,
    read_dataset,
    realsense_d435_intrinsics,
    write_transforms,
)
from real2sim.plumbing.errors import UserInputError


def _make_dataset(root, n=4, w=32, h=24, seed=0) -> Dataset:
    rng = np.random.default_rng(seed)
    (root / "images").mkdir(parents=True)
    (root / "masks").mkdir()
    frames = []
    for i in range(n):
        Image.fromarray(rng.integers(0, 255, (h, w, 3), dtype=np.uint8)).save(root / f"images/im{i}.png")
        Image.fromarray(np.full((h, w), 255, np.uint8)).save(root / f"masks/im{i}.png")
        m = np.eye(4)
        m[:3, :3] = Rotation.random(random_state=seed + i).as_matrix()
        m[:3, 3] = rng.normal(size=3)
        frames.append(Frame(f"images/im{i}.png", m, f"masks/im{i}.png"))
    ds = Dataset(root, realsense_d435_intrinsics(w, h), tuple(frames), {"note": "kept"})
    write_transforms(root / "transforms.json", ds)
    return ds


def test_round_trip(tmp_path):
    ds = _make_dataset(tmp_path)
    back = read_dataset(tmp_path)
    assert back.intrinsics == ds.intrinsics
    assert [f.file_path for f in back.frames] == [f.file_path for f in ds.frames]
    assert [f.mask_path for f in back.frames] == [f.mask_path for f in ds.frames]
    assert np.allclose(back.poses_c2w_gl(), ds.poses_c2w_gl())
    assert back.extra["note"] == "kept"
    # OpenCV axes are the OpenGL ones with y and z flipped.
    cv = back.poses_c2w_cv()
    assert np.allclose(cv[:, :3, 0], back.poses_c2w_gl()[:, :3, 0])
    assert np.allclose(cv[:, :3, 2], -back.poses_c2w_gl()[:, :3, 2])
    # The file is nerfstudio's layout.
    data = json.loads((tmp_path / "transforms.json").read_text())
    assert {"fl_x", "fl_y", "cx", "cy", "w", "h", "camera_model", "frames"} <= set(data)
    assert read_dataset(tmp_path / "transforms.json").intrinsics == ds.intrinsics


def test_intrinsics():
    k = realsense_d435_intrinsics()
    assert (k.fl_x, k.fl_y, k.cx, k.cy, k.width, k.height) == (615.0, 615.0, 320.0, 240.0, 640, 480)
    assert realsense_d435_intrinsics(160, 120) == k.scaled(160, 120)
    assert np.allclose(k.matrix(), [[615, 0, 320], [0, 615, 240], [0, 0, 1]])


def _edit(root, fn):
    path = root / "transforms.json"
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("edit,message", [
    (lambda d: d.update(frames=[]), "no frames"),
    (lambda d: d.pop("frames"), "no frames"),
    (lambda d: d["frames"][1].pop("transform_matrix"), "needs file_path and transform_matrix"),
    (lambda d: d["frames"][1].update(transform_matrix=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
     "not rigid"),
    (lambda d: d["frames"][1].update(transform_matrix=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]),
     "not rigid"),
    (lambda d: d["frames"][1].update(transform_matrix=[[1, 0, 0], [0, 1, 0]]), "shape"),
    (lambda d: d["frames"][1].update(transform_matrix=[[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0],
                                                       [0, 0, 0, 1]]), "non-finite"),
    (lambda d: d["frames"][1].update(transform_matrix="abc"), "numeric"),
    (lambda d: d["frames"][2].update(file_path="images/missing.png"), "not found"),
    (lambda d: d["frames"][2].update(mask_path="masks/missing.png"), "not found"),
    (lambda d: d["frames"][3].update(file_path="images/im0.png"), "duplicate"),
    (lambda d: d.pop("fl_x"), "missing camera intrinsics"),
    (lambda d: d.update(w=0), "invalid camera intrinsics"),
    (lambda d: d.update(camera_model="EQUIRECTANGULAR"), "not supported"),
    (lambda d: d.update(table_plane=False, support_z_m=float("nan")), "support_z_m must be a number"),
    (lambda d: d.update(table_plane=False, support_z_m=True), "support_z_m must be a number"),
    (lambda d: d.update(support_z_m=0.0), "support_z_m is for a dataset without a table"),
])
def test_invalid_transforms_raise_one_line(tmp_path, edit, message):
    _make_dataset(tmp_path)
    _edit(tmp_path, edit)
    with pytest.raises(UserInputError, match=message) as err:
        read_dataset(tmp_path)
    assert "\n" not in str(err.value)


def test_unreadable_inputs(tmp_path):
    with pytest.raises(UserInputError, match="not found"):
        read_dataset(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserInputError, match="neither transforms.json nor a COLMAP model"):
        read_dataset(tmp_path / "empty")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad/transforms.json").write_text("{not json")
    with pytest.raises(UserInputError, match="not readable JSON"):
        read_dataset(tmp_path / "bad")
    (tmp_path / "bad/transforms.json").write_text("[1, 2]")
    with pytest.raises(UserInputError, match="JSON object"):
        read_dataset(tmp_path / "bad")


def test_per_frame_intrinsics_must_agree(tmp_path):
    _make_dataset(tmp_path)

    def per_frame(d):
        for fr in d["frames"]:
            fr.update({k: d[k] for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")})
        for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
            d.pop(k)
    _edit(tmp_path, per_frame)
    assert read_dataset(tmp_path).intrinsics.width == 32
    _edit(tmp_path, lambda d: d["frames"][1].update(fl_x=99.0))
    with pytest.raises(UserInputError, match="different intrinsics"):
        read_dataset(tmp_path)


def test_check_rigid_accepts_3x4():
    m = check_rigid(np.eye(4)[:3], "x")
    assert np.array_equal(m, np.eye(4))


def test_pose_errors():
    a = np.tile(np.eye(4), (2, 1, 1))
    b = a.copy()
    b[1, :3, :3] = Rotation.from_rotvec([0, 0, np.radians(2.0)]).as_matrix()
    b[1, :3, 3] = [0.003, 0.004, 0.0]
    rot, trans = pose_errors(a, b)
    assert np.allclose(rot, [0.0, 2.0]) and np.allclose(trans, [0.0, 5.0])


def test_colmap_model_import(tmp_path):
    """images + sparse/0 (a COLMAP model) is read as a dataset with the same camera-to-world poses."""
    pycolmap = pytest.importorskip("pycolmap")
    ds = _make_dataset(tmp_path, n=3, w=40, h=30)
    (tmp_path / "transforms.json").unlink()
    rec = pycolmap.Reconstruction()
    k = ds.intrinsics
    cam = pycolmap.Camera(model="PINHOLE", width=k.width, height=k.height, params=[k.fl_x, k.fl_y, k.cx, k.cy],
                          camera_id=1)
    rec.add_camera_with_trivial_rig(cam)
    for i, f in enumerate(ds.frames):
        cfw = np.linalg.inv(f.transform_matrix @ CV_FROM_GL)[:3]
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f.file_path.split("/")[1], camera_id=1, image_id=i + 1),
                                         pycolmap.Rigid3d(cfw))
    (tmp_path / "sparse/0").mkdir(parents=True)
    rec.write(str(tmp_path / "sparse/0"))
    back = read_dataset(tmp_path)
    assert back.intrinsics == CameraIntrinsics(k.width, k.height, k.fl_x, k.fl_y, k.cx, k.cy)
    assert [f.file_path for f in back.frames] == [f.file_path for f in ds.frames]
    assert [f.mask_path for f in back.frames] == [f.mask_path for f in ds.frames]
    assert np.allclose(back.poses_c2w_gl(), ds.poses_c2w_gl(), atol=1e-9)
    (tmp_path / "sparse/0/cameras.bin").write_bytes(b"garbage")
    with pytest.raises(UserInputError, match="COLMAP model"):
        read_dataset(tmp_path)


def _damage(root, name, how):
    """Damage one file of a `_make_dataset` folder: empty, truncated, not an image, or another size."""
    path = root / name
    if how == "empty":
        path.write_bytes(b"")
    elif how == "truncated":
        path.write_bytes(path.read_bytes()[:40])
    elif how == "garbage":
        path.write_bytes(b"not an image at all" * 10)
    elif how == "other size":
        mode = "L" if name.startswith("masks") else "RGB"
        Image.new(mode, (16, 12)).save(path)


@pytest.mark.parametrize("name", ["images/im2.png", "masks/im1.png"])
@pytest.mark.parametrize("how,message", [
    ("empty", "is empty"), ("truncated", "not a readable image"), ("garbage", "not a readable image"),
    ("other size", "is 16x12 px, but the dataset's camera is 32x24"),
])
def test_bad_image_or_mask_is_refused_up_front(tmp_path, name, how, message):
    _make_dataset(tmp_path)
    _damage(tmp_path, name, how)
    with pytest.raises(UserInputError, match=message) as err:
        read_dataset(tmp_path)
    assert name in str(err.value) and "\n" not in str(err.value)
    read_dataset(tmp_path, check_files=False)  # the poses alone are still readable


def test_images_must_match_the_intrinsics(tmp_path):
    _make_dataset(tmp_path)
    _edit(tmp_path, lambda d: d.update(w=64, h=48, cx=32.0, cy=24.0))
    with pytest.raises(UserInputError, match="is 32x24 px, but the dataset's camera is 64x48"):
        read_dataset(tmp_path)


@pytest.mark.parametrize("key", ["file_path", "mask_path"])
@pytest.mark.parametrize("path", ["../outside.png", "images/../../outside.png", "/etc/passwd"])
def test_paths_outside_the_dataset_are_refused(tmp_path, key, path):
    root = tmp_path / "ds"
    _make_dataset(root)
    Image.new("RGB", (32, 24)).save(tmp_path / "outside.png")
    _edit(root, lambda d: d["frames"][1].update({key: path}))
    with pytest.raises(UserInputError, match=f"{key} '.*' points outside the dataset folder"):
        read_dataset(root)
    with pytest.raises(UserInputError, match="points outside"):
        read_dataset(root, check_files=False)


def test_absolute_paths_inside_the_dataset_are_kept(tmp_path):
    _make_dataset(tmp_path)
    inside = str(tmp_path / "images" / "im1.png")
    _edit(tmp_path, lambda d: d["frames"][1].update(file_path=inside))
    assert read_dataset(tmp_path).frames[1].file_path == inside
