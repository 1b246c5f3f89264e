"""A simulated capture turned into what a phone + COLMAP user has: images, masks and a COLMAP model
(``sparse/0``) in a random similarity frame.

Stand-in for COLMAP's triangulation: the sparse ``points3D`` are pixels of the exact depth maps
(``ground_truth/depth/*.png``, uint16 mm: table and object) back-projected with the exact poses,
with Gaussian noise and a share of outliers spread over the scene, then moved into the model
frame with the cameras. The points have no tracks (nothing in ``run`` reads them).
``ground_truth/`` stays in the capture's robot frame; ``ground_truth/model_from_world.json``
records the move, so that ``run`` can compare against the truth.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from real2sim.formats.dataset import CV_FROM_GL, read_dataset, read_ground_truth
from real2sim.capture.phone.robot_frame import Similarity, transform_poses


def random_similarity(rng: np.random.Generator, scale_range=(0.1, 10.0)) -> Similarity:
    """A uniformly random rotation, a translation of up to 5 units, a log-uniform scale."""
    from scipy.spatial.transform import Rotation

    scale = float(np.exp(rng.uniform(*np.log(scale_range))))
    return Similarity(scale, Rotation.random(random_state=rng).as_matrix(), rng.uniform(-5.0, 5.0, 3))


def depth_points(root: Path, per_view: int, rng: np.random.Generator) -> np.ndarray:
    """(P, 3) world points (metres) of ``per_view`` random valid pixels of each exact depth map."""
    from PIL import Image

    truth = read_ground_truth(root)
    k = truth.intrinsics
    out = []
    for frame, c2w_cv in zip(truth.frames, truth.poses_c2w_cv()):
        depth_m = np.asarray(Image.open(root / "ground_truth" / "depth" / Path(frame.file_path).name),
                             dtype=float) / 1000.0
        rows, cols = np.nonzero(depth_m > 0)
        pick = rng.choice(len(rows), min(per_view, len(rows)), replace=False)
        d = depth_m[rows[pick], cols[pick]]
        cam = np.stack([(cols[pick] + 0.5 - k.cx) / k.fl_x * d, (rows[pick] + 0.5 - k.cy) / k.fl_y * d, d], axis=1)
        out.append(cam @ c2w_cv[:3, :3].T + c2w_cv[:3, 3])
    return np.concatenate(out)


def make_colmap_capture(src: Path, dst: Path, model_from_world: Similarity, *, seed: int = 0,
                        points_per_view: int = 100, noise_mm: float = 0.5, outlier_fraction: float = 0.1,
                        max_points: int | None = None, ground_truth: bool = True) -> Path:
    """``dst``: images/, masks/, sparse/0 of ``src`` (a simulated capture) in the frame ``model_from_world``;
    ``max_points``: keep only that many sparse points (a model too thin for the table plane)."""
    import pycolmap

    rng = np.random.default_rng(seed)
    ds = read_dataset(src)
    dst.mkdir(parents=True)
    for folder in ("images", "masks"):
        shutil.copytree(src / folder, dst / folder)
    if ground_truth:
        shutil.copytree(src / "ground_truth", dst / "ground_truth")
        (dst / "ground_truth" / "model_from_world.json").write_text(
            json.dumps({"model_from_world": model_from_world.matrix().tolist()}))

    world = depth_points(src, points_per_view, rng)
    world += rng.normal(0.0, 1e-3 * noise_mm / np.sqrt(3), world.shape)
    n_out = int(outlier_fraction * len(world))
    world[rng.choice(len(world), n_out, replace=False)] = rng.uniform([-0.4, -0.4, -0.1], [0.4, 0.4, 0.4], (n_out, 3))
    if max_points is not None:
        world = world[rng.choice(len(world), min(max_points, len(world)), replace=False)]

    k = ds.intrinsics
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=k.width, height=k.height,
                                                    params=[k.fl_x, k.fl_y, k.cx, k.cy], camera_id=1))
    model_c2w_cv = transform_poses(model_from_world, ds.poses_c2w_gl()) @ CV_FROM_GL
    for i, (frame, c2w) in enumerate(zip(ds.frames, model_c2w_cv)):
        image = pycolmap.Image(name=Path(frame.file_path).name, camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.linalg.inv(c2w)[:3]))
    for xyz in model_from_world.apply(world):
        rec.add_point3D(xyz, pycolmap.Track())
    (dst / "sparse" / "0").mkdir(parents=True)
    rec.write(str(dst / "sparse" / "0"))
    return dst


#: nerfstudio's ``applied_transform`` (documented in ``ns-process-data``'s transforms.json): COLMAP's
#: axes turned so that its -y (usually up in a photo) becomes +z; a proper rotation.
NERFSTUDIO_APPLIED = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]])


def make_nerfstudio_capture(src: Path, dst: Path, model_from_world: Similarity, *, seed: int = 0,
                            point_cloud: bool = True) -> Path:
    """``dst`` laid out as ``ns-process-data`` leaves a COLMAP-posed capture: ``transforms.json`` in
    the COLMAP model's frame turned by ``applied_transform`` (OpenGL camera-to-world poses, one
    camera, ``mask_path`` per frame), ``colmap/sparse/0``, and with ``point_cloud`` the sparse points
    in that frame as an ASCII ``sparse_pc.ply`` that ``ply_file_path`` names. ``ground_truth/`` with
    ``model_from_world.json`` relating it to the transforms.json frame."""
    import trimesh

    from real2sim.formats.dataset import Dataset, write_transforms
    from real2sim.capture.phone.normalise import read_sparse_points

    make_colmap_capture(src, dst, model_from_world, seed=seed)
    model = read_dataset(dst)
    points, _ = read_sparse_points(model)
    (dst / "colmap").mkdir()
    shutil.move(dst / "sparse", dst / "colmap" / "sparse")
    applied = Similarity(1.0, NERFSTUDIO_APPLIED[:, :3], NERFSTUDIO_APPLIED[:, 3])
    frames = tuple(
        replace(frame, file_path=f"images/{Path(frame.file_path).name}", mask_path=f"masks/{Path(frame.file_path).stem}.png",
                transform_matrix=pose, extra={"colmap_im_id": i + 1})
        for i, (frame, pose) in enumerate(zip(model.frames, transform_poses(applied, model.poses_c2w_gl()))))
    extra = {"applied_transform": NERFSTUDIO_APPLIED.tolist()}
    if point_cloud:
        trimesh.PointCloud(applied.apply(points)).export(dst / "sparse_pc.ply", encoding="ascii")
        extra["ply_file_path"] = "sparse_pc.ply"
    write_transforms(dst / "transforms.json", Dataset(dst, model.intrinsics, frames, extra))
    (dst / "ground_truth" / "model_from_world.json").write_text(
        json.dumps({"model_from_world": (applied @ model_from_world).matrix().tolist()}))
    return dst
