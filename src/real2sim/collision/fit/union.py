"""The union's distance (eq. 7, the minimum over primitives), evaluated sparsely.

Only each sample's closest primitive is evaluated with autograd: the gradient of a
minimum flows only to its argmin anyway."""

from __future__ import annotations

import torch

from real2sim.collision.primitive_sdf import primitive_sdf
from real2sim.collision.fit.params import Layout


_CHUNK_ELEMENTS = 4_000_000  # primitives x points per dense no-grad block: bounds memory


@torch.no_grad()
def closest(layout: Layout, packed: list[torch.Tensor], points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Union distance (N,) and index of the closest primitive (N,), dense but chunked, no autograd."""
    n = len(points)
    step = max(1, _CHUNK_ELEMENTS // max(1, layout.total))
    dist = torch.empty(n, dtype=points.dtype, device=points.device)
    arg = torch.empty(n, dtype=torch.long, device=points.device)
    for start in range(0, n, step):
        x = points[start : start + step]
        d = torch.cat([primitive_sdf(k, x, p) for k, p in zip(layout.kinds, packed)], 0)
        v, i = d.min(0)
        dist[start : start + step] = v
        arg[start : start + step] = i
    return dist, arg


def paired_distance(layout: Layout, packed: list[torch.Tensor], points: torch.Tensor, arg: torch.Tensor) -> torch.Tensor:
    """Distance of each point to its own (closest) primitive, with autograd through the parameters."""
    out = points.new_zeros(len(points))
    for kind, p, off, count in zip(layout.kinds, packed, layout.offsets, layout.counts):
        sel = ((arg >= off) & (arg < off + count)).nonzero().squeeze(1)
        if len(sel) == 0:
            continue
        d = primitive_sdf(kind, points[sel], p[arg[sel] - off], paired=True)
        out = out.index_put((sel,), d)
    return out


def truncate_estimates(
    layout: Layout, arg: torch.Tensor, d: torch.Tensor, target: torch.Tensor, limit: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Clamp prediction and target at ``limit`` where the closest primitive is a superquadric."""
    estimated = torch.zeros_like(arg, dtype=torch.bool)
    for kind, off, count in zip(layout.kinds, layout.offsets, layout.counts):
        if kind == "superquadric":
            estimated |= (arg >= off) & (arg < off + count)
    return torch.where(estimated, d.clamp(max=limit), d), torch.where(estimated, target.clamp(max=limit), target)


def alive(arg: torch.Tensor, dist: torch.Tensor, target: torch.Tensor, total: int) -> torch.Tensor:
    """Bool (P,): the primitive is the closest one of at least one interior sample it covers."""
    covered = (target < 0) & (dist <= 0)
    return torch.bincount(arg[covered], minlength=total) > 0
