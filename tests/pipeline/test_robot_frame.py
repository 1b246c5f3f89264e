"""Captures without a robot: the robot frame from a COLMAP model (real2sim.capture.phone.robot_frame, .normalise).

Unit tests of the plane fit, the similarity and its action on poses; then `run` end to end on a
small simulated capture of the can (60 views at 120x90 px, no pose noise: with fewer views the
can's visual hull does not close, tests/reconstruct/conftest.py) moved into a random similarity
frame as a COLMAP model (tests/pipeline/colmap_capture.py: sparse points from the exact depth maps,
0.5 mm noise, 10 % outliers). The asset from the moved capture (--object-height-m = the can's true
height, 0.1 m) is compared with the asset from the original, robot-frame capture; so is the asset
from the same capture laid out as nerfstudio's ``ns-process-data`` writes it (transforms.json in the
COLMAP frame turned by ``applied_transform``, sparse_pc.ply, colmap/sparse/0).

Tolerances asserted (measured on this capture, seed 5, scale 4.07, in brackets: --object-height-m /
--scale at the exact scale): mass exact; CoM in the asset frame within 1 mm (0.012 / 0.016 mm);
inertia eigenvalues within 5 % (0.43 / 0.01 %); extents of the asset's watertight mesh within 2 %
(0.25 / 0.47 %) and its volume within 3 % (0.61 / 0.004 %). With the height, the asset is slightly
smaller: its scale comes from the visual hull's height (an outer bound, 0.2 % above the true top at
128 voxels); with --scale the differences come from the yaw, which turns the voxel grid against the
object. Normalised camera poses against the true ones after removing the free yaw and x/y shift:
rotation within 0.05 deg (0.003 deg both), camera centres within 2 mm (0.76 / 0.017 mm: the 0.2 %
scale error at ~0.3 m). Errors of the frame against the truth (robot_frame.json): scale within 1 %
(-0.20 %), table tilt within 0.05 deg (0.003 deg), table height within 0.5 mm (0.0003 mm).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from real2sim.plumbing.errors import UserInputError
from real2sim.capture.phone import robot_frame as rf
from tests.pipeline.colmap_capture import make_colmap_capture, make_nerfstudio_capture, random_similarity
from tests.reconstruct.conftest import raised_dataset

HULL = ["--backend", "hull", "--voxels", "64", "--max-faces", "4000", "--texture-px", "256",
        "--collision", "mesh", "--mass-kg", "0.35"]
FAST = [*HULL, "--no-refine-poses"]  # a metric capture's poses as given (refining them is run's default)
CAN_HEIGHT_M = 0.1


def _random_rotation(rng) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.random(random_state=rng).as_matrix()


def _plane_points(rng, normal, offset, count, noise):
    """Points on the plane normal . x = offset (spread over 2 units), with Gaussian noise along the normal."""
    basis = np.linalg.svd(normal[None])[2][1:]  # two directions in the plane
    uv = rng.uniform(-1.0, 1.0, (count, 2))
    return offset * normal + uv @ basis + rng.normal(0.0, noise, count)[:, None] * normal


# ----------------------------------------------------------------------------- unit tests


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plane_fit_finds_the_plane_among_outliers_and_noise(seed):
    rng = np.random.default_rng(seed)
    normal = _random_rotation(rng)[:, 0]
    offset = rng.uniform(-3, 3)
    on = _plane_points(rng, normal, offset, 600, noise=0.002)
    off = rng.uniform(-1.5, 1.5, (400, 3)) + offset * normal  # 40 % outliers around it
    points = rng.permutation(np.concatenate([on, off]))
    plane = rf.fit_plane_ransac(points, threshold=0.01, seed=seed)
    if plane.normal @ normal < 0:
        plane = plane.flipped()
    angle = np.degrees(np.arccos(np.clip(plane.normal @ normal, -1, 1)))
    assert angle < 0.5 and abs(plane.offset - offset) < 0.002
    assert 600 <= plane.inliers < 640 and plane.rms == pytest.approx(0.002, rel=0.3)
    again = rf.fit_plane_ransac(points, threshold=0.01, seed=seed)
    assert np.array_equal(again.normal, plane.normal) or np.array_equal(again.normal, -plane.normal)  # seeded


def test_plane_fit_refuses_too_few_points_or_no_plane():
    rng = np.random.default_rng(0)
    with pytest.raises(UserInputError, match="only 10 sparse points"):
        rf.fit_plane_ransac(rng.normal(size=(10, 3)), 0.01, seed=0)
    with pytest.raises(UserInputError, match="no table plane"):
        rf.fit_plane_ransac(rng.normal(size=(200, 3)), 1e-4, seed=0)
    line = np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 3.0])
    with pytest.raises(UserInputError, match="collinear"):
        rf.fit_plane_ransac(line, 0.01, seed=0)


def test_plane_normal_turns_towards_the_cameras():
    plane = rf.Plane(np.array([0.0, 0.0, -1.0]), 0.5)  # z = -0.5, normal pointing down
    above = np.array([[0.1, 0.0, 1.0], [0.0, 0.3, 2.0], [-1.0, 0.0, 0.2]])
    up = rf.orient_towards_cameras(plane, above)
    assert np.allclose(up.normal, [0, 0, 1]) and up.offset == -0.5
    assert np.all(up.distance(above) > 0)
    assert rf.orient_towards_cameras(up, above) is up
    with pytest.raises(UserInputError, match="both sides"):
        rf.orient_towards_cameras(up, np.array([[0, 0, 1.0], [0, 0, -2.0]]))


def test_similarity_algebra_and_matrix_round_trip():
    rng = np.random.default_rng(3)
    a = rf.Similarity(2.5, _random_rotation(rng), rng.normal(size=3))
    b = rf.Similarity(0.3, _random_rotation(rng), rng.normal(size=3))
    x = rng.normal(size=(20, 3))
    assert np.allclose((a @ b).apply(x), a.apply(b.apply(x)))
    assert np.allclose(a.inverse().apply(a.apply(x)), x)
    assert np.allclose((a @ b).matrix(), a.matrix() @ b.matrix())
    back = rf.Similarity.from_matrix(a.matrix())
    assert back.scale == pytest.approx(2.5) and np.allclose(back.rotation, a.rotation)
    assert np.allclose(back.translation, a.translation)
    with pytest.raises(UserInputError):
        rf.Similarity.from_matrix(np.diag([1.0, 1.0, -1.0, 1.0]))  # a reflection


def test_rotation_taking_and_nearest_rotation():
    rng = np.random.default_rng(4)
    for a in [rng.normal(size=3), np.array([0.0, 0, -1]), np.array([0.0, 0, 1])]:
        r = rf.rotation_taking(a, [0, 0, 1])
        assert np.allclose(r @ (a / np.linalg.norm(a)), [0, 0, 1])
        assert np.allclose(r.T @ r, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)
    noisy = _random_rotation(rng) + 1e-3 * rng.normal(size=(3, 3))
    fixed = rf.nearest_rotation(noisy)
    assert np.allclose(fixed.T @ fixed, np.eye(3), atol=1e-12) and np.abs(fixed - noisy).max() < 5e-3


def test_poses_moved_and_back_stay_rigid():
    from real2sim.formats.dataset import check_rigid

    rng = np.random.default_rng(5)
    c2w = np.tile(np.eye(4), (6, 1, 1))
    c2w[:, :3, :3] = [_random_rotation(rng) for _ in range(6)]
    c2w[:, :3, 3] = rng.normal(size=(6, 3))
    sim = rf.Similarity(7.0, _random_rotation(rng), rng.normal(size=3))
    moved = rf.transform_poses(sim, c2w)
    for m in moved:
        check_rigid(m, "moved", tol=1e-9)
    assert np.allclose(moved[:, :3, 3], sim.apply(c2w[:, :3, 3]))
    assert np.allclose(moved[:, :3, :3], sim.rotation @ c2w[:, :3, :3])
    assert np.allclose(rf.transform_poses(sim.inverse(), moved), c2w)


def test_table_similarity_puts_the_plane_at_z0_and_the_centre_on_the_axis():
    rng = np.random.default_rng(6)
    normal = _random_rotation(rng)[:, 2]
    plane = rf.Plane(normal, 1.7)
    centre = 1.7 * normal + np.cross(normal, [1.0, 0, 0]) + 0.4 * normal  # 0.4 units above the plane
    sim = rf.table_similarity(plane, centre=centre, scale=0.25)
    table = _plane_points(rng, normal, 1.7, 50, noise=0.0)
    assert np.allclose(sim.apply(table)[:, 2], 0.0, atol=1e-12)
    assert np.allclose(sim.apply(centre), [0.0, 0.0, 0.1])
    assert np.allclose(sim.rotation @ normal, [0, 0, 1])


def test_frame_errors_of_a_pure_turn_about_z_are_zero():
    from real2sim.formats.rotations import rot_z

    errors = rf.frame_errors(rf.Similarity(1.0, rot_z(0.7), np.array([0.01, -0.02, 0.0])))
    assert errors["scale_rel_error"] == 0 and errors["table_tilt_deg"] < 1e-6
    assert errors["table_origin_height_mm"] == 0 and errors["yaw_deg"] == pytest.approx(np.degrees(0.7))
    assert errors["xy_shift_mm"] == pytest.approx([10.0, -20.0])


def test_projection_matches_the_reconstruction_stage_with_distortion():
    from real2sim.formats.dataset import CameraIntrinsics
    from real2sim.multiview.views import project

    rng = np.random.default_rng(7)
    k = CameraIntrinsics(160, 120, 150.0, 148.0, 81.0, 59.0, k1=-0.1, k2=0.02, p1=1e-3, p2=-2e-3)
    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, :3, 3] = [[0, 0, -1.0], [0.1, 0, -1.2], [0, -0.1, -0.9]]
    points = rng.uniform(-0.2, 0.2, (50, 3))
    uv, z = rf.project_points(k, c2w, points)
    uv_ref, z_ref = project(k, c2w, points)
    assert np.allclose(uv, uv_ref, atol=1e-3) and np.allclose(z, z_ref, atol=1e-5)


# ----------------------------------------------------------------------------- end to end


def run_cli(capsys, *args) -> tuple[int, str, str]:
    from real2sim.cli import main

    try:
        code = main(["run", *map(str, args)])
    except SystemExit as exc:  # argparse's own checks exit from the parser
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> dict[str, Path]:
    """The can in the robot frame (no ground truth: the comparison is asset to asset), and moved into a
    random similarity frame as a COLMAP model, with and without ground_truth/."""
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    root = tmp_path_factory.mktemp("robot_frame")
    capture(make_textured_object("can"), root / "can",
            CaptureConfig(views=60, width=120, height=90, pose_noise_mm=0, pose_noise_deg=0))
    shutil.copytree(root / "can", root / "robot", ignore=shutil.ignore_patterns("ground_truth"))
    sim = random_similarity(np.random.default_rng(5))
    make_colmap_capture(root / "can", root / "moved", sim, seed=5)
    make_colmap_capture(root / "can", root / "moved_no_truth", sim, seed=5, ground_truth=False)
    make_colmap_capture(root / "can", root / "few_points", sim, seed=5, max_points=12, ground_truth=False)
    make_nerfstudio_capture(root / "can", root / "nerfstudio", sim, seed=5)
    raised_dataset(root / "can", root / "raised", 0.25)
    return {"root": root, "truth": root / "can", "robot": root / "robot", "moved": root / "moved",
            "moved_no_truth": root / "moved_no_truth", "few_points": root / "few_points",
            "nerfstudio": root / "nerfstudio", "raised": root / "raised", "scale": sim.scale, "similarity": sim}


@pytest.fixture(scope="module")
def assets(captures, tmp_path_factory) -> dict[str, Path]:
    from real2sim.cli import main

    out = tmp_path_factory.mktemp("robot_frame_assets")
    runs = {"robot": [captures["robot"]],
            "height": [captures["moved"], "--object-height-m", CAN_HEIGHT_M],
            # the exact scale, and the masks stage on a COLMAP dataset (it writes a model-frame transforms.json)
            "scale": [captures["moved_no_truth"], "--scale", repr(1.0 / captures["scale"]), "--mask", "provided"],
            # ns-process-data's layout: transforms.json in COLMAP's frame turned by applied_transform
            "nerfstudio": [captures["nerfstudio"], "--object-height-m", CAN_HEIGHT_M],
            # a metric capture whose table top is not at z = 0 (a robot base below the table)
            "raised": [captures["raised"], "--table-z-m", "0.25"]}
    for name, (dataset, *extra) in runs.items():
        assert main(["run", str(dataset), "--out", str(out / name), *map(str, extra), *FAST]) == 0, name
    return {name: out / name for name in runs}


def _asset_summary(asset_dir: Path) -> dict:
    import trimesh

    props = json.loads((asset_dir / "physical_properties.json").read_text())
    mesh = trimesh.load(asset_dir / "visual" / "collision_reference.obj", force="mesh")
    assert mesh.is_watertight
    return {"mass": props["mass_kg"], "com": np.asarray(props["com_m"]),
            "eig": np.linalg.eigvalsh(np.asarray(props["inertia_kg_m2"])), "extents": np.sort(mesh.extents),
            "volume": mesh.volume}


@pytest.mark.parametrize("run", ["height", "scale", "nerfstudio", "raised"])
def test_moved_capture_gives_the_same_asset(assets, run):
    ref, got = _asset_summary(assets["robot"]), _asset_summary(assets[run])
    assert got["mass"] == ref["mass"] == 0.35
    assert np.linalg.norm(got["com"] - ref["com"]) < 1e-3
    assert np.all(np.abs(got["eig"] / ref["eig"] - 1) < 0.05), (got["eig"], ref["eig"])
    assert np.all(np.abs(got["extents"] / ref["extents"] - 1) < 0.02), (got["extents"], ref["extents"])
    assert abs(got["volume"] / ref["volume"] - 1) < 0.03
    stages = list(json.loads((assets[run] / ".run" / "run.json").read_text())["stages"])
    assert stages == {"scale": ["masks", "robot_frame", "reconstruct", "asset"],
                      "raised": ["reconstruct", "asset", "truth"]}.get(run, ["robot_frame", "reconstruct", "asset", "truth"])


@pytest.mark.parametrize("run", ["robot", "height", "raised"])
def test_asset_up_is_the_table_normal(assets, run):
    """`run` keeps the table's normal as the asset's +z (the object stands as it was captured, on the
    bottom closed at the table); PCA on a reconstructed can would tilt it by its reconstruction's error."""
    transform = np.asarray(json.loads((assets[run] / "canonical_transform.json").read_text())["T_asset_from_input"])
    np.testing.assert_allclose(transform[:3, :3] @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], atol=1e-9)
    config = json.loads((assets[run] / "asset_config.json").read_text())
    assert config["pca_up"] is False


def _yaw_xy_removed(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``est`` poses moved by the turn about z and x/y shift that best fit their camera centres onto ``ref``'s."""
    from real2sim.formats.rotations import rot_z

    a, b = est[:, :2, 3], ref[:, :2, 3]
    ac, bc = a - a.mean(axis=0), b - b.mean(axis=0)
    turn = rot_z(np.arctan2((ac[:, 0] * bc[:, 1] - ac[:, 1] * bc[:, 0]).sum(), (ac * bc).sum()))
    shift = np.r_[b.mean(axis=0) - turn[:2, :2] @ a.mean(axis=0), 0.0]
    return rf.transform_poses(rf.Similarity(1.0, turn, shift), est)


def test_normalised_poses_match_the_robot_poses_up_to_yaw_and_xy(assets, captures):
    from real2sim.formats.dataset import pose_errors, read_dataset

    truth = read_dataset(captures["robot"]).poses_c2w_gl()
    for run in ("height", "scale"):
        norm = read_dataset(assets[run] / ".run" / "robot_frame").poses_c2w_gl()
        rot_deg, centre_mm = pose_errors(_yaw_xy_removed(norm, truth), truth)
        assert rot_deg.max() < 0.05 and centre_mm.max() < 2.0, (run, rot_deg.max(), centre_mm.max())
    record = json.loads((assets["height"] / ".run" / "robot_frame" / "robot_frame.json").read_text())
    errors = record["errors_vs_ground_truth"]
    assert abs(errors["scale_rel_error"]) < 0.01 and errors["table_tilt_deg"] < 0.05
    assert abs(errors["table_origin_height_mm"]) < 0.5 and max(map(abs, errors["xy_shift_mm"])) < 1.0
    assert record["hull_height_m"] == pytest.approx(CAN_HEIGHT_M)
    assert record["robot_from_model"]["scale"] == pytest.approx(1 / captures["scale"], rel=0.01)
    # the can seen from a hemisphere that reaches its side: the sparse points reach the hull's top
    assert "reach its top" in record["object_top"]["from"], record["object_top"]
    by_scale = json.loads((assets["scale"] / ".run" / "robot_frame" / "robot_frame.json").read_text())
    assert "--scale given" in by_scale["object_top"]["from"]  # the height sets nothing: not measured, no warning


@pytest.mark.parametrize("run", ["height", "nerfstudio", "raised"])
def test_truth_of_a_moved_capture_is_aligned_by_the_known_similarity(assets, run):
    truth = json.loads((assets[run] / "truth.json").read_text())
    phys, rec = truth["physical_properties"], truth["reconstruction"]
    assert rec["chamfer_mm"] < 2.0 and rec["iou"] > 0.9  # the true can placed in the normalised frame
    assert phys["com_error_mm"] < 3.0 and phys["inertia_eigenvalue_max_rel_error"] < 0.1
    assert phys["inertia_tensor_rel_frobenius_error"] < 0.1  # same axes: the frames agree
    assert truth["camera_poses"]["before_refinement"]["rot_max_deg"] < 0.05
    if run != "raised":
        assert truth["robot_frame"]["errors_vs_ground_truth"]["table_tilt_deg"] < 0.05
    assert truth["masks_iou"]["mean"] == pytest.approx(1.0)


def test_second_run_of_a_colmap_capture_skips_every_stage(assets, captures, capsys):
    code, stdout, _ = run_cli(capsys, captures["moved"], "--out", assets["height"], "--object-height-m",
                              CAN_HEIGHT_M, *FAST)
    assert code == 0 and "none, all unchanged" in stdout


def _assert_refused(cases: dict, tmp_path: Path, capsys) -> None:
    """Each case ``label: (run arguments, words)`` exits 2 with one line holding ``words``, writing nothing."""
    for label, (args, words) in cases.items():
        out = tmp_path / label.replace(" ", "_")
        code, _, err = run_cli(capsys, *args, "--out", out, *FAST)
        assert code == 2, (label, err)
        assert len(err.strip().splitlines()) == 1 and words in err, (label, err)
        assert not out.exists(), label


def test_bad_colmap_inputs_exit_2_with_one_line(captures, tmp_path, capsys):
    moved, robot = captures["moved_no_truth"], captures["robot"]
    cases = {
        "no scale": ([moved], "--object-height-m H"),
        "both": ([moved, "--object-height-m", "0.1", "--scale", "0.2"], "exactly one"),
        "metric dataset": ([robot, "--scale", "0.2"], "COLMAP model dataset"),
        "zero height": ([moved, "--object-height-m", "0"], "--object-height-m: expected a number > 0"),
        "table z for colmap": ([moved, "--object-height-m", "0.1", "--table-z-m", "0.2"], "--table-z-m is for"),
    }
    _assert_refused(cases, tmp_path, capsys)
    code, _, err = run_cli(capsys, moved, "--out", tmp_path / "x", *FAST)
    assert "--scale" in err and "--object-height-m" in err


# about 36 s; the default suite's version is tests/multiview/test_dense_run.py (25 sparse points, the table from the
# dense points of a close-up capture)
@pytest.mark.slow
def test_too_few_sparse_points_take_the_table_from_dense_points(captures, tmp_path, capsys):
    """12 sparse points give no table plane; the dense points from the photos do (issue #68 part 2)."""
    code, _, err = run_cli(capsys, captures["few_points"], "--object-height-m", "0.1", "--out", tmp_path / "few",
                           *FAST)
    assert code == 0, err
    record = json.loads((tmp_path / "few" / ".run" / "robot_frame" / "robot_frame.json").read_text())
    assert record["table_plane_from"]["from"].startswith("the dense points")


def test_nerfstudio_capture_reads_its_point_cloud_or_else_its_colmap_model(captures, assets, tmp_path):
    """ns-process-data's sparse_pc.ply is in the transforms.json frame; without it, colmap/sparse/0 moved by
    applied_transform gives the same points. The normalised copy no longer claims a model frame."""
    from real2sim.formats.dataset import is_model_frame, read_dataset
    from real2sim.capture.phone.normalise import read_sparse_points

    with_cloud = read_dataset(captures["nerfstudio"])
    without = read_dataset(make_nerfstudio_capture(captures["truth"], tmp_path / "no_cloud", captures["similarity"],
                                                   seed=5, point_cloud=False))
    assert is_model_frame(with_cloud) and is_model_frame(without)
    (cloud, cloud_from), (model, model_from) = read_sparse_points(with_cloud), read_sparse_points(without)
    assert cloud_from == "sparse_pc.ply" and model_from.startswith("colmap/sparse/0")
    np.testing.assert_allclose(cloud, model, atol=1e-5 * np.abs(model).max())
    normalised = read_dataset(assets["nerfstudio"] / ".run" / "robot_frame")
    assert not is_model_frame(normalised) and "applied_transform" not in normalised.extra
    record = json.loads((assets["nerfstudio"] / ".run" / "robot_frame" / "robot_frame.json").read_text())
    assert record["sparse_points"]["from"] == "sparse_pc.ply"


def test_bad_nerfstudio_inputs_exit_2_with_one_line(captures, tmp_path, capsys):
    """Without a scale; a point cloud named outside the folder; no sparse points at all; and `reconstruct`,
    which needs a metric frame with the table at z = 0."""
    from real2sim.cli import main

    def edited(name: str, edit) -> Path:
        copy = tmp_path / name
        shutil.copytree(captures["nerfstudio"], copy, ignore=shutil.ignore_patterns("ground_truth"))
        data = json.loads((copy / "transforms.json").read_text())
        edit(copy, data)
        (copy / "transforms.json").write_text(json.dumps(data))
        return copy

    outside = edited("outside", lambda root, d: d.update(ply_file_path="../elsewhere.ply"))
    bare = edited("bare", lambda root, d: (shutil.rmtree(root / "colmap"), (root / "sparse_pc.ply").unlink()))
    cases = {"no scale": ([captures["nerfstudio"]], "nerfstudio-processed capture"),
             "cloud outside": ([outside, "--object-height-m", "0.1"], "outside the dataset folder"),
             "no points": ([bare, "--object-height-m", "0.1"], "no sparse points")}
    _assert_refused(cases, tmp_path, capsys)
    out = tmp_path / "mesh"
    assert main(["reconstruct", str(captures["nerfstudio"]), "--out", str(out), "--backend", "hull"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--object-height-m" in err and not out.exists(), err


def test_normalise_reports_progress(captures, tmp_path):
    from real2sim.capture.phone.normalise import NormaliseConfig, normalise
    from tests.progress_check import Recorder

    progress = Recorder()
    # a coarse hull (the stage's 128 voxels are what the fixture's runs check): the same steps, a third of the time
    config = NormaliseConfig(object_height_m=CAN_HEIGHT_M, hull_voxels=32)
    normalise(captures["moved"], tmp_path / "robot", config, progress=progress)
    assert progress.check(counted=False) == [("table plane, object height", 0, 0)]
