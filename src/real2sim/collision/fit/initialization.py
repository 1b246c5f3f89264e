"""Where the primitives start: interior fill points, k-means clusters of the interior samples."""

from __future__ import annotations

import math

import numpy as np
import torch

from real2sim.collision.primitive_sdf import HAS_ROTATION, SIZE_DIM
from real2sim.collision.fit.config import FitConfig
from real2sim.collision.fit.params import Layout


def interior_fill_points(
    points: np.ndarray, sdf: np.ndarray, resolution: int = 64, seed: int = 0
) -> np.ndarray:
    """Points (M, 3) deep inside the object, inferred from near-surface samples alone.

    Near-surface samples leave the deep interior almost unsampled (the paper adds only 500
    uniform ones), so eq. 9 alone is satisfied by a hollow shell of primitives, which has
    poor volume and hydroelastic behaviour. Voxels that hold an interior sample (sdf < 0)
    form a closed shell; the voxels it encloses (``binary_fill_holes``) that hold no
    outside sample are interior. One jittered point per such voxel is returned; the
    fitter gives them a negative target, so only the hinge of eq. 9 acts on them.
    """
    from scipy import ndimage

    inside = points[sdf < 0]
    if len(inside) < 100:
        return np.zeros((0, 3), dtype=np.float32)
    lo = inside.min(0)
    hi = inside.max(0)
    voxel = float((hi - lo).max()) / resolution
    if voxel <= 0:
        return np.zeros((0, 3), dtype=np.float32)
    lo = lo - 2 * voxel
    shape = np.ceil((hi + 2 * voxel - lo) / voxel).astype(int) + 1

    def cells(p: np.ndarray) -> tuple[np.ndarray, ...]:
        ijk = np.floor((p - lo) / voxel).astype(int)
        ok = np.all((ijk >= 0) & (ijk < shape), axis=1)
        return tuple(ijk[ok].T)

    occupied = np.zeros(shape, dtype=bool)
    occupied[cells(inside)] = True
    outside = np.zeros(shape, dtype=bool)
    outside[cells(points[sdf >= 0])] = True
    enclosed = ndimage.binary_fill_holes(occupied) & ~occupied & ~outside
    ijk = np.argwhere(enclosed)
    rng = np.random.default_rng(seed)
    return (lo + (ijk + rng.random(ijk.shape)) * voxel).astype(np.float32)


def _kmeans(x: torch.Tensor, k: int, generator: torch.Generator, iterations: int = 20) -> tuple[torch.Tensor, torch.Tensor]:
    """Lloyd's k-means with k-means++ seeding; returns (centres (k, 3), labels (M,))."""
    m = len(x)
    centres = torch.empty(k, 3, dtype=x.dtype, device=x.device)
    first = int(torch.randint(m, (1,), generator=generator, device="cpu"))
    centres[0] = x[first]
    d2 = ((x - centres[0]) ** 2).sum(1)
    for i in range(1, k):
        probs = (d2 / d2.sum().clamp(min=1e-30)).cpu()
        j = int(torch.multinomial(probs, 1, generator=generator))
        centres[i] = x[j]
        d2 = torch.minimum(d2, ((x - centres[i]) ** 2).sum(1))
    labels = torch.zeros(m, dtype=torch.long, device=x.device)
    for _ in range(iterations):
        labels = torch.cdist(x, centres).argmin(1)
        sums = torch.zeros_like(centres).index_add_(0, labels, x)
        counts = torch.bincount(labels, minlength=k).to(x.dtype).unsqueeze(1)
        centres = torch.where(counts > 0, sums / counts.clamp(min=1), centres)
    return centres, labels


def _cluster_spreads(x: torch.Tensor, centres: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Per-cluster standard deviation along each axis (k, 3)."""
    k = len(centres)
    diff2 = (x - centres[labels]) ** 2
    sums = torch.zeros_like(centres).index_add_(0, labels, diff2)
    counts = torch.bincount(labels, minlength=k).to(x.dtype).unsqueeze(1).clamp(min=1)
    return torch.sqrt(sums / counts)


def packed_from_blobs(kind: str, centres: torch.Tensor, sigma: torch.Tensor, init_exponent: float) -> torch.Tensor:
    """Packed rows for primitives whose volume matches blobs with per-axis std ``sigma``.

    A uniform solid of half-extent h has std h/sqrt(3) (box), a uniform disc of radius r
    has E[rho^2] = r^2/2, a uniform ball E[|x|^2] = 3r^2/5, a uniform ellipsoid std a/sqrt(5).
    """
    n = len(centres)
    ident = torch.zeros(n, 4, dtype=centres.dtype, device=centres.device)
    ident[:, 0] = 1.0
    if kind == "sphere":
        r = torch.sqrt((sigma**2).sum(1) * 5.0 / 3.0)
        return torch.cat((centres, r[:, None]), 1)
    if kind == "box":
        return torch.cat((centres, sigma * math.sqrt(3.0)), 1)
    if kind == "rotated_box":
        return torch.cat((centres, sigma * math.sqrt(3.0), ident), 1)
    if kind == "ellipsoid":
        return torch.cat((centres, sigma * math.sqrt(5.0), ident), 1)
    if kind == "superquadric":  # starts with both exponents at init_exponent, sized like the box
        exponents = torch.full_like(centres[:, :2], init_exponent)
        return torch.cat((centres, sigma * math.sqrt(3.0), exponents, ident), 1)
    radius = torch.sqrt(2.0 * (sigma[:, 0] ** 2 + sigma[:, 1] ** 2))
    half = sigma[:, 2] * math.sqrt(3.0)
    if kind == "capsule":
        half = torch.clamp(half - radius, min=0.0)
    return torch.cat((centres, radius[:, None], half[:, None], ident), 1)


def initial_packed(
    layout: Layout, points: torch.Tensor, sdf: torch.Tensor, config: FitConfig, generator: torch.Generator
) -> list[torch.Tensor]:
    """Initial packed rows per family (unit-sphere coordinates)."""
    n = layout.total
    dev, dt = points.device, points.dtype
    floor = 2.0 * config.min_size
    if config.init == "kmeans" and config.box_init == "cover" and layout.kinds == ("box",):
        cover = _cover_packed(points, sdf, n, config, generator)
        if cover is not None:
            return [cover]
    if config.init == "kmeans":
        inside = points[sdf < 0]
        if len(inside) < n:  # too few interior samples: fall back to all near-surface ones
            inside = points[sdf.abs() <= sdf.abs().quantile(0.5)]
        take = torch.randperm(len(inside), generator=generator)[: min(len(inside), max(50 * n, 10_000))].to(dev)
        x = inside[take]
        k = min(n, len(x))
        centres, labels = _kmeans(x, k, generator, iterations=10)
        sigma = _cluster_spreads(x, centres, labels)
        # Interior samples hug the surface, so a cluster is a thin patch of shell: give each
        # primitive at least the typical spacing between neighbouring clusters in every direction.
        if k > 1:
            spacing = torch.cdist(centres, centres).fill_diagonal_(float("inf")).min(1).values
            sigma = torch.maximum(sigma, 0.5 * spacing[:, None] / math.sqrt(3.0))
        if k < n:
            extra = torch.randint(k, (n - k,), generator=generator).to(dev)
            centres = torch.cat((centres, centres[extra]))
            sigma = torch.cat((sigma, sigma[extra]))
        order = torch.randperm(n, generator=generator).to(dev)  # which cluster seeds which family
        centres, sigma = centres[order], sigma[order].clamp(min=floor)
    else:
        # Paper-like: positions and sizes random in the middle of the unit sphere.
        u = torch.rand(n, 3, generator=generator).to(dev, dt) * 2 - 1
        centres = 0.5 * u
        sigma = (0.03 + 0.07 * torch.rand(n, 3, generator=generator)).to(dev, dt)
    out = []
    for kind, count, off in zip(layout.kinds, layout.counts, layout.offsets):
        packed = packed_from_blobs(kind, centres[off : off + count], sigma[off : off + count], config.superquadric_init_exponent)
        s = SIZE_DIM[kind]
        packed[:, 3 : 3 + s] = packed[:, 3 : 3 + s].clamp(min=floor)
        if HAS_ROTATION[kind] and config.init == "random":
            packed[:, -4:] += 0.05 * torch.randn(count, 4, generator=generator).to(dev, dt)
        out.append(packed)
    return out


def _cover_packed(points: torch.Tensor, sdf: torch.Tensor, n: int, config: FitConfig,
                  generator: torch.Generator) -> torch.Tensor | None:
    """Packed rows of ``n`` axis-aligned boxes from the greedy cover (:mod:`.box_cover`). When the
    cover needs fewer boxes (a carton is one), the rest start as the smallest boxes at random
    interior samples: they are dead from the start, so revival moves them to the worst-covered
    samples and the end of the fit drops those still dead. None when the cover finds no voxel
    wholly inside (a solid thinner than a voxel): the k-means start is used then."""
    from real2sim.collision.fit.box_cover import greedy_box_cover

    state = generator.get_state()
    seed = int(torch.randint(2**31 - 1, (1,), generator=generator))
    centres, half = greedy_box_cover(points.cpu().numpy(), sdf.cpu().numpy(), n, config.fill_resolution, seed)
    if len(centres) == 0:
        generator.set_state(state)  # the k-means start then draws exactly what it draws without the cover
        return None
    centres = torch.as_tensor(centres, dtype=points.dtype, device=points.device)
    half = torch.as_tensor(half, dtype=points.dtype, device=points.device)
    if len(centres) < n:
        inside = (sdf < 0).nonzero().squeeze(1)
        pick = inside[torch.randint(len(inside), (n - len(centres),), generator=generator).to(points.device)]
        centres = torch.cat((centres, points[pick]))
        half = torch.cat((half, torch.zeros(n - len(half), 3, dtype=points.dtype, device=points.device)))
    return torch.cat((centres, half.clamp(min=2.0 * config.min_size)), 1)
