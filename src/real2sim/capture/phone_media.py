"""What a phone writes: JPEG photos with EXIF, H.264 video with rotation metadata (PyAV), and the
motion blur of a moving camera. Plain functions of arrays, used by :mod:`.handheld`."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def motion_blur(image: np.ndarray, streak_px: np.ndarray) -> np.ndarray:
    """``image`` (H, W, C float) averaged along the straight streak ``streak_px`` (dx, dy), centred
    on each pixel: the camera moving at constant speed while the shutter is open."""
    import cv2

    length = float(np.hypot(*streak_px))
    if length < 0.25:
        return image
    steps = int(np.ceil(length)) + 1
    out = np.zeros_like(image)
    for f in np.linspace(-0.5, 0.5, steps):
        shift = np.array([[1.0, 0.0, f * streak_px[0]], [0.0, 1.0, f * streak_px[1]]])
        out += cv2.warpAffine(image, shift, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REFLECT).reshape(image.shape)  # OpenCV drops a lone channel
    return out / steps


def photo_name(i: int) -> str:
    return f"IMG_{i + 1:04d}.jpg"


def phone_exif(fov_deg: float):
    """EXIF a phone writes and SfM tools read: make, model and the 35 mm-equivalent focal length."""
    from PIL import ExifTags, Image

    exif = Image.Exif()
    exif[ExifTags.Base.Make] = "real2sim"
    exif[ExifTags.Base.Model] = "simulated phone"
    exif.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.FocalLengthIn35mmFilm] = int(round(18.0 / np.tan(np.radians(fov_deg) / 2)))
    return exif


class VideoWriter:
    """H.264 MP4 through PyAV (FFmpeg inside its wheel), yuv420p as phones write. ``width`` x
    ``height``: the picture as displayed; ``rotation_deg`` (0, 90, 180, 270): frames are stored
    turned, with the display matrix that turns them back counter-clockwise by that much.
    ``quality`` 1-100 as JPEG's (mapped to x264's crf 33..18)."""

    def __init__(self, path: Path, width: int, height: int, fps: float, quality: int = 90, rotation_deg: int = 0):
        import av
        from fractions import Fraction

        self.container = av.open(str(path), mode="w")
        self.stream = self.container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        self.turns = rotation_deg // 90  # counter-clockwise quarter turns that display a stored frame
        w, h = (height, width) if self.turns % 2 else (width, height)
        self.stream.width, self.stream.height, self.stream.pix_fmt = w, h, "yuv420p"
        if self.turns:
            self.stream.set_display_rotation(rotation_deg if rotation_deg <= 180 else -90)
        # quality from the JPEG setting: crf 18 (q 100) .. 33 (q 1); keyframes every second
        self.stream.options = {"crf": str(int(round(33 - 15 * quality / 100))), "g": str(int(fps))}

    def write(self, rgb: np.ndarray) -> None:
        import av

        stored = np.rot90(rgb, k=-self.turns)  # turned back by the player
        for packet in self.stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(stored), format="rgb24")):
            self.container.mux(packet)

    def close(self) -> None:
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()
