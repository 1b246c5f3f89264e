"""Trusted depth and the point cloud made of it: forward-backward agreement of the views' depth maps.

A pixel's depth is kept when enough of its neighbour views agree with it (:func:`consistent_depth`): its
point, projected into a neighbour, lands where that neighbour's own depth puts a point which, projected
back, falls within ``max_reprojection_px`` of the pixel at a depth within ``max_relative_depth`` of its
own. Wrong depths (a flat patch, a reflection, the room beyond the depth range) rarely agree twice.
The kept pixels become points (:func:`fused_points`), each with the normal of its depth map's surface
facing its camera, its colour and its pixel's footprint (world units a pixel spans at its depth).

Frames: the views' world frame (any unit); depth along the optical axis as in
:class:`~real2sim.multiview.stereo.DepthMaps`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from real2sim.multiview.stereo import DepthMaps, camera_rays
from real2sim.multiview.views import project_torch


@dataclass(frozen=True)
class FusionConfig:
    """Which depths :func:`consistent_depth` trusts."""

    max_reprojection_px: float = 1.0
    """A neighbour agrees when the round trip through its depth comes back within this many pixels (> 0)."""
    max_relative_depth: float = 0.01
    """... and within this share of the depth (> 0)."""
    min_agreeing: int = 2
    """Neighbours that must agree for a depth to be kept (>= 1)."""
    min_score: float = 0.3
    """Depths whose correlation is below this are not trusted (-1..1)."""


@dataclass(frozen=True)
class DensePoints:
    """Points fused from trusted depth.

    ``points``: (P, 3) float64 world; ``normals``: (P, 3) unit, facing the camera that saw the point;
    ``colours``: (P, 3) float32 0-1; ``view``: (P,) int the view whose depth gave it; ``footprint``: (P,)
    float64 world units one pixel of that view spans at the point's depth.
    """

    points: np.ndarray
    normals: np.ndarray
    colours: np.ndarray
    view: np.ndarray
    footprint: np.ndarray

    def subset(self, keep: np.ndarray) -> "DensePoints":
        return DensePoints(self.points[keep], self.normals[keep], self.colours[keep], self.view[keep],
                           self.footprint[keep])


def back_projected(maps: DepthMaps) -> np.ndarray:
    """(V, h, w, 3) float64 world point of every pixel's depth (pixels without depth: their camera centre)."""
    out = np.empty(maps.depth.shape + (3,))
    for i in range(len(maps.depth)):
        out[i] = maps.c2w_cv[i, :3, 3] + camera_rays(maps.intrinsics, maps.c2w_cv[i]) * maps.depth[i][..., None]
    return out


def consistent_depth(maps: DepthMaps, config: FusionConfig = FusionConfig(),
                     device: str | torch.device = "cpu") -> np.ndarray:
    """(V, h, w) int: how many of each pixel's neighbour views (``maps.neighbours``) agree with its depth
    (module docstring); 0 where the pixel has no depth or its correlation is below ``config.min_score``."""
    k = maps.intrinsics
    h, w = maps.depth.shape[1:]
    depth = torch.from_numpy(maps.depth).to(device)
    points = torch.from_numpy(back_projected(maps)).float().to(device)  # (V, h, w, 3)
    w2c = torch.from_numpy(np.linalg.inv(maps.c2w_cv)).float().to(device)
    pixel_v, pixel_u = torch.meshgrid(torch.arange(h, device=device) + 0.5, torch.arange(w, device=device) + 0.5,
                                      indexing="ij")
    score = torch.from_numpy(maps.score).to(device)
    out = np.zeros(maps.depth.shape, np.int32)
    with torch.no_grad():
        for i in range(len(depth)):
            nb = torch.from_numpy(np.asarray(maps.neighbours[i])).to(device)
            d_i = depth[i].reshape(-1)
            u, v, _ = project_torch(k, w2c[nb], points[i].reshape(-1, 3))  # (N, hw) in each neighbour
            col, row = torch.floor(u).long(), torch.floor(v).long()
            inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
            col, row = col.clamp(0, w - 1), row.clamp(0, h - 1)
            which = nb[:, None].expand_as(col)
            d_j = depth[which, row, col]
            u2, v2, z2 = project_torch(k, w2c[i:i + 1], points[which, row, col].reshape(-1, 3))  # and back
            error_px = torch.hypot(u2[0].reshape(col.shape) - pixel_u.reshape(1, -1),
                                   v2[0].reshape(col.shape) - pixel_v.reshape(1, -1))
            ok = (inside & (d_j > 0) & (error_px <= config.max_reprojection_px)
                  & ((z2[0].reshape(col.shape) - d_i).abs() <= config.max_relative_depth * d_i))
            valid = (d_i > 0) & (score[i].reshape(-1) >= config.min_score)
            out[i] = (ok.sum(dim=0) * valid).reshape(h, w).cpu().numpy()
    return out


def depth_normals(points: np.ndarray, camera_m: np.ndarray) -> np.ndarray:
    """(h, w, 3) unit normals of the surface of one view's back-projected ``points`` (h, w, 3), by central
    differences (one-sided at the border), turned to face ``camera_m`` (3,)."""
    du = np.gradient(points, axis=1)
    dv = np.gradient(points, axis=0)
    n = np.cross(du, dv)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
    facing = np.sum(n * (camera_m - points), axis=-1, keepdims=True) < 0
    return np.where(facing, -n, n)


def fused_points(maps: DepthMaps, agreeing: np.ndarray, config: FusionConfig = FusionConfig()) -> DensePoints:
    """The points of the pixels with at least ``config.min_agreeing`` agreeing neighbours (``agreeing``:
    :func:`consistent_depth`)."""
    world = back_projected(maps)
    keep = agreeing >= config.min_agreeing
    pts, normals, colours, view, footprint = [], [], [], [], []
    for i in range(len(world)):
        m = keep[i]
        pts.append(world[i][m])
        normals.append(depth_normals(world[i], maps.c2w_cv[i, :3, 3])[m])
        colours.append(maps.rgb[i][m])
        view.append(np.full(int(m.sum()), i))
        footprint.append(maps.depth[i][m].astype(np.float64) / maps.intrinsics.fl_x)
    return DensePoints(np.concatenate(pts), np.concatenate(normals), np.concatenate(colours).astype(np.float32),
                       np.concatenate(view), np.concatenate(footprint))
