"""Structure from motion from scratch on a small simulated handheld capture (images only, as a phone
gives them): the poses match the truth up to a similarity, the focal length is found, the images come
back undistorted; camera groups, pairs for video frames and the refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from real2sim.capture.phone.sfm import SfmConfig, list_images, match_pairs, structure_from_motion
from real2sim.capture.phone.sfm_images import camera_groups
from real2sim.formats.dataset import CV_FROM_GL, read_ground_truth
from real2sim.plumbing.errors import UserInputError

VIEWS = 20


@pytest.fixture(scope="module")
def handheld(tmp_path_factory) -> Path:
    from real2sim.cli import main

    out = tmp_path_factory.mktemp("sfm") / "phone"
    assert main(["capture", "can", "--handheld", "--with-board", "--views", str(VIEWS), "--width-px", "320", "--height-px", "240",
                 "--out", str(out)]) == 0
    return out


def _aligned_errors(est_c2w: np.ndarray, true_c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-centre errors (m) and rotation errors (deg) after the similarity of the centres."""
    from real2sim.capture.poses.refinement import umeyama
    from real2sim.formats.dataset import rotation_angle_deg

    s, r, t = umeyama(est_c2w[:, :3, 3], true_c2w[:, :3, 3])
    centres = np.linalg.norm(s * est_c2w[:, :3, 3] @ r.T + t - true_c2w[:, :3, 3], axis=1)
    return centres, rotation_angle_deg(r @ est_c2w[:, :3, :3], true_c2w[:, :3, :3])


def test_sfm_from_scratch_matches_the_truth(handheld, tmp_path):
    paths = list_images(handheld)
    assert len(paths) == VIEWS  # the photos only: ground_truth/ is a sidecar
    result = structure_from_motion(paths, tmp_path / "images", SfmConfig())
    assert len(result.names) >= VIEWS - 2, result.left_out
    assert set(result.left_out) | set(result.sources) == {p.name for p in paths}
    truth = read_ground_truth(handheld)
    true_c2w = {Path(f.file_path).name: f.transform_matrix @ CV_FROM_GL for f in truth.frames}
    centres, angles = _aligned_errors(result.camera_to_world, np.stack([true_c2w[s] for s in result.sources]))
    assert np.median(centres) < 0.003 and centres.max() < 0.006, centres
    assert angles.max() < 1.0, angles
    # one OPENCV camera, its focal length found without EXIF help beyond the phone's guess
    (camera,) = result.cameras
    assert camera["model"] == "OPENCV" and camera["images"] == len(result.names)
    assert result.intrinsics.fl_x == pytest.approx(truth.intrinsics.fl_x, rel=0.02)
    assert (result.intrinsics.k1, result.intrinsics.k2) == (0.0, 0.0)  # the images written are undistorted
    from PIL import Image

    with Image.open(tmp_path / "images" / result.names[0]) as image:
        assert image.size == (320, 240)


def _png(path: Path, size: tuple[int, int], orientation: int | None = None) -> Path:
    from PIL import Image

    image = Image.fromarray(np.random.default_rng(0).integers(0, 255, (size[1], size[0], 3), dtype=np.uint8))
    exif = Image.Exif()
    if orientation:
        exif[0x0112] = orientation
    image.save(path, exif=exif) if path.suffix == ".jpg" else image.save(path)
    return path


def test_camera_groups_by_size_and_strays_left_out(tmp_path):
    paths = [_png(tmp_path / f"a{i}.png", (64, 48)) for i in range(4)]
    paths += [_png(tmp_path / f"b{i}.png", (80, 60)) for i in range(3)]
    paths.append(_png(tmp_path / "odd.png", (50, 50)))
    groups, left_out = camera_groups(paths, min_group_images=3)
    assert groups == [0, 0, 0, 0, 1, 1, 1, -1]
    assert list(left_out) == ["odd.png"] and "fewer than 3" in left_out["odd.png"]
    # a photo stored sideways (EXIF orientation 6) shown upright is 48x64: its own group
    rotated = [_png(tmp_path / f"r{i}.jpg", (64, 48), orientation=6) for i in range(3)]
    groups, _ = camera_groups(paths[:4] + rotated, min_group_images=3)
    assert groups == [0, 0, 0, 0, 1, 1, 1]


def test_mixed_sizes_without_groups_is_one_line(tmp_path):
    paths = [_png(tmp_path / f"p{i}.png", (40 + 8 * i, 30 + 4 * i)) for i in range(8)]
    with pytest.raises(UserInputError, match="do not form camera groups") as info:
        camera_groups(paths)
    assert "\n" not in str(info.value)


def test_pairs_for_video_frames_are_sequential_and_close_the_loop():
    pairs = match_pairs(40, overlap=3, loop_every=10)
    assert (0, 1) in pairs and (0, 3) in pairs and (0, 4) not in pairs
    assert (0, 30) in pairs and (10, 30) in pairs  # key frames all with each other: the orbit's end meets its start
    assert all(i < j for i, j in pairs) and len(set(pairs)) == len(pairs)


def test_too_few_registered_is_one_line(tmp_path):
    from PIL import Image

    paths = []
    for i in range(9):  # blank photos: no features
        paths.append(tmp_path / f"blank{i}.png")
        Image.fromarray(np.full((48, 64, 3), 128, np.uint8)).save(paths[-1])
    with pytest.raises(UserInputError, match=r"registered 0 of 9 images") as info:
        structure_from_motion(paths, tmp_path / "out")
    assert "\n" not in str(info.value) and "no features" in str(info.value)
