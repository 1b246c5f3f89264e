"""Video frames for structure from motion: a clip written with PyAV here is decoded, its sharpest frame
of each stretch kept, its rotation metadata honoured; a file that is not a video is one line, exit 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from real2sim.capture.phone.video import decode_frames, laplacian_variance, select_frames, write_frames
from real2sim.plumbing.errors import UserInputError

W, H, FRAMES = 96, 64, 30
BLURRED = {i for i in range(FRAMES) if i % 3 != 1}  # the middle frame of each run of 3 is the sharp one


def _frame(i: int) -> np.ndarray:
    """A checkerboard moving right by 2 px a frame, a white block in the top-left corner; blurred frames
    are box-filtered."""
    from scipy import ndimage

    y, x = np.mgrid[0:H, 0:W]
    img = (((x + 2 * i) // 8 + y // 8) % 2 * 200 + 25).astype(np.float32)
    if i in BLURRED:
        img = ndimage.uniform_filter(img, size=7)
    img[:12, :12] = 255.0
    return np.repeat(img[..., None], 3, axis=2).astype(np.uint8)


def write_clip(path: Path, rotation_deg: int = 0) -> None:
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
        stream.options = {"crf": "12"}
        if rotation_deg:
            stream.set_display_rotation(rotation_deg)
        for i in range(FRAMES):
            container.mux(stream.encode(av.VideoFrame.from_ndarray(_frame(i), format="rgb24")))
        container.mux(stream.encode())


def test_select_frames_takes_the_sharpest_of_each_stretch():
    sharp = np.array([1, 5, 2, 9, 1, 1, 3, 3, 8, 0], float)
    assert select_frames(sharp, 5) == [1, 3, 4, 6, 8]  # one per pair of frames, the sharper of each
    assert select_frames(sharp, 20) == list(range(10))


def test_laplacian_variance_ranks_blur_lower():
    assert laplacian_variance(_frame(1)) > 3 * laplacian_variance(_frame(0))


def test_decoded_frames_are_sharp_and_evenly_spread(tmp_path):
    clip = tmp_path / "clip.mp4"
    write_clip(clip)
    frames = decode_frames(clip, 10)
    assert frames.total == FRAMES
    assert list(frames.indices) == [3 * k + 1 for k in range(10)]  # the sharp one of each run of 3
    assert frames.images[0].shape == (H, W, 3)
    # the decoded picture is the written one (H.264 at high quality)
    assert np.abs(frames.images[0].astype(float) - _frame(1)).mean() < 6
    paths = write_frames(frames, tmp_path / "frames")
    assert [p.name for p in paths][:2] == ["frame_000001.png", "frame_000004.png"] and all(p.is_file() for p in paths)


def test_rotation_metadata_is_honoured(tmp_path):
    """FFmpeg's display rotation (``ffmpeg -display_rotation``): degrees to turn the stored picture
    counter-clockwise before it is shown; a phone's portrait clip stores -90 (turn clockwise)."""
    clip = tmp_path / "portrait.mp4"
    write_clip(clip, rotation_deg=90)
    frames = decode_frames(clip, 3)
    assert frames.rotation_deg == 90
    image = frames.images[0].astype(float)
    assert image.shape == (W, H, 3)  # shown upright: the stored landscape frame turned a quarter
    assert image[-10:, :10].mean() > 250  # the stored top-left white block, turned counter-clockwise
    assert image[:10, :10].mean() < 200 and image[:10, -10:].mean() < 200
    assert np.abs(image - np.rot90(_frame(frames.indices[0]), k=1)).mean() < 6


@pytest.mark.parametrize("content", [b"", b"not a video at all" * 100])
def test_undecodable_video_is_one_line(tmp_path, content):
    clip = tmp_path / "broken.mp4"
    clip.write_bytes(content)
    with pytest.raises(UserInputError) as info:
        decode_frames(clip, 10)
    assert "broken.mp4" in str(info.value) and "\n" not in str(info.value)


def test_frames_written_to_a_folder_are_not_kept(tmp_path):
    clip = tmp_path / "clip.mp4"
    write_clip(clip)
    frames = decode_frames(clip, 5, folder=tmp_path / "frames")
    assert frames.images == () and [p.name for p in frames.paths] == [f"frame_{i:06d}.png" for i in frames.indices]
    from real2sim.formats.dataset import load_image_rgb

    assert np.abs(load_image_rgb(frames.paths[0]).astype(float) - _frame(frames.indices[0])).mean() < 6
