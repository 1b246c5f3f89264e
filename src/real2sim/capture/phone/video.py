"""Frames from a phone video for structure from motion: decoded with PyAV (FFmpeg inside the wheel),
turned upright by the clip's rotation metadata, and chosen for sharpness and even spacing.

Selection (:func:`select_frames`): the clip's frames are split into ``count`` runs of equal length
along the clip, and from each run the sharpest frame is kept, sharpness being the variance of the
Laplacian of the grey image (a blurred frame has weak second derivatives). A person walks around
the object at a roughly steady pace, so even spacing in time is even spacing along the path, and
within each run the frame least smeared by motion wins.

Two passes over the file: the first scores every frame (keeping no images, so a long clip needs no
memory), the second keeps the chosen ones (in memory, or written to a folder as they come: 80 frames
of a 4K clip would hold 2 GB).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress

#: File name endings taken as a video by `run` (case-insensitive).
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".3gp")
DEFAULT_FRAMES = 80
#: Frames are scored at this longer side at most (sharpness ranks frames; full size costs time only).
SCORE_SIDE_PX = 480


@dataclass(frozen=True)
class VideoFrames:
    """``images``: the chosen frames, upright RGB uint8 (H, W, 3) (empty when they were written to ``paths``
instead); ``indices``: their frame numbers in
    the clip (0-based, decoding order); ``sharpness``: their variance of the Laplacian; ``total``:
    frames in the clip; ``rotation_deg``: the rotation applied (the clip's metadata, counter-clockwise)."""

    images: tuple[np.ndarray, ...]
    indices: tuple[int, ...]
    sharpness: tuple[float, ...]
    total: int
    rotation_deg: int
    fps: float
    paths: tuple[Path, ...] = ()

    def to_json(self) -> dict:
        return {"frames_in_clip": self.total, "chosen": list(self.indices),
                "sharpness": [round(s, 2) for s in self.sharpness], "rotation_deg": self.rotation_deg,
                "fps": self.fps}


def laplacian_variance(rgb: np.ndarray) -> float:
    """Variance of the 4-neighbour Laplacian of the grey image (0-255 units squared): higher is sharper."""
    grey = rgb[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    lap = (grey[1:-1, :-2] + grey[1:-1, 2:] + grey[:-2, 1:-1] + grey[2:, 1:-1] - 4.0 * grey[1:-1, 1:-1])
    return float(lap.var())


def select_frames(sharpness: np.ndarray, count: int) -> list[int]:
    """Indices of ``count`` frames (all when the clip has fewer): the sharpest of each of ``count`` equal
    runs of the clip, in order."""
    total = len(sharpness)
    if total <= count:
        return list(range(total))
    edges = np.linspace(0, total, count + 1).round().astype(int)
    return [int(a + np.argmax(sharpness[a:b])) for a, b in zip(edges[:-1], edges[1:])]


def _upright(rgb: np.ndarray, rotation_deg: int) -> np.ndarray:
    """The frame as it is shown: FFmpeg's display rotation is counter-clockwise degrees."""
    return np.ascontiguousarray(np.rot90(rgb, k=(rotation_deg // 90) % 4))


def _open(path: Path):
    import av

    try:
        container = av.open(str(path))
        if not container.streams.video:
            container.close()
            raise UserInputError(f"{path} holds no video stream")
        return container
    except UserInputError:
        raise
    except Exception as exc:  # noqa: BLE001 -- PyAV raises many kinds (InvalidDataError, OSError, ...)
        raise UserInputError(f"cannot decode video {path}: {_first_line(exc)}") from None


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _frames(path: Path):
    """(index, upright RGB, rotation) of every frame, decoding order; UserInputError on a decoding error."""
    container = _open(path)
    try:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        for index, frame in enumerate(container.decode(stream)):
            rotation = int(round(getattr(frame, "rotation", 0) or 0))
            yield index, _upright(frame.to_ndarray(format="rgb24"), rotation), rotation
    except UserInputError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise UserInputError(f"cannot decode video {path}: {_first_line(exc)}") from None
    finally:
        container.close()


def decode_frames(path: Path | str, count: int = DEFAULT_FRAMES, progress: ProgressFn | None = None,
                  folder: Path | None = None) -> VideoFrames:
    """The ``count`` frames of the video at ``path`` chosen as the module docstring says; with ``folder``
    written there as ``frame_<clip index>.png`` instead of kept. UserInputError (one line) for a file that
    does not decode or holds fewer than 2 frames."""
    from PIL import Image

    progress = progress or null_progress
    path = Path(path)
    if count < 1:
        raise UserInputError(f"--frames must be at least 1 (got {count})")
    container = _open(path)
    stream = container.streams.video[0]
    fps = float(stream.average_rate or stream.guessed_rate or 0.0)
    expected = int(stream.frames or 0)
    container.close()
    scores = []
    for index, rgb, _ in _frames(path):
        step = max(1, max(rgb.shape[:2]) // SCORE_SIDE_PX)
        scores.append(laplacian_variance(rgb[::step, ::step]))
        if index % 20 == 0:
            progress("video: scoring frames for sharpness", index + 1, max(expected, index + 1))
    if len(scores) < 2:
        raise UserInputError(f"video {path} has {len(scores)} decodable frame{'s' * (len(scores) != 1)}; "
                             "a walk around the object needs many")
    chosen = select_frames(np.asarray(scores), count)
    wanted, images, paths, rotation = set(chosen), [], [], 0
    if folder is not None:
        Path(folder).mkdir(parents=True, exist_ok=True)
    for index, rgb, rotation in _frames(path):
        if index in wanted:
            if folder is None:
                images.append(rgb)
            else:
                paths.append(Path(folder) / f"frame_{index:06d}.png")
                Image.fromarray(rgb).save(paths[-1])
            progress("video: decoding the chosen frames", len(images) + len(paths), len(chosen))
        if index >= chosen[-1]:
            break
    if len(images) + len(paths) != len(chosen):  # the file changed between the passes
        raise UserInputError(f"video {path} decoded differently on a second pass ({len(images) + len(paths)} of "
                             f"{len(chosen)} frames)")
    return VideoFrames(tuple(images), tuple(chosen), tuple(scores[i] for i in chosen), len(scores), rotation, fps,
                       tuple(paths))


def write_frames(frames: VideoFrames, folder: Path) -> list[Path]:
    """The chosen frames as ``folder/frame_<clip index>.png``; their paths in order."""
    from PIL import Image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for index, rgb in zip(frames.indices, frames.images):
        paths.append(folder / f"frame_{index:06d}.png")
        Image.fromarray(rgb).save(paths[-1])
    return paths
