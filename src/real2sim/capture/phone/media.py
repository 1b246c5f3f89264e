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


class LensWarp:
    """Radial lens distortion (OpenCV's k1, k2) applied to a pinhole render.

    The pinhole image is rendered on a ``canvas`` (intrinsics of the same focal length, larger
    where barrel distortion (k1 < 0) reaches beyond the output's pinhole field) and resampled onto
    the output grid: each output pixel's centre, undistorted (fixed-point iteration), says where to
    sample. Without distortion the canvas is the output and nothing is resampled."""

    def __init__(self, cam, k1: float, k2: float):
        from dataclasses import replace

        self.identity = k1 == 0.0 and k2 == 0.0
        u, v = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
        xd, yd = (u - cam.cx) / cam.fl_x, (v - cam.cy) / cam.fl_y
        xu, yu = xd.copy(), yd.copy()
        for _ in range(30):  # x_d = x_u (1 + k1 r^2 + k2 r^4), r from the undistorted point
            r2 = xu * xu + yu * yu
            f = 1.0 + k1 * r2 + k2 * r2 * r2
            xu, yu = xd / f, yd / f
        pu, pv = cam.fl_x * xu + cam.cx, cam.fl_y * yu + cam.cy  # pinhole pixel coordinates (centres +0.5)
        x0, y0 = (int(np.floor(min(p.min(), 0.0))) - 2 for p in (pu, pv))
        x1 = int(np.ceil(max(pu.max(), cam.width))) + 2
        y1 = int(np.ceil(max(pv.max(), cam.height))) + 2
        if self.identity:
            x0, y0, x1, y1 = 0, 0, cam.width, cam.height
        self.canvas = replace(cam, width=x1 - x0, height=y1 - y0, cx=cam.cx - x0, cy=cam.cy - y0, k1=0.0, k2=0.0)
        # cv2.remap's coordinates put pixel centres at integers
        self.map_x = (pu - x0 - 0.5).astype(np.float32)
        self.map_y = (pv - y0 - 0.5).astype(np.float32)

    def apply(self, image: np.ndarray, nearest: bool = False) -> np.ndarray:
        """The canvas image (H, W[, C]) seen through the lens, on the output grid."""
        import cv2

        if self.identity:
            return image
        flags = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        return cv2.remap(image, self.map_x, self.map_y, flags, borderMode=cv2.BORDER_REPLICATE)
