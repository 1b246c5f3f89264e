"""What a simulated handheld phone capture (:mod:`real2sim.capture.sim.handheld`) is asked to do."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.capture.phone.board import BoardSpec
from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError


@dataclass(frozen=True)
class HandheldConfig:
    """A handheld phone capture: the phone's lens and pictures, the person's path around the object, and
    what a phone adds (roll, aim, blur, exposure drift, JPEG)."""

    views: int = 60
    """Photos, or video frames (``video``: the clip lasts ``views / fps`` seconds) (>= 1)."""
    width: int = 640
    """Picture width as displayed, pixels (16-8192; even for a video)."""
    height: int = 480
    """Picture height as displayed, pixels (16-8192; even for a video)."""
    fov_deg: float = 65.0
    """Horizontal field of view, degrees (20-120; square pixels, centred principal point)."""
    seed: int = 0
    """Seed of the path, the blur streaks and the exposure drift."""
    board: BoardSpec | None = None
    """The printed board, lying flat on the table under the object with its frame the world frame; None: no
    board."""
    video: bool = False
    """A video (``clip.mp4``, H.264) instead of photos."""
    fps: float = 30.0
    """Video frames per second (1-240)."""
    jpeg_quality: int = 90
    """JPEG quality of the photos, and the video's quality on the same scale (1-100)."""
    elevation_deg: tuple[float, float] = (20.0, 72.0)
    """The range (degrees) the orbit's height swings through, twice up and down in one loop, seen from the
    object's middle."""
    distance_factors: tuple[float, float] = (0.85, 1.3)
    """The range of the camera's distance, as multiples of the distance at which the object (with the board:
    at least most of the board) fills ``fill_fraction`` of the view's height."""
    fill_fraction: float = 0.7
    """Share (0-1) of the view's height the object fills at distance factor 1."""
    close_fraction: float = 0.12
    """Share (0-1) of the photos taken close, at ``close_factor`` (photos only), spread evenly along the walk;
    0.7 is how people photograph an object they care about (issue #68)."""
    close_factor: float = 0.55
    """Distance factor of the close photos (0.2-1): the camera stands at this multiple of the distance at
    which the object's bounding sphere fills ``fill_fraction`` of the view's height, so at 0.55 that sphere
    spans 1.3 view heights and the image border cuts the object, unless it is much smaller than its sphere
    from where the view stands (a tall object seen from above): see ``close_cut``."""
    close_cut: bool = False
    """Each close view then steps nearer by 15 % at a time until the image border cuts the object's true
    mesh, no nearer than 1.3 bounding radii from its middle; False keeps the fixed ``close_factor`` distance
    of the captures recorded before (golden outputs, the phone figures), where 1-2 of 7 close views of 60
    leave the object whole."""
    roll_deg: float = 4.0
    """RMS roll of the camera about its optical axis, degrees."""
    aim_jitter: float = 0.12
    """RMS aim off the object's middle, as a fraction of the object's radius."""
    motion_blur_px: float = 1.5
    """RMS blur streak length, pixels at 640 wide (photos: hand shake in a random direction; video: along the
    image motion over half a frame interval)."""
    exposure_jitter_stops: float = 0.1
    """RMS auto-exposure change, stops."""
    supersample: int = 2
    """Colour rendered at this many times the size and averaged down (anti-aliasing, as a lens and sensor
    do) (>= 1)."""
    video_rotation_deg: int = 0
    """0, 90, 180 or 270 (video only): the frames are stored turned and the stream's display matrix turns them
    back by this much, counter-clockwise, as a phone held upright records (270: portrait); ``width`` x
    ``height`` and ground_truth/ are the picture as displayed."""
    distortion_k1: float = 0.0
    """The lens's radial distortion k1 (OpenCV's; -0.5 to 0.5, below 0 barrel), stated in ground_truth/'s
    intrinsics; 0 because phones mostly correct their lens's distortion."""
    distortion_k2: float = 0.0
    """The lens's radial distortion k2 (OpenCV's; -0.5 to 0.5), as ``distortion_k1``."""
    table_size_m: float = 2.4
    """Side of the square textured table, metres."""
    table_texture_px: int = 2048
    """Side of the table's square procedural texture, px (256-16384). At 2048 its finest noise is 2 cm across,
    a blur to a close-up at phone resolution (a few SIFT features where a wooden table has grain); above
    2048 the texture gains mm-scale grain (4096: 0.6 mm a texel on the 2.4 m table).
    (why: docs/design-notes/capture.md#sfm-keeps-what-colmap-finds)"""
    texture_seed: int = 7
    """Seed of the table's procedural texture (and, plus 1, of the object's when it has none)."""
    room: bool = False
    """A room behind the table: walls, a floor, shelves with boxes and things on the table 0.55-1.05 m from
    the object, textured, laid out from ``texture_seed`` (:mod:`real2sim.capture.sim.room`); False: a plain
    grey backdrop."""
    auto_exposure: bool = False
    """Each photo's exposure follows the scene's brightness as a phone's does: the centre-weighted mean
    luminance (linear light) is brought to middle grey (0.18), within +-2 stops; ``exposure_jitter_stops``
    comes on top."""
    markers: int = 0
    """Printed square fiducials lying flat on the table on a ring around the object (0-16), each on white
    paper with a one-cell quiet zone; their true corners go to ``ground_truth/markers.json``."""
    marker_mm: float = 40.0
    """Side of each printed marker's black square, mm (5-300)."""
    marker_dictionary: str = "DICT_4X4_50"
    """The markers' dictionary, an OpenCV aruco name (DICT_4X4_50, DICT_5X5_100, DICT_APRILTAG_36h11, ...);
    the markers are its ids 0..markers-1."""

    def camera(self) -> CameraIntrinsics:
        fl = 0.5 * self.width / np.tan(np.radians(self.fov_deg) / 2)
        return CameraIntrinsics(width=self.width, height=self.height, fl_x=float(fl), fl_y=float(fl),
                                cx=self.width / 2.0, cy=self.height / 2.0, k1=float(self.distortion_k1),
                                k2=float(self.distortion_k2))

    def validate(self) -> None:
        if int(self.views) < 1:
            raise UserInputError(f"--views must be at least 1 (got {self.views})")
        if not (16 <= self.width <= 8192 and 16 <= self.height <= 8192):
            raise UserInputError(f"image size {self.width}x{self.height} out of range (16..8192 px)")
        if self.video and (self.width % 2 or self.height % 2):
            raise UserInputError(f"--video needs an even --width-px and --height-px (H.264), got {self.width}x{self.height}")
        if not (np.isfinite(self.fov_deg) and 20.0 <= self.fov_deg <= 120.0):
            raise UserInputError(f"--fov-deg must be in 20..120 for a handheld capture (got {self.fov_deg})")
        if not (np.isfinite(self.fps) and 1.0 <= self.fps <= 240.0):
            raise UserInputError(f"--fps must be in 1..240 (got {self.fps})")
        for name in ("distortion_k1", "distortion_k2"):
            if not (np.isfinite(getattr(self, name)) and abs(getattr(self, name)) <= 0.5):
                raise UserInputError(f"--{name.replace('_', '-')} must be in -0.5..0.5 (got {getattr(self, name)})")
        if self.video_rotation_deg not in (0, 90, 180, 270):
            raise UserInputError(f"--video-rotation-deg must be 0, 90, 180 or 270 (got {self.video_rotation_deg})")
        if self.video_rotation_deg and not self.video:
            raise UserInputError("--video-rotation-deg needs --video")
        if not 1 <= int(self.jpeg_quality) <= 100:
            raise UserInputError(f"--jpeg-quality must be in 1..100 (got {self.jpeg_quality})")
        if not (np.isfinite(self.close_fraction) and 0.0 <= self.close_fraction <= 1.0):
            raise UserInputError(f"--close-fraction must be in 0..1 (got {self.close_fraction})")
        if not (np.isfinite(self.close_factor) and 0.2 <= self.close_factor <= 1.0):
            raise UserInputError(f"--close-factor must be in 0.2..1 (got {self.close_factor})")
        if not 256 <= int(self.table_texture_px) <= 16384:
            raise UserInputError(f"--table-texture-px must be in 256..16384 (got {self.table_texture_px})")
        if not 0 <= int(self.markers) <= 16:
            raise UserInputError(f"--markers must be in 0..16 (got {self.markers})")
        if not (np.isfinite(self.marker_mm) and 5.0 <= self.marker_mm <= 300.0):
            raise UserInputError(f"--marker-mm must be in 5..300 (got {self.marker_mm})")
        if self.markers:
            from real2sim.capture.phone.markers import aruco_dictionary

            if self.video:
                raise UserInputError("--markers is for photos (a video's frames have no truth files to hold them)")
            if self.board is not None:
                raise UserInputError("--markers and --with-board do not go together: the markers are the scale "
                                     "for captures without our board")
            count = aruco_dictionary(self.marker_dictionary).bytesList.shape[0]
            if self.markers > count:
                raise UserInputError(f"--markers {self.markers}: {self.marker_dictionary} has only {count} ids")
        if self.board is not None:
            self.board.validate()
