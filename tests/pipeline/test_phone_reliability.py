"""Reliability of `run` on phone photos and its warnings (issue #69): a warning raised while a stage builds its
output under a temporary name names the output; a --board that is not the board in the photos stops at the
board_frame stage naming the file; a truncated photo is a one-line error before any work. Real captures: a
small handheld one with the board, shared by the module, and a tiny robot capture with its empty table."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from tests.cli_helpers import run_cli

VIEWS = 20
HULL = ["--backend", "hull", "--voxels", "48", "--max-faces", "2000", "--texture-px", "64", "--collision", "mesh"]


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    from real2sim.cli import main

    out = tmp_path_factory.mktemp("phone") / "photos"
    assert main(["capture", "can", "--handheld", "--with-board", "--views", str(VIEWS), "--width-px", "320", "--height-px", "240",
                 "--out", str(out)]) == 0
    return out


def _error_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("real2sim")]  # the rest: progress


# ----------------------------------------------------------------------------- 1. warnings name the outputs


def test_final_names_maps_only_the_stages_own_temporaries():
    from real2sim.pipeline.manifest import final_names

    rename = final_names([".run/masked", ".run/reconstruct/mesh.obj"])
    assert rename("masks of /a/.run/.masked.tmp-8hv_gq_o: 1 of 8 (first: .masked.tmp-8hv_gq_o/images/x.png)") == \
        "masks of /a/.run/masked: 1 of 8 (first: masked/images/x.png)"
    assert rename("'/a/.run/reconstruct/.mesh.obj.tmp-abcdefgh.obj' failed") == "'/a/.run/reconstruct/mesh.obj' failed"
    # another stage's temporary, or a name that only ends like one, stays as it is
    assert rename("/a/.run/.dataset.tmp-abcdefgh and /a/my.masked.tmp-abcdefgh") == \
        "/a/.run/.dataset.tmp-abcdefgh and /a/my.masked.tmp-abcdefgh"


@pytest.fixture(scope="module")
def background_capture(tmp_path_factory) -> Path:
    """8 views at 64x48 with the empty table; one view's background is another colour everywhere, so its
    background mask covers the whole image: the masks stage warns while it works in its temporary copy."""
    from PIL import Image

    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    out = tmp_path_factory.mktemp("background") / "can"
    capture(make_textured_object("can"), out, CaptureConfig(views=8, width=64, height=48, with_background=True))
    path = out / "background" / "frame_00003.png"
    with Image.open(path) as image:
        size, mode = image.size, image.mode
    Image.new(mode, size, (255, 0, 255) if mode == "RGB" else 255).save(path)
    return out


def test_a_mask_stage_warning_names_the_masked_folder_not_its_temporary(background_capture, tmp_path, capsys):
    asset = tmp_path / "asset"
    args = ("run", background_capture, "--out", asset, "--mask", "background", "--no-refine-poses", "--mass-kg", 0.3,
            *HULL)
    code, out, err = run_cli(capsys, *args)
    assert code == 0, err
    shown = [line for line in err.splitlines() if line.startswith("WARNING: the background masks of")]
    assert len(shown) == 1 and f"{asset.resolve()}/.run/masked:" in shown[0], err
    summary = [line for line in out.splitlines() if line.startswith("WARNING: ")]
    assert f"{shown[0]} (stage masks)" in summary, out
    record = json.loads((asset / ".run" / "run.json").read_text())
    stored = [w for stage in record["stages"].values() for w in stage.get("warnings", [])]
    assert f"WARNING: {record['stages']['masks']['warnings'][0]}" == shown[0]
    truth = json.loads((asset / "truth.json").read_text())
    for text in [*err.splitlines(), *out.splitlines(), *stored, *(w["message"] for w in truth["warnings"])]:
        assert ".tmp-" not in text, text
    # skipped as unchanged, the summary repeats what run.json kept
    code, out, err = run_cli(capsys, *args)
    assert code == 0 and "none, all unchanged" in out and ".tmp-" not in out + err
    assert f"{shown[0]} (stage masks)" in out.splitlines()


# ----------------------------------------------------------------------------- 2. a --board not in the photos


def test_a_board_file_that_is_not_the_board_in_the_photos_stops_at_the_board_frame_stage(photos, tmp_path, capsys):
    """The photos show the default 7x5 board of 32 mm squares; the file is a 9x6 board of 20 mm squares."""
    from real2sim.capture.phone.board_frame import MIN_BOARD_VIEWS

    code, _, err = run_cli(capsys, "board", "--out", tmp_path / "b.pdf", "--squares", "9x6", "--board-square-mm", 20)
    assert code == 0, err
    board = tmp_path / "b.png"
    asset = tmp_path / "asset"
    code, out, err = run_cli(capsys, "run", photos, "--mass-kg", 0.4, "--out", asset, "--backend", "hull",
                             "--board", board)
    assert code == 2, (out, err)
    lines = _error_lines(err)
    assert len(lines) == 1 and "Traceback" not in err, err
    line = lines[0]
    assert "error: stage board_frame:" in line and f"9x6, 20 mm squares, from {board}" in line, line
    assert re.search(r"(was not found in any|was found in only \d+) of the \d+ registered views", line), line
    assert f"at least {MIN_BOARD_VIEWS} are needed" in line and "--board" in line, line
    assert (asset / ".run" / "sfm" / "sparse" / "0").is_dir() and not (asset / ".run" / "phone").exists()


# ----------------------------------------------------------------------------- 3. a truncated photo


def test_a_truncated_photo_is_one_line_before_any_work(photos, tmp_path, capsys):
    copy = tmp_path / "photos"
    shutil.copytree(photos, copy)
    cut = copy / "IMG_0005.jpg"
    data = cut.read_bytes()
    cut.write_bytes(data[:len(data) // 2])  # the first half of a valid JPEG: its header still reads
    asset = tmp_path / "asset"
    code, out, err = run_cli(capsys, "run", copy, "--mass-kg", 0.4, "--out", asset, "--backend", "hull")
    assert code == 2, (out, err)
    lines = _error_lines(err)
    assert len(lines) == 1 and "Traceback" not in err and "internal error" not in err, err
    assert f"cannot read image {cut}" in lines[0] and "truncated" in lines[0], lines[0]
    assert "features" not in err and not asset.exists()  # before structure from motion's first step
