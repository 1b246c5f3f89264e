"""Parameter layout of a union of primitives: raw (unconstrained) parameters <-> packed rows.

Sizes go through a softplus above ``min_size``, superquadric exponents through a
sigmoid into the convex range, quaternions are normalised; the raw vector comes from
the paper's network ``g_theta()`` or is optimised directly."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from real2sim.collision.primitive_sdf import EXPONENT_DIM, PARAM_DIM, SIZE_DIM, SUPERQUADRIC_EXPONENT_RANGE
from real2sim.formats.spec import PRIMITIVE_FAMILIES
from real2sim.collision.fit.config import FitConfig


def _inverse_softplus(y: torch.Tensor) -> torch.Tensor:
    y = torch.clamp(y, min=1e-6)
    return y + torch.log(-torch.expm1(-y))


@dataclass(frozen=True)
class Layout:
    """Where each family's raw parameters live in the flat raw vector."""

    kinds: tuple[str, ...]  # one per family, in SPEC order
    counts: tuple[int, ...]
    offsets: tuple[int, ...]  # first primitive index of each family
    raw_offsets: tuple[int, ...]  # first raw entry of each family
    total_raw: int

    @staticmethod
    def of(parts: tuple[tuple[str, int], ...]) -> "Layout":
        kinds, counts, offs, roffs = [], [], [], []
        p = r = 0
        for family, count in parts:
            kind = PRIMITIVE_FAMILIES.get(family, family)
            if kind not in PARAM_DIM:
                raise ValueError(f"unknown primitive family {family!r}")
            kinds.append(kind)
            counts.append(int(count))
            offs.append(p)
            roffs.append(r)
            p += count
            r += count * PARAM_DIM[kind]
        return Layout(tuple(kinds), tuple(counts), tuple(offs), tuple(roffs), r)

    @property
    def total(self) -> int:
        return sum(self.counts)

    def split(self, raw: torch.Tensor) -> list[torch.Tensor]:
        return [
            raw[ro : ro + n * PARAM_DIM[k]].reshape(n, PARAM_DIM[k])
            for k, n, ro in zip(self.kinds, self.counts, self.raw_offsets)
        ]


def constrain(kind: str, raw: torch.Tensor, min_size: float, gain: float) -> torch.Tensor:
    """Raw rows -> packed rows: sizes through softplus + min_size, superquadric exponents through a
    sigmoid onto their convex range; centre and quaternion as they are (the SDFs normalise
    quaternions, so eq. 12 still sees the raw output, as in the paper)."""
    s, e = SIZE_DIM[kind], EXPONENT_DIM[kind]
    sizes = torch.nn.functional.softplus(raw[:, 3 : 3 + s]) + min_size
    lo, hi = SUPERQUADRIC_EXPONENT_RANGE
    exponents = lo + (hi - lo) * torch.sigmoid(gain * raw[:, 3 + s : 3 + s + e])
    return torch.cat((raw[:, :3], sizes, exponents, raw[:, 3 + s + e :]), 1)


def unconstrain(kind: str, packed: torch.Tensor, min_size: float, gain: float) -> torch.Tensor:
    """Packed rows -> raw rows, the inverse of :func:`constrain` (exponents clamped just inside their range)."""
    s, e = SIZE_DIM[kind], EXPONENT_DIM[kind]
    sizes = _inverse_softplus(packed[:, 3 : 3 + s] - min_size)
    lo, hi = SUPERQUADRIC_EXPONENT_RANGE
    unit = ((packed[:, 3 + s : 3 + s + e] - lo) / (hi - lo)).clamp(1e-6, 1 - 1e-6)
    return torch.cat((packed[:, :3], sizes, torch.logit(unit) / gain, packed[:, 3 + s + e :]), 1)


def constrain_all(layout: Layout, raws: list[torch.Tensor], config: FitConfig) -> list[torch.Tensor]:
    """Packed rows of every family from its raw rows (:func:`constrain` with the config's bounds)."""
    return [constrain(k, r, config.min_size, config.superquadric_exponent_gain) for k, r in zip(layout.kinds, raws)]


class PrimitiveNet(torch.nn.Module):
    """g_theta() of eq. 10 / Fig. 3: a learned latent vector through FC layers with a dense skip
    (the latent concatenated into the last hidden layer) to the flat raw parameter vector.

    The output is added to ``base`` (the initial raw parameters, a buffer), and the last layer
    starts near zero, so the fit starts exactly where the initialisation put the primitives.
    """

    def __init__(self, base: torch.Tensor, latent_dim: int, hidden_dim: int) -> None:
        super().__init__()
        self.register_buffer("base", base.clone())
        self.latent = torch.nn.Parameter(torch.randn(latent_dim) / math.sqrt(latent_dim))
        self.fc1 = torch.nn.Linear(latent_dim, hidden_dim)
        self.fc2 = torch.nn.Linear(hidden_dim, hidden_dim)
        self.fc3 = torch.nn.Linear(hidden_dim + latent_dim, hidden_dim)
        self.out = torch.nn.Linear(hidden_dim, base.numel())
        with torch.no_grad():
            self.out.weight.mul_(1e-2)
            self.out.bias.zero_()

    def forward(self) -> torch.Tensor:
        z = self.latent
        h = torch.relu(self.fc1(z))
        h = torch.relu(self.fc2(h))
        h = torch.relu(self.fc3(torch.cat((h, z))))
        return self.base + self.out(h)

    @torch.no_grad()
    def reset_rows(self, index: torch.Tensor, new_raw: torch.Tensor) -> None:
        """Make the output equal ``new_raw`` at ``index`` by shifting the base."""
        current = self.forward()
        self.base[index] += new_raw - current[index]


class DirectParams(torch.nn.Module):
    """The raw parameter vector optimised directly (``parameterization="direct"``), with the
    same interface as :class:`PrimitiveNet`."""

    def __init__(self, base: torch.Tensor) -> None:
        super().__init__()
        self.raw = torch.nn.Parameter(base.clone())

    def forward(self) -> torch.Tensor:
        return self.raw

    @torch.no_grad()
    def reset_rows(self, index: torch.Tensor, new_raw: torch.Tensor) -> None:
        self.raw[index] = new_raw
