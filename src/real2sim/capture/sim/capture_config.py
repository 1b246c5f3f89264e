"""What a simulated wrist-camera capture (:mod:`real2sim.capture.sim.wrist_camera`) is asked to do, and what
it reports; below the capture and the helpers that write its files.

World frame as in ``wrist_camera``: metres, z up, the table top (or, without a table, the object's lowest
point) at z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from real2sim.formats.dataset import CameraIntrinsics, realsense_d435_intrinsics
from real2sim.plumbing.errors import UserInputError


@dataclass(frozen=True)
class ReachabilityModel:
    """Which camera positions a wrist camera on a table-side arm (Franka-like) can reach: within a distance
    range of the arm's shoulder and an elevation range seen from the object's look-at point. Orientation is
    not limited: the wrist is assumed to point the camera at the object from anywhere it can reach."""

    base_xy_m: tuple[float, float] = (-0.55, 0.0)
    """The arm's base on the table, world (x, y), metres."""
    shoulder_height_m: float = 0.33
    """The arm's shoulder above its base (the table top), metres."""
    r_min_m: float = 0.25
    """Nearest a camera may be to the shoulder, metres."""
    r_max_m: float = 0.85
    """Farthest a camera may be from the shoulder, metres (>= ``r_min_m``)."""
    min_elevation_deg: float = 8.0
    """Lowest camera elevation seen from the look-at point, degrees."""
    max_elevation_deg: float = 88.0
    """Highest camera elevation seen from the look-at point, degrees (at most 90)."""

    def reachable(self, positions_m: np.ndarray, target_m: np.ndarray) -> np.ndarray:
        """(N,) bool for (N, 3) camera positions in the world frame."""
        shoulder = np.array([self.base_xy_m[0], self.base_xy_m[1], self.shoulder_height_m])
        r = np.linalg.norm(positions_m - shoulder, axis=1)
        rel = positions_m - target_m
        elev = np.degrees(np.arctan2(rel[:, 2], np.linalg.norm(rel[:, :2], axis=1)))
        return ((r >= self.r_min_m) & (r <= self.r_max_m)
                & (elev >= self.min_elevation_deg) & (elev <= self.max_elevation_deg)
                & (positions_m[:, 2] > 0.0))


@dataclass(frozen=True)
class CaptureConfig:
    """How to capture: the camera, its path around the object, the reported poses' noise, and the hard-rig
    options (turntable ring, another lens, cut-off views, no table, exposure jitter, JPEG), all off by default."""

    views: int = 200
    """Camera views (>= 1)."""
    width: int = 640
    """Image width, pixels (16-8192)."""
    height: int = 480
    """Image height, pixels (16-8192)."""
    intrinsics: CameraIntrinsics | None = None
    """The camera, scaled to ``width`` x ``height`` when its size differs; None: a RealSense D435-like colour
    camera (fx = fy = 615 px at 640x480, scaled with the size), principal point at the image centre."""
    pose_noise_mm: float = 5.0
    """RMS position error of the reported poses (transforms.json) against the exact ones, mm (>= 0)."""
    pose_noise_deg: float = 1.0
    """RMS rotation error of the reported poses, degrees (>= 0)."""
    seed: int = 0
    """Seed of the pose noise, the cut-off views and the colour gains."""
    with_background: bool = False
    """Also render the empty table from every pose (``background/``)."""
    elevations_deg: tuple[float, ...] = (12.0, 25.0, 38.0, 51.0, 64.0, 76.0, 86.0)
    """The rings of the arm's camera path: elevations seen from the look-at point, degrees."""
    distance_factors: tuple[float, ...] = (1.0, 1.35)
    """Camera distances, as multiples of the distance at which the object's bounding sphere fills
    ``fill_fraction`` of the vertical field of view."""
    fill_fraction: float = 0.75
    """Share (0-1) of the vertical field of view the object's bounding sphere fills at distance factor 1."""
    reach: ReachabilityModel = field(default_factory=ReachabilityModel)
    """Where the arm can put the camera; views are picked among the reachable positions."""
    table_size_m: float = 1.6
    """Side of the square textured table, metres."""
    texture_seed: int = 7
    """Seed of the table's procedural texture (and, plus 1, of the object's when it has none)."""
    ring_elevation_deg: float | None = None
    """A turntable ring instead of the arm's path: ``views`` cameras evenly around one horizontal ring at this
    elevation (degrees, -85 to 85) seen from the object's middle, 0 level with it; None: off."""
    focal_px: float | None = None
    """A lens other than the D435's: focal length in pixels of the written images (1 to 1e5; square pixels,
    centred principal point); the cameras stand back until the object fills ``fill_fraction`` of the view, on
    a tripod (the arm's distance limits lifted, its elevation limits kept). None: off; not with ``fov_deg``."""
    fov_deg: float | None = None
    """A lens given by its horizontal field of view, degrees (1-170), otherwise as ``focal_px``; None: off."""
    cut_off_fraction: float = 0.0
    """Share (0-1) of the views turned so that the image border cuts the object."""
    no_table: bool = False
    """The object on a thin post against a dark background instead of the table; its lowest point stays at
    z = 0."""
    exposure_jitter_stops: float = 0.0
    """RMS per-view exposure change, stops (0-3)."""
    white_balance_jitter: float = 0.0
    """RMS per-view relative gain of red and blue against green (0-1)."""
    jpeg_quality: int | None = None
    """Images written as ``images/*.jpg`` at this JPEG quality (1-100; masks stay PNG); None: PNG."""

    def camera(self) -> CameraIntrinsics:
        if self.focal_px is not None or self.fov_deg is not None:
            fl = self.focal_px if self.focal_px is not None else 0.5 * self.width / np.tan(np.radians(self.fov_deg) / 2)
            return CameraIntrinsics(width=self.width, height=self.height, fl_x=float(fl), fl_y=float(fl),
                                    cx=self.width / 2.0, cy=self.height / 2.0)
        if self.intrinsics is not None:
            if (self.intrinsics.width, self.intrinsics.height) != (self.width, self.height):
                return self.intrinsics.scaled(self.width, self.height)
            return self.intrinsics
        return realsense_d435_intrinsics(self.width, self.height)

    def validate(self) -> None:
        if int(self.views) < 1:
            raise UserInputError(f"--views must be at least 1 (got {self.views})")
        if self.width < 16 or self.height < 16 or self.width > 8192 or self.height > 8192:
            raise UserInputError(f"image size {self.width}x{self.height} out of range (16..8192 px)")
        for name in ("pose_noise_mm", "pose_noise_deg"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise UserInputError(f"--{name.replace('_', '-')} must be >= 0 (got {v})")
        _validate_hard_rig(self)


def _validate_hard_rig(c: CaptureConfig) -> None:
    """UserInputError (naming the flag) for hard-rig settings out of range; the CLI's types say the same."""
    checks = [("--ring-elevation-deg", c.ring_elevation_deg, -85.0, 85.0), ("--focal-px", c.focal_px, 1.0, 1e5),
              ("--fov-deg", c.fov_deg, 1.0, 170.0), ("--cut-off-fraction", c.cut_off_fraction, 0.0, 1.0),
              ("--exposure-jitter-stops", c.exposure_jitter_stops, 0.0, 3.0),
              ("--white-balance-jitter", c.white_balance_jitter, 0.0, 1.0), ("--jpeg-quality", c.jpeg_quality, 1, 100)]
    for flag, value, lo, hi in checks:
        if value is not None and not (np.isfinite(value) and lo <= value <= hi):
            raise UserInputError(f"{flag} must be in {lo:g}..{hi:g} (got {value})")
    if c.focal_px is not None and c.fov_deg is not None:
        raise UserInputError("give --focal-px or --fov-deg, not both")


@dataclass(frozen=True)
class CaptureResult:
    out_dir: Path
    num_views: int
    render_seconds: float
    total_seconds: float
