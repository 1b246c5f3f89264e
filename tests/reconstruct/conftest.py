"""One small simulated capture of the can, shared by the reconstruct tests, and the tiny
settings that keep every reconstruction in this folder to seconds on a 2-core machine.

The capture has 60 views, not 24: with 24 (or 48) views of the can, ``hull.object_region``
cannot bound the object (a voxel that no camera sees counts as inside, so the search box
always touches its sides; see ``test_hull_and_stage.py::test_object_region_closes_with_24_views``).
From 60 views on the box closes (measured for 60, 72, 80, 90, 100 and 200 views).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

W, H = 160, 120
VIEWS = 60


def capture_can(out: Path, views: int = VIEWS) -> Path:
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    capture(make_textured_object("can"), out,
            CaptureConfig(views=views, width=W, height=H, pose_noise_mm=0, pose_noise_deg=0))
    return out


@pytest.fixture(scope="session")
def can_capture(tmp_path_factory) -> Path:
    """A 60-view, 160x120, noise-free capture of the can with masks and ground_truth/ (about 2-3 s)."""
    return capture_can(tmp_path_factory.mktemp("reconstruct_capture") / "can")


@pytest.fixture(scope="session")
def can_without_truth(can_capture, tmp_path_factory) -> Path:
    """The same capture without ground_truth/: the stage then skips its truth comparison.

    ``compare_to_truth`` costs ~12 s per call on this can (libigl's fast winding number on the
    can's long sliver cap triangles and on its convex hull's, 400k points each), more than the
    whole tiny reconstruction; tests that need the errors call it with fewer volume samples.
    """
    return copy_dataset(can_capture, tmp_path_factory.mktemp("reconstruct_no_truth") / "can")


@pytest.fixture(scope="session")
def truth(can_capture):
    """The true can in the capture's world frame (metres)."""
    from real2sim.reconstruct.truth import load_truth

    return load_truth(can_capture)


@pytest.fixture(scope="session")
def hull_result(can_capture, tiny_config):
    """The hull backend on the capture, with the truth comparison in its report (about 15 s)."""
    from dataclasses import replace

    from real2sim.reconstruct.stage import reconstruct

    return reconstruct(can_capture, replace(tiny_config, backend="hull"))


@pytest.fixture(scope="session")
def tiny_config():
    """A field and hull small enough for the default suite (field grid 18x18x24 -> 36x36x48)."""
    from real2sim.reconstruct.stage import ReconstructConfig
    from real2sim.reconstruct.field.train import FieldConfig

    field = FieldConfig(coarse_voxels=24, fine_voxels=48, coarse_steps=40, fine_steps=80, rays_per_step=1024)
    # max_faces 4000: xatlas takes ~10 s to unwrap the 28k-face hull surface, ~0.4 s for 4000 faces
    return ReconstructConfig(field=field, texture_px=256, hull_voxels=64, max_faces=4000)


def copy_dataset(src: Path, dst: Path, *, ground_truth: bool = False) -> Path:
    """A copy of a dataset folder (images, masks, transforms.json), optionally with ground_truth/."""
    ignore = None if ground_truth else shutil.ignore_patterns("ground_truth")
    shutil.copytree(src, dst, ignore=ignore)
    return dst


def edit_transforms(root: Path, edit) -> Path:
    """Rewrite ``root/transforms.json`` through ``edit(data) -> data``."""
    path = root / "transforms.json"
    path.write_text(json.dumps(edit(json.loads(path.read_text())), indent=2))
    return root


def raised_dataset(src: Path, dst: Path, dz_m: float) -> Path:
    """A copy of a capture with the world frame moved down by ``dz_m`` (everything, table included,
    ``dz_m`` higher): camera poses, true poses and the true object's pose; the table top at z = ``dz_m``."""
    copy_dataset(src, dst, ground_truth=True)

    def raise_frames(data):
        for frame in data["frames"]:
            frame["transform_matrix"][2][3] += dz_m
        if "support_z_m" in data:
            data["support_z_m"] += dz_m
        return data

    edit_transforms(dst, raise_frames)
    edit_transforms(dst / "ground_truth", raise_frames)
    pose_path = dst / "ground_truth" / "object_pose.json"
    pose = json.loads(pose_path.read_text())
    pose["world_from_mesh"][2][3] += dz_m
    pose_path.write_text(json.dumps(pose))
    return dst
