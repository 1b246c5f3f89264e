"""Printed square fiducials on the table of a simulated handheld capture: where they lie, what their paper
looks like, and their true corners (:func:`marker_layout`, :func:`marker_page`).

World frame: the table top z = 0, z up, metres, the object's footprint centre the origin. Each marker is a
sheet with the black square of side ``marker_mm`` and a one-cell white quiet zone; the sheets lie on a ring
around the object's footprint, each turned by its own angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.capture.phone.markers import aruco_dictionary, marker_cells

#: Texture pixels per marker cell (a close 1920-wide photo sees a 40 mm marker at about 300 px).
PX_PER_CELL = 32
#: Gap between the object's footprint and the nearest marker sheet's centre, in marker sides.
RING_GAP_SIDES = 1.0


@dataclass(frozen=True, eq=False)
class MarkerLayout:
    """``ids`` (N,); ``sheet_poses`` (N, 4, 4) world from each sheet's centre (its texture's top row
    towards the sheet's +y); ``sheet_side_m``: the square sheet's side; ``corners_m`` (N, 4, 3): the black
    square's corners in the world, OpenCV's order (the printed marker's top-left, top-right, bottom-right,
    bottom-left)."""

    dictionary: str
    marker_m: float
    ids: np.ndarray
    sheet_poses: np.ndarray
    sheet_side_m: float
    corners_m: np.ndarray

    def to_json(self) -> dict:
        return {"dictionary": self.dictionary, "marker_mm": 1000.0 * self.marker_m,
                "markers": [{"id": int(i), "corners_world_m": c.tolist()} for i, c in zip(self.ids, self.corners_m)],
                "note": "each marker's black square, corners in OpenCV's order (the printed marker's top-left, "
                        "top-right, bottom-right, bottom-left), world frame (table top z = 0), metres"}


def marker_layout(count: int, marker_mm: float, dictionary: str, footprint_radius_m: float, seed: int
                  ) -> MarkerLayout:
    """``count`` markers (ids 0..count-1) evenly around a ring ``RING_GAP_SIDES`` sides beyond the object's
    footprint radius, each sheet turned by a random angle, from ``seed``."""
    rng = np.random.default_rng((seed, 43))
    marker_m = marker_mm / 1000.0
    cells = marker_cells(dictionary)
    sheet = marker_m * (cells + 2) / cells
    ring = footprint_radius_m + RING_GAP_SIDES * marker_m + 0.5 * sheet
    angles = 2 * np.pi * (np.arange(count) / max(count, 1) + rng.random())
    yaws = rng.uniform(0, 2 * np.pi, count)
    half = marker_m / 2
    local = np.array([[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]])
    poses, corners = [], []
    for angle, yaw in zip(angles, yaws):
        c, s = np.cos(yaw), np.sin(yaw)
        pose = np.eye(4)
        pose[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        pose[:2, 3] = ring * np.array([np.cos(angle), np.sin(angle)])
        poses.append(pose)
        corners.append(local @ pose[:3, :3].T + pose[:3, 3])
    return MarkerLayout(dictionary, marker_m, np.arange(count), np.stack(poses) if poses else np.zeros((0, 4, 4)),
                        sheet, np.stack(corners) if corners else np.zeros((0, 4, 3)))


def marker_page(dictionary: str, marker_id: int, paper_white: int, ink_black: int) -> np.ndarray:
    """(S, S, 3) uint8: the printed sheet of one marker, its quiet zone included, ink and paper as printed."""
    import cv2

    cells = marker_cells(dictionary)
    image = cv2.aruco.generateImageMarker(aruco_dictionary(dictionary), int(marker_id), cells * PX_PER_CELL, 1)
    image = np.pad(image, PX_PER_CELL, constant_values=255)
    page = (ink_black + (paper_white - ink_black) * (image.astype(float) / 255.0)).astype(np.uint8)
    return np.repeat(page[:, :, None], 3, axis=2)
