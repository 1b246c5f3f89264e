"""A radiance field on a voxel grid, rendered by the paper's equations 1-4 (in discrete form).

The field stores, at every voxel centre of a :class:`~real2sim.multiview.voxel_grid.VoxelGrid`,
a raw density and ``feature_channels`` colour features, in one table so that one
sparse gather serves both. A point's values are the trilinear blend of its cell's
eight corners (an explicit 8-corner gather: on CPU several times faster than
``grid_sample``, and its gradient touches only those rows, so the optimiser can
update sparsely). Density is activated after blending (softplus of the blended
raw value), which lets a surface sit inside a cell rather than on the grid.

Units: density is per voxel length, so one voxel of density ``s`` lets
``exp(-s)`` of the light through whatever the voxel size. Colour comes from a
tiny decoder of the features and the viewing direction (view-dependent shading).

Rendering a ray ``r(t) = o + t d`` (world frame, metres, ``d`` unit): samples at
a fixed step inside the grid's box, skipped where ``occupancy`` (the carved visual
hull) is empty; alpha_i = 1 - exp(-sigma_i dt_i), T_i = exp(-sum_{j<i} sigma_j dt_j),
w_i = T_i alpha_i; colour = sum w_i c_i (eq. 1-2), depth = sum w_i t_i (eq. 4),
opacity = sum w_i.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import numpy as np
import torch
import torch.nn.functional as F
from scipy.ndimage import binary_dilation

from real2sim.multiview.rays import SurfaceRays
from real2sim.multiview.views import ray_box
from real2sim.multiview.voxel_grid import VoxelGrid, surface_from_grid


@dataclass(frozen=True)
class RayBatch:
    """Rendered rays: ``rgb`` (R, 3), ``opacity`` (R,), ``depth_m`` (R,) distance along the ray (metres)."""

    rgb: torch.Tensor
    opacity: torch.Tensor
    depth_m: torch.Tensor


def _blend_rows(table: torch.Tensor, flat: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """(P,) or (P, C): the rows ``flat`` (P * 8,) of ``table`` (N,) or (N, C) blended by ``weights`` (P, 8).
    index_select rather than table[idx]: its backward is an index_add, several times faster on CPU than
    the accumulating index_put that advanced indexing differentiates into."""
    rows = table.index_select(0, flat).view(*weights.shape, *table.shape[1:])
    return (rows * weights.view(*weights.shape, *([1] * (table.dim() - 1)))).sum(dim=1)


class VoxelRadianceField(torch.nn.Module):
    """Density + colour features on ``grid``, restricted to ``occupancy`` (bool, ``grid.shape``).

    ``init_density``: the starting density per voxel length, one value or one per voxel.
    """

    def __init__(self, grid: VoxelGrid, occupancy: np.ndarray, *, feature_channels: int = 12,
                 hidden: int = 32, init_density: float | np.ndarray = 1.0, device: str | torch.device = "cpu",
                 generator: torch.Generator | None = None):
        super().__init__()
        self.grid = grid
        self.feature_channels = feature_channels
        n = int(np.prod(grid.shape))
        raw = _softplus_inverse(np.broadcast_to(np.asarray(init_density, dtype=np.float64), grid.shape).reshape(-1))
        self.density_table = torch.nn.Parameter(torch.from_numpy(raw.astype(np.float32)).to(device))
        self.feature_table = torch.nn.Parameter(torch.zeros(n, feature_channels, device=device))
        self.register_buffer("occupancy", torch.from_numpy(np.ascontiguousarray(occupancy)).to(device))
        self.decoder = torch.nn.Sequential(
            torch.nn.Linear(feature_channels + 3, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 3))
        with torch.no_grad():
            for layer in self.decoder:
                if isinstance(layer, torch.nn.Linear):
                    bound = 1.0 / np.sqrt(layer.in_features)
                    layer.weight.uniform_(-bound, bound, generator=generator)
                    layer.bias.zero_()
        self.decoder.to(device)
        self._origin = torch.tensor(grid.origin_m, dtype=torch.float32, device=device)
        self._shape = torch.tensor(grid.shape, device=device)
        lo, hi = grid.bounds_m
        self._lo = torch.tensor(lo, dtype=torch.float32, device=device)
        self._hi = torch.tensor(hi, dtype=torch.float32, device=device)
        ny, nz = grid.shape[1], grid.shape[2]
        # made once: a tensor made per lookup is a host-to-device copy on a GPU, several per training step
        self._corner_offsets = torch.tensor([(dx * ny + dy) * nz + dz for dx in (0, 1) for dy in (0, 1)
                                             for dz in (0, 1)], device=device)
        self._compact: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None  # see compact_grid

    @property
    def device(self) -> torch.device:
        return self.density_table.device

    def occupancy_rays(self, grow_voxels: int = 1) -> SurfaceRays:
        """The surface (trimesh, metres; ``.mesh``) of the occupied voxels' cells grown by ``grow_voxels`` (at
        least one, so that no occupied sample lies outside it), with its Embree scene; made once per field and
        growth (ray casts use it to skip empty space)."""
        surfaces = self.__dict__.setdefault("_occupancy_rays", {})
        if grow_voxels not in surfaces:
            grown = binary_dilation(self.occupancy.cpu().numpy(), iterations=max(int(grow_voxels), 1))
            surfaces[grow_voxels] = SurfaceRays(surface_from_grid(grown.astype(np.float32), self.grid, 0.5,
                                                                  table_z_m=float(self.grid.bounds_m[0, 2])))
        return surfaces[grow_voxels]

    def grid_parameters(self) -> list[torch.nn.Parameter]:
        return [self.density_table, self.feature_table]

    @contextmanager
    def compact_grid(self) -> Iterator[tuple[torch.nn.Parameter, torch.nn.Parameter]]:
        """Parameters of the only grid rows a render can read, density (M,) and features (M, C), for an
        optimiser to step instead of the whole grid: while the context is open every lookup reads them, and
        the grid takes their values when it closes.

        A render samples occupied points only, whose trilinear corners lie in the occupancy grown by one
        voxel (26-connected); a row outside it gets no gradient, which Adam leaves as it is, so stepping
        these rows alone is the same training. The fine grid's dense tables are most of a CPU step's
        memory traffic (docs/design-notes/reconstruct.md#field-speed)."""
        grown = binary_dilation(self.occupancy.cpu().numpy(), structure=np.ones((3, 3, 3), dtype=bool))
        rows = torch.from_numpy(np.flatnonzero(grown)).to(self.device)
        lut = torch.zeros(len(self.density_table), dtype=torch.long, device=self.device)  # other rows: row 0, unread
        lut[rows] = torch.arange(len(rows), device=self.device)
        density = torch.nn.Parameter(self.density_table.detach().index_select(0, rows))
        features = torch.nn.Parameter(self.feature_table.detach().index_select(0, rows))
        self._compact = (lut, density, features)
        try:
            yield density, features
        finally:
            self._compact = None
            with torch.no_grad():
                self.density_table.index_copy_(0, rows, density.detach())
                self.feature_table.index_copy_(0, rows, features.detach())

    def _tables(self, flat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(density table, feature table, ``flat`` as their row indices): the grid's, or while
        :meth:`compact_grid` is open, its rows'."""
        if self._compact is None:
            return self.density_table, self.feature_table, flat
        lut, density, features = self._compact
        return density, features, lut.index_select(0, flat)

    # -- lookups ---------------------------------------------------------------------------------
    def _grid_coords(self, points_m: torch.Tensor) -> torch.Tensor:
        return (points_m - self._origin) / self.grid.voxel_m

    def occupied(self, points_m: torch.Tensor) -> torch.Tensor:
        """(P,) bool: the point's nearest voxel is in the occupancy (and inside the grid)."""
        q = torch.round(self._grid_coords(points_m)).long()
        inside = ((q >= 0) & (q < self._shape)).all(dim=-1)
        q = torch.minimum(q.clamp_min(0), self._shape - 1)
        return inside & self.occupancy[q[:, 0], q[:, 1], q[:, 2]]

    def _corners(self, points_m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Row indices (P, 8) of each point's cell corners and their trilinear weights (P, 8)."""
        q = self._grid_coords(points_m)
        base = torch.minimum(torch.floor(q).clamp_min(0), (self._shape - 2).float())
        frac = (q - base).clamp(0.0, 1.0)
        base = base.long()
        ny, nz = self.grid.shape[1], self.grid.shape[2]
        row = (base[:, 0] * ny + base[:, 1]) * nz + base[:, 2]
        wx = torch.stack([1 - frac[:, 0], frac[:, 0]], dim=1)
        wy = torch.stack([1 - frac[:, 1], frac[:, 1]], dim=1)
        wz = torch.stack([1 - frac[:, 2], frac[:, 2]], dim=1)
        weights = (wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]).reshape(-1, 8)
        return row[:, None] + self._corner_offsets, weights

    def interpolate(self, points_m: torch.Tensor) -> torch.Tensor:
        """(P, 1 + C) trilinear blend of raw density and features at world points (clamped to the grid)."""
        idx, weights = self._corners(points_m)
        density_table, feature_table, flat = self._tables(idx.reshape(-1))
        density = _blend_rows(density_table, flat, weights)
        return torch.cat([density[:, None], _blend_rows(feature_table, flat, weights)], dim=1)

    def blend_nodes(self, table: torch.Tensor, points_m: torch.Tensor) -> torch.Tensor:
        """(P,) trilinear blend at world points of ``table``, one value per grid node (flat, C order)."""
        idx, weights = self._corners(points_m)
        return (table[idx] * weights).sum(dim=1)

    def _density_raw(self, points_m: torch.Tensor) -> torch.Tensor:
        idx, weights = self._corners(points_m)
        table, _, flat = self._tables(idx.reshape(-1))
        return _blend_rows(table, flat, weights)

    def density(self, points_m: torch.Tensor) -> torch.Tensor:
        """(P,) density per voxel length at world points; zero outside the occupancy."""
        sigma = F.softplus(self._density_raw(points_m))
        return torch.where(self.occupied(points_m), sigma, torch.zeros_like(sigma))

    def colour(self, features: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.decoder(torch.cat([features, directions], dim=-1)))

    # -- rendering -------------------------------------------------------------------------------
    def render(self, origins: torch.Tensor, directions: torch.Tensor, *, step_voxels: float = 0.5,
               jitter: torch.Tensor | None = None, view_dependent: bool = True, max_distance_m: float | None = None,
               t_range_m: tuple[torch.Tensor, torch.Tensor] | None = None) -> RayBatch:
        """Render rays (R, 3) world origins and unit directions; ``jitter`` (R,) in [0, 1) shifts the samples.

        ``view_dependent=False`` hides the viewing direction from the colour decoder (a
        Lambertian field, which cannot fake a cavity's look on a lid across it).
        ``max_distance_m`` ends every ray that far from its origin; ``t_range_m`` (R,), (R,)
        limits each ray to where it may meet the object (it is also clipped to the grid's box).

        A first pass, density only and without gradients, walks the rays in chunks of
        samples and stops each one once it is opaque; the second pass, with colour and
        gradients, visits only the samples before that point.
        """
        device = origins.device
        rays = len(origins)
        step_m = step_voxels * self.grid.voxel_m
        t_near, t_far = ray_box(origins, directions, self._lo, self._hi)
        if t_range_m is not None:
            t_near = torch.maximum(t_near, t_range_m[0])
            t_far = torch.maximum(torch.minimum(t_far, t_range_m[1]), t_near)
        if max_distance_m is not None:
            t_far = torch.maximum(torch.clamp_max(t_far, max_distance_m), t_near)
        offset = torch.full((rays,), 0.5, device=device) if jitter is None else jitter
        ray_of, position = self._front_samples(origins, directions, t_near, t_far, offset, step_m, step_voxels)
        t = t_near[ray_of] + (position + offset[ray_of]) * step_m
        points = origins[ray_of] + t[:, None] * directions[ray_of]
        values = self.interpolate(points)
        tau = F.softplus(values[:, 0]) * step_voxels  # optical thickness of one step
        # exclusive cumulative sum per ray, with gradients: a (rays, longest) layout of the kept samples
        counts = torch.bincount(ray_of, minlength=rays)
        slot = torch.arange(len(ray_of), device=device) - (torch.cumsum(counts, 0) - counts)[ray_of]
        width = int(counts.max().item()) if len(ray_of) else 1
        dense = torch.zeros(rays, width, device=device, dtype=tau.dtype).index_put((ray_of, slot), tau)
        before = (torch.cumsum(dense, dim=1) - dense)[ray_of, slot]
        weights = torch.exp(-before) * (1.0 - torch.exp(-tau))
        colour = self.colour(values[:, 1:], directions[ray_of] if view_dependent else torch.zeros_like(points))
        zeros = torch.zeros(rays, device=device, dtype=tau.dtype)
        rgb = torch.zeros(rays, 3, device=device, dtype=tau.dtype).index_add(0, ray_of, weights[:, None] * colour)
        return RayBatch(rgb=rgb, opacity=zeros.index_add(0, ray_of, weights),
                        depth_m=zeros.index_add(0, ray_of, weights * t))

    def _front_samples(self, origins, directions, t_near, t_far, offset, step_m: float, step_voxels: float,
                       chunk: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(ray, sample position) of the occupied samples in front of each ray's opaque point, sorted by ray.

        The rays are walked ``chunk`` samples at a time; the samples kept do not depend on it.
        """
        device = origins.device
        if chunk is None:
            # A CPU pays for every sample, so short chunks stop sooner at opaque points. A GPU pays per
            # chunk, for the kernel launches and the host sync of each pass (why:
            # docs/design-notes/reconstruct.md#field-speed).
            chunk = 32 if device.type == "cpu" else 256
        per_ray = torch.ceil((t_far - t_near) / step_m).long().clamp_min(0)
        optical = torch.zeros(len(origins), device=device, dtype=torch.float64)
        alive = torch.nonzero(per_ray > 0)[:, 0]
        rays_kept, positions_kept = [], []
        first = 0
        with torch.no_grad():
            while len(alive):
                count = torch.clamp(per_ray[alive] - first, 0, chunk)
                of_alive = torch.repeat_interleave(count)  # each sample's ray among the alive ones
                ray_of = alive[of_alive]
                position = first + torch.arange(len(ray_of), device=device) - (torch.cumsum(count, 0) - count)[of_alive]
                t = t_near[ray_of] + (position + offset[ray_of]) * step_m
                points = origins[ray_of] + t[:, None] * directions[ray_of]
                # one index list for the three: each boolean index waits for the device on a GPU
                occupied = torch.nonzero(self.occupied(points))[:, 0]
                ray_of, position, points = ray_of[occupied], position[occupied], points[occupied]
                tau = (F.softplus(self._density_raw(points)) * step_voxels).double()
                before = optical[ray_of] + _exclusive_segment_cumsum(tau, ray_of, len(origins))
                front = torch.nonzero(before < _OPAQUE_OPTICAL_DEPTH)[:, 0]
                rays_kept.append(ray_of[front])
                positions_kept.append(position[front])
                optical.index_add_(0, ray_of, tau)
                first += chunk
                alive = alive[(optical[alive] < _OPAQUE_OPTICAL_DEPTH) & (per_ray[alive] > first)]
        if not rays_kept:
            empty = torch.zeros(0, dtype=torch.long, device=device)
            return empty, empty
        ray_of, position = torch.cat(rays_kept), torch.cat(positions_kept)
        order = torch.argsort(ray_of * (int(per_ray.max()) + 1) + position) if len(rays_kept) > 1 else None
        return (ray_of, position) if order is None else (ray_of[order], position[order])

    def render_chunked(self, origins: torch.Tensor, directions: torch.Tensor, chunk: int = 8192,
                       step_voxels: float = 0.5, max_distance_m: float | None = None,
                       t_range_m: tuple[torch.Tensor, torch.Tensor] | None = None) -> RayBatch:
        """:meth:`render` without gradients, in chunks of rays (bounded memory)."""
        parts = []
        with torch.no_grad():
            for s in range(0, len(origins), chunk):
                t_range = None if t_range_m is None else (t_range_m[0][s:s + chunk], t_range_m[1][s:s + chunk])
                parts.append(self.render(origins[s:s + chunk], directions[s:s + chunk], step_voxels=step_voxels,
                                         max_distance_m=max_distance_m, t_range_m=t_range))
        return RayBatch(*(torch.cat([getattr(p, f) for p in parts]) for f in ("rgb", "opacity", "depth_m")))

    # -- resolution ------------------------------------------------------------------------------
    def upsampled(self, grid: VoxelGrid, occupancy: np.ndarray) -> "VoxelRadianceField":
        """The same field on a finer ``grid`` (values blended from this one); the decoder is shared."""
        finer = VoxelRadianceField(grid, occupancy, feature_channels=self.feature_channels,
                                   hidden=self.decoder[0].out_features, device=self.device)
        with torch.no_grad():
            centres = torch.from_numpy(grid.centres().astype(np.float32)).to(self.device)
            values = torch.cat([self.interpolate(c) for c in centres.split(262_144)])
            # density is per voxel length: the same medium has less of it per (smaller) voxel
            per_voxel = F.softplus(values[:, 0]) * (grid.voxel_m / self.grid.voxel_m)
            finer.density_table.copy_(torch.log(torch.expm1(per_voxel.clamp_min(1e-6))))
            finer.feature_table.copy_(values[:, 1:])
        finer.decoder.load_state_dict(self.decoder.state_dict())
        return finer


_OPAQUE_OPTICAL_DEPTH = 9.0  # transmittance exp(-9) ~ 1e-4: nothing behind it shows


def _exclusive_segment_cumsum(values: torch.Tensor, segment: torch.Tensor, segments: int) -> torch.Tensor:
    """Sum of the earlier values of the same segment, for values sorted by (non-decreasing) segment."""
    running = torch.cumsum(values, 0) - values
    base = torch.full((segments,), float("inf"), dtype=values.dtype, device=values.device)
    base = base.scatter_reduce(0, segment, running, reduce="amin")
    return running - base[segment]


def _softplus_inverse(y):
    """Raw value whose softplus is ``y`` (> 0), elementwise."""
    return np.log(np.expm1(y))
