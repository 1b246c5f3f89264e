"""The truncated SDF loss (eq. 9) and the regularizers (eqs. 11-13)."""

from __future__ import annotations

import math

import torch

from real2sim.collision.primitive_sdf import HAS_ROTATION
from real2sim.collision.fit.config import FitConfig
from real2sim.collision.fit.params import Layout


def sdf_loss(predicted: torch.Tensor, target: torch.Tensor, inside: str = "hinge",
             protrusion_weight: float = 0.0) -> torch.Tensor:
    """Eq. 9 per sample: squared error where the target is outside (>= 0), hinge max(d, 0) inside.

    ``inside="squared"`` uses max(d, 0)^2 instead (beyond the paper): the linear hinge is much
    steeper than the squared outside term near zero error, which biases the union to bulge out.
    ``protrusion_weight`` w (beyond the paper) multiplies the outside error by 1 + w where the union
    comes nearer the sample than the true surface does (predicted < target: the union reaches
    past the object there); 0 is eq. 9's symmetric square, bit for bit.
    """
    hinge = torch.clamp(predicted, min=0.0)
    outside = (predicted - target) ** 2
    if protrusion_weight:
        outside = outside * (1.0 + protrusion_weight * (predicted < target).to(outside.dtype))
    return torch.where(target >= 0, outside, hinge * hinge if inside == "squared" else hinge)


def centre_penalty(centres: torch.Tensor) -> torch.Tensor:
    """Eq. 11 per primitive: ``|c|^2 - 1`` outside the unit sphere, else 0."""
    return torch.clamp((centres * centres).sum(-1) - 1.0, min=0.0)


def quaternion_penalty(raw_quaternions: torch.Tensor) -> torch.Tensor:
    """Eq. 12 per primitive: ``(|q| - 1)^2`` on the raw (unnormalised) quaternion."""
    return (torch.sqrt((raw_quaternions**2).sum(-1) + 1e-18) - 1.0) ** 2


def rotation_angle(quaternions: torch.Tensor) -> torch.Tensor:
    """Rotation angle tau in [0, pi] of (unnormalised) quaternions.

    Eq. 13 writes ``tau = 2 arccos(qw)``; we use the equivalent ``2 atan2(|v|, |w|)`` of the
    normalised quaternion: the same angle for unit q with w >= 0, the shorter one of q and -q
    otherwise, and a finite gradient at tau = 0 where arccos' is infinite.
    """
    v = torch.sqrt((quaternions[..., 1:] ** 2).sum(-1) + 1e-18)
    return 2.0 * torch.atan2(v, quaternions[..., 0].abs())


def rotation_penalty(quaternions: torch.Tensor) -> torch.Tensor:
    """Eq. 13 per primitive: zero for |tau| <= pi/4, growing linearly beyond."""
    return torch.clamp(rotation_angle(quaternions) - math.pi / 4.0, min=0.0)


def regularizers(layout: Layout, raws: list[torch.Tensor], config: FitConfig) -> torch.Tensor:
    """The weighted sum of eqs. 11-13 over every primitive of ``raws`` (raw rows per family); eq. 13
    only for the kinds in ``config.rotation_range_kinds``."""
    total = raws[0].new_zeros(())
    for kind, raw in zip(layout.kinds, raws):
        total = total + config.weight_centre * centre_penalty(raw[:, :3]).sum()
        if HAS_ROTATION[kind]:
            q = raw[:, -4:]
            total = total + config.weight_quaternion * quaternion_penalty(q).sum()
            if kind in config.rotation_range_kinds:
                total = total + config.weight_rotation * rotation_penalty(q).sum()
    return total
