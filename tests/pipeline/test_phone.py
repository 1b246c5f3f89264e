"""`run PHOTOS_DIR|VIDEO`: structure from motion and the board's world frame on a small simulated handheld
capture (the poses land on the true ones in metres, no alignment), and each bad input is one line, exit 2.
The whole run on a capture is the slow test at the end."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from real2sim.formats.dataset import CV_FROM_GL, read_dataset, read_ground_truth, rotation_angle_deg
from real2sim.plumbing.errors import UserInputError
from real2sim.pipeline.phone import (BOARD_RECORD, SFM_RECORD, PhoneConfig, _write_model, phone_input,
                                     run_board_frame, run_sfm)

VIEWS = 20


def run_cli(capsys, *args) -> tuple[int, str, str]:
    from real2sim.cli import main

    try:
        code = main(["run", *map(str, args)])
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def capture_cli(*args) -> None:
    from real2sim.cli import main

    assert main(["capture", *map(str, args)]) == 0


@pytest.fixture(scope="module")
def handheld(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("phone") / "photos"
    capture_cli("can", "--handheld", "--with-board", "--views", VIEWS, "--width-px", 320, "--height-px", 240, "--out", out)
    return out


@pytest.fixture(scope="module")
def sfm_dir(handheld, tmp_path_factory) -> Path:
    target = tmp_path_factory.mktemp("sfm") / "sfm"
    run_sfm(phone_input(handheld), target, PhoneConfig())
    return target


def test_sfm_stage_writes_a_colmap_dataset_with_its_truth(handheld, sfm_dir):
    import real2sim.capture.phone.board_focal as board_focal
    from real2sim.formats.colmap_model import read_colmap_model

    ds = read_colmap_model(sfm_dir)
    assert len(ds.frames) >= VIEWS - 2 and ds.intrinsics.k1 == 0.0
    record = json.loads((sfm_dir / SFM_RECORD).read_text())
    assert record["registered"] == len(ds.frames) and record["matching"] == "exhaustive"
    # the truth relates to the model by the camera centres: a few mm of SfM error at most
    assert record["ground_truth"]["camera_centre_rms_mm"] < 4.0
    assert (sfm_dir / "ground_truth" / "model_from_world.json").is_file()
    # the board measured the focal length and the model took it (SfM's own was 0.5 % long here; the
    # board's 0.07-0.24 % short over three runs)
    true_focal_px = json.loads((handheld / "ground_truth" / "transforms.json").read_text())["fl_x"]
    (focal,) = record["focal_from_board"]
    assert focal["board_views"] >= VIEWS // 2
    if "not_used" in focal:
        # On these 20 small views the two halves' estimates straddle the 0.5 % rule from one SfM run to
        # the next (SfM's distortion is the calibration's first guess): 0.62 % once in about ten CI runs.
        # Then the rule must be why, the halves near it, and the model must keep SfM's focal length.
        assert "disagree" in focal["not_used"]
        assert board_focal.MAX_SPLIT_DISAGREEMENT < focal["split_disagreement"] < 2 * board_focal.MAX_SPLIT_DISAGREEMENT
        assert record["cameras"][0]["params"][0] == focal["sfm_focal_px"] == ds.intrinsics.fl_x
        return
    assert focal["board_focal_px"] == pytest.approx(true_focal_px, rel=0.005)
    assert record["cameras"][0]["params"][0] == focal["board_focal_px"] == ds.intrinsics.fl_x


def test_a_board_in_too_few_views_leaves_sfms_focal_length_with_a_warning(handheld, tmp_path, monkeypatch):
    import real2sim.capture.phone.board_focal as board_focal

    monkeypatch.setattr(board_focal, "MIN_VIEWS", VIEWS + 1)  # the board in every view, and still too few
    with pytest.warns(RuntimeWarning, match="focal length stays SfM's"):
        record = run_sfm(phone_input(handheld), tmp_path / "sfm", PhoneConfig())
    (focal,) = record["focal_from_board"]
    assert focal["board_focal_px"] is None and f"fewer than {VIEWS + 1}" in focal["not_used"]
    assert record["cameras"][0]["params"][0] == focal["sfm_focal_px"]


def test_board_gives_metres_and_the_table(handheld, sfm_dir, tmp_path):
    target = tmp_path / "phone"
    record = run_board_frame(sfm_dir, target, PhoneConfig())
    assert record["found_in"] >= VIEWS // 2
    ds, truth = read_dataset(target), read_ground_truth(handheld)
    true_c2w = {Path(f.file_path).stem: f.transform_matrix for f in truth.frames}
    est = ds.poses_c2w_gl()
    ref = np.stack([true_c2w[Path(f.file_path).stem] for f in ds.frames])
    # the board's frame is the capture's world frame: the poses compare as they are, in metres
    centre_mm = 1000 * np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)
    assert np.median(centre_mm) < 4.0 and centre_mm.max() < 10.0, centre_mm
    assert rotation_angle_deg(est[:, :3, :3], ref[:, :3, :3]).max() < 1.0
    errors = record["errors_vs_ground_truth"]
    assert abs(errors["scale_rel_error"]) < 0.01 and errors["table_tilt_deg"] < 0.5  # -0.2 to -0.5 % measured
    assert abs(errors["table_origin_height_mm"]) < 2.0
    assert (target / "ground_truth" / "mesh.obj").is_file() and (target / BOARD_RECORD).is_file()


def _board_file(tmp_path: Path, *flags) -> Path:
    """The PNG `real2sim board` writes (its layout in the file's metadata)."""
    from real2sim.cli import main

    assert main(["board", "--out", str(tmp_path / "board.pdf"), *map(str, flags)]) == 0
    return tmp_path / "board.png"


def test_board_frame_uses_the_board_file_it_is_given(handheld, sfm_dir, tmp_path):
    """`run --board FILE`: the layout read from the file that `real2sim board` wrote is the one the
    board_frame stage looks for and measures with; the same layout with squares half the size would
    halve the scene."""
    from dataclasses import replace

    from real2sim.capture.phone.board import DEFAULT_BOARD, read_board_spec

    spec = read_board_spec(_board_file(tmp_path))
    assert spec == DEFAULT_BOARD
    record = run_board_frame(sfm_dir, tmp_path / "phone", PhoneConfig(board=spec))
    assert record["board"] == DEFAULT_BOARD.to_json() and abs(record["errors_vs_ground_truth"]["scale_rel_error"]) < 0.02
    small = replace(DEFAULT_BOARD, square_m=DEFAULT_BOARD.square_m / 2, marker_m=DEFAULT_BOARD.marker_m / 2)
    halved = run_board_frame(sfm_dir, tmp_path / "phone_small", PhoneConfig(board=small))
    assert abs(halved["errors_vs_ground_truth"]["scale_rel_error"] + 0.5) < 0.02, halved["errors_vs_ground_truth"]


def test_run_reads_a_custom_board_file_and_refuses_a_wrong_one(tmp_path, capsys):
    import argparse

    from PIL import Image

    from real2sim.capture.phone.board import BoardSpec
    from real2sim.cli.run import phone_config

    (tmp_path / "photos").mkdir()
    for i in range(9):
        Image.new("RGB", (64, 48), (128, 128, 128)).save(tmp_path / "photos" / f"IMG_{i:04d}.png")
    png = _board_file(tmp_path, "--squares", "9x6", "--board-square-mm", "20")
    args = argparse.Namespace(dataset=tmp_path / "photos", frames=None, board_square_mm=25.0, board=png, seed=0)
    config = phone_config(args)
    assert (config.board.squares_x, config.board.squares_y, config.board.square_m) == (9, 6, 0.02)
    from real2sim.pipeline.phone import board_spec

    assert isinstance(config.board, BoardSpec) and abs(board_spec(config).square_m - 0.025) < 1e-12
    Image.new("RGB", (64, 48)).save(tmp_path / "plain.png")
    code, out, err = run_cli(capsys, tmp_path / "photos", "--mass-kg", 0.3, "--out", tmp_path / "asset",
                             "--board", tmp_path / "plain.png")
    _one_line_exit_2(code, out, err, "not a board written by `real2sim board`", tmp_path / "asset")


def _without_board(handheld: Path, sfm_dir: Path, tmp_path: Path, keep: int) -> Path:
    """The sfm stage's dataset with the board painted out of all but ``keep`` images."""
    from PIL import Image

    copy = tmp_path / "sfm"
    shutil.copytree(sfm_dir, copy)
    for i, path in enumerate(sorted((copy / "images").glob("*.png"))):
        if i >= keep:
            Image.new("RGB", Image.open(path).size, (120, 110, 100)).save(path)
    return copy


@pytest.mark.parametrize("keep, message", [(0, "was not found in any of the"), (2, "at least 3 are needed")])
def test_board_missing_or_in_too_few_views_is_one_line(handheld, sfm_dir, tmp_path, keep, message):
    with pytest.raises(UserInputError, match=message) as info:
        run_board_frame(_without_board(handheld, sfm_dir, tmp_path, keep), tmp_path / "phone", PhoneConfig())
    assert "\n" not in str(info.value) and "--object-height-m" in str(info.value)
    assert not (tmp_path / "phone").exists()


def test_model_written_for_the_robot_frame_stage(tmp_path):
    """Without the board, the sfm stage's folder is a COLMAP dataset the robot_frame stage reads."""
    from real2sim.formats.colmap_model import read_colmap_model
    from real2sim.formats.dataset import CameraIntrinsics

    (tmp_path / "images").mkdir()
    from PIL import Image

    for name in ("a.png", "b.png"):
        Image.new("RGB", (40, 30)).save(tmp_path / "images" / name)
    c2w = np.stack([np.eye(4), np.eye(4)])
    c2w[1, :3, 3] = [0.5, 0.0, 0.0]
    _write_model(tmp_path, ("a.png", "b.png"), c2w, CameraIntrinsics(40, 30, 35.0, 35.0, 20.0, 15.0),
                 np.array([[0.0, 0.0, 2.0], [0.1, 0.0, 2.0]]))
    ds = read_colmap_model(tmp_path)
    assert [f.file_path for f in ds.frames] == ["images/a.png", "images/b.png"]
    assert np.allclose(ds.frames[1].transform_matrix @ CV_FROM_GL, c2w[1], atol=1e-9)
    from real2sim.capture.phone.normalise import _colmap_points

    assert len(_colmap_points(tmp_path / "sparse" / "0")) == 2


# ----------------------------------------------------------------------------- the command's bad inputs


def _one_line_exit_2(code: int, out: str, err: str, text: str, asset: Path) -> None:
    assert code == 2, (out, err)
    lines = [line for line in err.splitlines() if line.startswith("real2sim")]  # the rest: progress
    assert len(lines) == 1 and text in lines[0] and "error" in lines[0] and "Traceback" not in err, err
    assert not asset.exists()


def test_folder_with_no_images(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("no photos here")
    code, out, err = run_cli(capsys, tmp_path / "empty", "--mass-kg", 0.3, "--out", tmp_path / "asset")
    _one_line_exit_2(code, out, err, "holds no images", tmp_path / "asset")


def test_mixed_sizes(tmp_path, capsys):
    from PIL import Image

    (tmp_path / "photos").mkdir()
    for i in range(8):
        Image.new("RGB", (40 + 8 * i, 30 + 4 * i)).save(tmp_path / "photos" / f"p{i}.png")
    code, out, err = run_cli(capsys, tmp_path / "photos", "--mass-kg", 0.3, "--out", tmp_path / "asset")
    _one_line_exit_2(code, out, err, "do not form camera groups", tmp_path / "asset")


def test_undecodable_video(tmp_path, capsys):
    (tmp_path / "clip.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"garbage" * 50)
    code, out, err = run_cli(capsys, tmp_path / "clip.mp4", "--mass-kg", 0.3, "--out", tmp_path / "asset")
    _one_line_exit_2(code, out, err, "cannot decode video", tmp_path / "asset")


def test_too_few_registered(tmp_path, capsys):
    from PIL import Image

    (tmp_path / "photos").mkdir()
    for i in range(9):
        Image.new("RGB", (64, 48), (128, 128, 128)).save(tmp_path / "photos" / f"IMG_{i:04d}.png")
    code, out, err = run_cli(capsys, tmp_path / "photos", "--mass-kg", 0.3, "--out", tmp_path / "asset")
    _one_line_exit_2(code, out, err, "registered 0 of 9 images", tmp_path / "asset")


def test_phone_flags_refused_on_a_dataset(tmp_path, capsys):
    capture_cli("can", "--views", 4, "--width-px", 32, "--height-px", 24, "--out", tmp_path / "ds")
    code, out, err = run_cli(capsys, tmp_path / "ds", "--mass-kg", 0.3, "--out", tmp_path / "asset", "--frames", 20)
    _one_line_exit_2(code, out, err, "--frames is for photos or a video", tmp_path / "asset")
    code, out, err = run_cli(capsys, tmp_path / "ds", "--mass-kg", 0.3, "--out", tmp_path / "asset", "--board",
                             tmp_path / "board.png")
    _one_line_exit_2(code, out, err, "--board is for photos or a video", tmp_path / "asset")


# ----------------------------------------------------------------------------- end to end (slow)


def _stages_run(out: str) -> str:
    return next(line for line in out.splitlines() if line.startswith("asset:"))


@pytest.mark.slow
def test_run_photos_with_the_board(tmp_path, capsys):
    """About 3 minutes on 2 cores: 24 photos, the board, the visual hull; then a rerun skips every stage."""
    photos = tmp_path / "photos"
    capture_cli("can", "--handheld", "--with-board", "--views", 24, "--width-px", 320, "--height-px", 240, "--out", photos)
    args = (photos, "--mass-kg", 0.35, "--out", tmp_path / "asset", "--backend", "hull", "--collision", "boxes:8")
    code, out, err = run_cli(capsys, *args)
    assert code == 0, err
    assert "sfm" in _stages_run(out) and "board_frame" in _stages_run(out)
    truth = json.loads((tmp_path / "asset" / "truth.json").read_text())
    assert truth["reconstruction"]["chamfer_mm"] < 4.0
    code, out, err = run_cli(capsys, *args)
    assert code == 0 and "none, all unchanged" in _stages_run(out)


@pytest.mark.slow
def test_run_without_the_board_asks_for_the_height(tmp_path, capsys):
    """The board never found and no --object-height-m: one line, exit 2, the SfM kept for the next run."""
    photos = tmp_path / "photos"
    capture_cli("can", "--handheld", "--views", 24, "--width-px", 320, "--height-px", 240, "--out", photos)
    code, out, err = run_cli(capsys, photos, "--mass-kg", 0.35, "--out", tmp_path / "asset", "--backend", "hull")
    assert code == 2
    lines = [line for line in err.splitlines() if line.startswith("real2sim")]
    assert len(lines) == 1 and "was not found" in lines[0] and "--object-height-m" in lines[0], err
    assert (tmp_path / "asset" / ".run" / "sfm" / "sparse" / "0").is_dir()  # kept for the next run


@pytest.mark.slow
def test_run_by_height_then_by_the_board_reuses_the_sfm(tmp_path, capsys):
    """--object-height-m takes the COLMAP route (robot_frame: table plane from the sparse points, scale from
    the height); the same photos then without it take the board's frame, the SfM not redone."""
    photos = tmp_path / "photos"
    capture_cli("can", "--handheld", "--with-board", "--views", 24, "--width-px", 320, "--height-px", 240, "--out", photos)
    args = (photos, "--mass-kg", 0.35, "--out", tmp_path / "asset", "--backend", "hull", "--collision", "boxes:8")
    code, out, err = run_cli(capsys, *args, "--object-height-m", 0.10)
    assert code == 0, err
    assert "robot_frame" in _stages_run(out) and "board_frame" not in _stages_run(out)
    record = json.loads((tmp_path / "asset" / ".run" / "robot_frame" / "robot_frame.json").read_text())
    errors = record["errors_vs_ground_truth"]
    assert abs(errors["scale_rel_error"]) < 0.02 and errors["table_tilt_deg"] < 1.0, record
    code, out, err = run_cli(capsys, *args)
    assert code == 0, err
    assert "sfm" not in _stages_run(out) and "board_frame" in _stages_run(out)
    assert not (tmp_path / "asset" / ".run" / "robot_frame").exists()


@pytest.mark.slow
def test_run_video_with_the_board(tmp_path, capsys):
    clip_dir = tmp_path / "clip"
    capture_cli("can", "--handheld", "--with-board", "--video", "--views", 90, "--width-px", 320, "--height-px", 240,
                "--out", clip_dir)
    code, out, err = run_cli(capsys, clip_dir / "clip.mp4", "--frames", 24, "--mass-kg", 0.35, "--out", tmp_path / "asset",
                             "--backend", "hull", "--collision", "boxes:8")
    assert code == 0, err
    record = json.loads((tmp_path / "asset" / ".run" / "sfm" / SFM_RECORD).read_text())
    assert len(record["video"]["chosen"]) == 24 and record["registered"] >= 20
    assert "sequential" in record["matching"]
    masks = json.loads((tmp_path / "asset" / ".run" / "run.json").read_text())["stages"]["masks"]
    assert masks["settings"]["parallax"] == {"plate_object_threshold": 0.08}  # a clip's masks: the object's opinion


def test_a_phone_capture_masked_by_parallax_gets_the_objects_second_opinion():
    """The table plate's chance matches on a printed object, taken back by the object's second opinion; for
    photos step 6 then lets fewer views carve (the mug's photos 1.26 / 1.71 / 1.27 -> 0.93 / 1.25 / 1.16 mm,
    benchmarks/results/phone_remask.md), a clip keeps the usual share (the bottle's video 1.07
    mm, 2.11 with it): `run` sets both for a phone capture, and leaves a ParallaxConfig the caller gave, and
    robot captures, as they are."""
    from real2sim.asset.build import AssetConfig
    from real2sim.capture.masks.methods import MaskConfig
    from real2sim.formats.spec import parse_spec
    from real2sim.pipeline.run import RunConfig, phone_mask_config
    from real2sim.capture.masks.parallax_config import (PHONE_PHOTOS_PLATE_OUTLIER_FRACTION, PHONE_PLATE_OBJECT_THRESHOLD,
                                                      ParallaxConfig)

    asset = AssetConfig(mass_kg=0.35, specs=(parse_spec("boxes:8"),))
    config = RunConfig(asset=asset, mask_method="parallax", mask=MaskConfig())
    assert ParallaxConfig().plate_object_threshold == 0 and ParallaxConfig().plate_outlier_fraction is None
    video, photos = phone_mask_config(config, "video").mask, phone_mask_config(config, "photos").mask
    assert video.plate_object_threshold == photos.plate_object_threshold == PHONE_PLATE_OBJECT_THRESHOLD > 0
    assert video.plate_outlier_fraction is None
    assert photos.plate_outlier_fraction == PHONE_PHOTOS_PLATE_OUTLIER_FRACTION < ParallaxConfig().outlier_fraction
    given = RunConfig(asset=asset, mask_method="parallax", mask=ParallaxConfig(neighbours=6))
    assert phone_mask_config(given, "video") is given
    background = RunConfig(asset=asset, mask_method="background")
    assert phone_mask_config(background, "photos") is background
