"""Training the voxel radiance field on masked images (the paper's loss, eq. 3).

Every training ray gets a random background colour: the target is the image
where the mask is set and that colour elsewhere, the prediction is the field's
colour composited over the same colour. So the field must be transparent
wherever the mask is not (the table is never learned) and opaque where it is;
this is the mask used as alpha.

Empty space is carved first: the field lives only inside a relaxed, dilated
visual hull. Training runs coarse-to-fine: a coarse grid first, then the field
is resampled onto a finer grid and trained further.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field as dataclass_field, replace

import numpy as np
import torch
from scipy.ndimage import binary_dilation, binary_erosion

from real2sim.formats.progress import ProgressFn
from real2sim.reconstruct.field import VoxelRadianceField
from real2sim.reconstruct.hull import VoxelGrid, carve
from real2sim.reconstruct.photo_carving import CarvingConfig, CarvingResult, photo_carve
from real2sim.reconstruct.views import PosedViews, pixel_rays


@dataclass(frozen=True)
class FieldConfig:
    """How the radiance field is trained. Grid sizes are voxels along the object's longest side.

    The density grid learns five times slower than the colour features
    (``lr_density``): the field starts as the visual hull (``init_density`` per voxel
    of the coarse grid inside it), which is already within a fraction of a millimetre
    of a convex object's surface, and a fast density lets the view-dependent colour
    trade geometry for shading. During development, on the bottle (100 views,
    320x240, an earlier build), density rates of 0.1 / 0.02 / 0.005 gave Chamfer
    0.74 / 0.51 / 0.47 mm; ``benchmarks/bench_reconstruct.py`` measures the defaults.
    ``view_dependent=False`` gives a Lambertian field.

    ``photo_carving``: before training, the visual hull is carved where the views disagree
    about its colour (:mod:`real2sim.reconstruct.photo_carving`), and
    the field starts empty there. Training cannot open a concavity the hull filled (a
    mug's cavity) by itself: a lid across it with a painted top renders nearly as well.
    The field may fill carved space again only within ``carved_margin_voxels`` (of the
    coarse grid) of what carving kept; deeper carved space is not part of the field, so
    rays into an opened cavity skip it (a negative margin keeps all of it in the field).
    """

    coarse_voxels: int = 80
    fine_voxels: int = 160
    coarse_steps: int = 400
    fine_steps: int = 800
    rays_per_step: int = 4096
    lr_density: float = 0.02
    lr_features: float = 0.1
    lr_decoder: float = 3e-3
    init_density: float = 4.0
    feature_channels: int = 12
    step_voxels: float = 0.5
    hull_outlier_fraction: float = 0.03
    carve_outlier_fraction: float = 0.1
    carve_dilation_voxels: int = 2
    view_dependent: bool = True
    mask_dilation_px: int = 3
    background_ray_fraction: float = 0.05
    photo_carving: bool = True
    carved_margin_voxels: int = 2
    carving: CarvingConfig = dataclass_field(default_factory=CarvingConfig)

    def with_budget(self, steps: int | None = None, voxels: int | None = None) -> "FieldConfig":
        """These settings with ``steps`` fine-grid training steps (the coarse grid gets half, so 1 step
        skips it) and ``voxels`` along the longest side of the fine grid (the coarse grid gets half);
        None keeps a setting."""
        config = self
        if steps is not None:
            config = replace(config, fine_steps=steps, coarse_steps=steps // 2)
        if voxels is not None:
            config = replace(config, fine_voxels=voxels, coarse_voxels=max(voxels // 2, 4))
        return config

    def with_carving(self, photo_carving: bool, hollow_prior: bool = True) -> "FieldConfig":
        """These settings with photo-consistent carving on or off, and its second pass (the hollow
        prior, :mod:`real2sim.reconstruct.photo_carving`) on or off."""
        return replace(self, photo_carving=photo_carving, carving=replace(self.carving, hollow_prior=hollow_prior))

    def validate(self) -> None:
        from real2sim.formats.errors import UserInputError

        for name in ("coarse_voxels", "fine_voxels", "rays_per_step", "feature_channels"):
            if int(getattr(self, name)) < 4:
                raise UserInputError(f"field setting {name} must be at least 4 (got {getattr(self, name)})")
        if self.coarse_steps < 0 or self.fine_steps < 1:
            raise UserInputError("field training needs at least one fine step")


@dataclass(frozen=True)
class TrainResult:
    field: VoxelRadianceField
    loss_curve: tuple[tuple[int, float], ...]  # (step, mean MSE over the last reporting window)
    seconds: float
    carved_voxels: int = 0  # coarse-grid voxels of the visual hull removed by photo-consistent carving
    # carving-grid voxels the carving removed and the masks' rays put back (poses off, see photo_carving)
    restored_voxels: int = 0
    # carving-grid voxels the second pass (the hollow prior, see photo_carving) removed
    opened_voxels: int = 0
    # of ``seconds``, the starting density: the visual hull's score and photo-consistent carving
    hull_and_carving_seconds: float = 0.0


@dataclass(frozen=True)
class RayPool:
    """Training rays: world origins/directions (R, 3), target colour (R, 3), mask (R,), float32 tensors."""

    origins: torch.Tensor
    directions: torch.Tensor
    rgb: torch.Tensor
    mask: torch.Tensor


def ray_pool(views: PosedViews, *, mask_dilation_px: int, background_fraction: float,
             rng: np.random.Generator) -> RayPool:
    """Rays through every pixel near the object (dilated masks) plus a sample of the others."""
    k = views.intrinsics
    origins, dirs, rgbs, masks = [], [], [], []
    disk = np.ones((2 * mask_dilation_px + 1,) * 2, bool)
    for i in range(views.count):
        near = binary_dilation(views.mask[i] > 0.5, disk)
        far = ~near & (rng.random(near.shape) < background_fraction)
        v_px, u_px = np.nonzero(near | far)
        o, d = pixel_rays(k, views.c2w_cv[i], u_px + 0.5, v_px + 0.5)
        origins.append(o)
        dirs.append(d)
        rgbs.append(views.rgb[i, v_px, u_px])
        masks.append(views.mask[i, v_px, u_px])
    cat = lambda xs: torch.from_numpy(np.concatenate(xs).astype(np.float32))
    return RayPool(cat(origins), cat(dirs), cat(rgbs), cat(masks))


def field_occupancy(views: PosedViews, grid: VoxelGrid, config: FieldConfig) -> np.ndarray:
    """The carved region the field may fill: a relaxed visual hull, dilated by a few voxels."""
    inside = carve(views, grid, config.carve_outlier_fraction) >= 0.5
    return binary_dilation(inside, np.ones((3, 3, 3), bool), iterations=config.carve_dilation_voxels)


def hull_density(views: PosedViews, grid: VoxelGrid, config: FieldConfig,
                 progress: ProgressFn | None = None, device: str = "cpu") -> tuple[np.ndarray, np.ndarray, CarvingResult | None]:
    """Initial density per voxel (``grid.shape``): ``init_density`` inside the visual hull, fading to
    nearly nothing outside it over about a voxel (a smooth step of the silhouette score), and
    nearly nothing where photo-consistent carving removed the hull; the voxels carved (bool); and
    the carving's result on its own grid (None without photo carving)."""
    score = carve(views, grid, config.hull_outlier_fraction)
    density = config.init_density * (1e-3 + 1.0 / (1.0 + np.exp(-12.0 * (score - 0.5))))
    if not config.photo_carving:
        return density, np.zeros(grid.shape, bool), None
    carved, result = _photo_carved(views, grid, score >= 0.5, config, progress, device)
    return np.where(carved, 1e-3 * config.init_density, density), carved, result


def _photo_carved(views: PosedViews, grid: VoxelGrid, hull: np.ndarray, config: FieldConfig,
                  progress: ProgressFn | None, device: str = "cpu") -> tuple[np.ndarray, CarvingResult]:
    """Voxels of ``grid`` that photo-consistent carving removes from the visual hull (``hull`` on ``grid``),
    and the carving's result on its own grid.

    Carving runs on a grid of at least ``config.carving.voxels`` along the longest side: on
    coarser voxels a true surface's voxel centres lie so far inside it that the views of
    them disagree (a 24-voxel can lost a quarter of its volume)."""
    if max(grid.shape) >= config.carving.voxels:
        result = photo_carve(views, grid, hull, config.carving, progress=progress, device=device)
        return hull & ~result.solid, result
    lo, hi = grid.bounds_m
    fine = VoxelGrid.covering(lo, hi, config.carving.voxels, table_z_m=float(lo[2]))
    fine_hull = carve(views, fine, config.hull_outlier_fraction) >= 0.5
    result = photo_carve(views, fine, fine_hull, config.carving, progress=progress, device=device)
    return _resampled(fine_hull & ~result.solid, fine, grid), result


def _resampled(mask: np.ndarray, source: VoxelGrid, target: VoxelGrid) -> np.ndarray:
    """``mask`` (bool, ``source.shape``) at the centres of ``target``'s voxels (nearest voxel)."""
    nearest = np.round((target.centres() - source.origin_m) / source.voxel_m).astype(int)
    nearest = np.clip(nearest, 0, np.asarray(source.shape) - 1)
    return mask[tuple(nearest.T)].reshape(target.shape)


def _deep_carved(carved: np.ndarray, source: VoxelGrid, target: VoxelGrid, margin_voxels: int) -> np.ndarray:
    """Photo-carved space (``carved`` on ``source``) farther than ``margin_voxels`` of ``source`` from
    anything carving kept, on ``target``: left out of the field's occupancy, so that rays skip
    it (a mug's opened cavity cost every ray into it a gradient sample per half voxel)."""
    if margin_voxels < 0 or not carved.any():
        return np.zeros(target.shape, bool)
    # scipy erodes until nothing changes when iterations is 0, so a zero margin is handled here
    deep = binary_erosion(carved, np.ones((3, 3, 3), bool), iterations=margin_voxels) if margin_voxels else carved
    return _resampled(deep, source, target)


def occupancy_ranges(field: VoxelRadianceField, origins: torch.Tensor,
                     directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per ray, the distances (R,) where it first enters and last leaves the field's occupancy.

    Ray-cast (embree) against the occupancy's surface, so rendering marches only that
    stretch of each ray; a ray that misses gets an empty range.
    """
    surface = field.occupancy_surface()
    origins = origins.cpu().numpy().astype(np.float64)
    dirs = directions.cpu().numpy().astype(np.float64)
    far = 4.0 * float(np.linalg.norm(field.grid.bounds_m[1] - field.grid.bounds_m[0])) + \
        float(np.abs(origins - field.grid.bounds_m.mean(axis=0)).max())
    t_in = np.zeros(len(origins))
    t_out = np.zeros(len(origins))
    hits, rays, _ = surface.ray.intersects_location(origins, dirs, multiple_hits=False)
    t_in[rays] = np.einsum("nd,nd->n", hits - origins[rays], dirs[rays])
    back_origin = origins + far * dirs
    hits_back, rays_back, _ = surface.ray.intersects_location(back_origin, -dirs, multiple_hits=False)
    t_out[rays_back] = far - np.einsum("nd,nd->n", hits_back - back_origin[rays_back], -dirs[rays_back])
    entered = np.zeros(len(origins), dtype=bool)
    entered[rays] = True
    t_out = np.where(entered, np.maximum(t_out, t_in) + field.grid.voxel_m, 0.0)
    t_in = np.where(entered, np.maximum(t_in - field.grid.voxel_m, 0.0), 0.0)
    to = lambda a: torch.from_numpy(a.astype(np.float32)).to(field.device)
    return to(t_in), to(t_out)


def train_field(views: PosedViews, region_m: tuple[np.ndarray, np.ndarray], config: FieldConfig = FieldConfig(), *,
                device: str = "cpu", seed: int = 0, progress: ProgressFn | None = None,
                table_z_m: float = 0.0) -> TrainResult:
    """Fit a :class:`VoxelRadianceField` to ``views`` inside the world box ``region_m`` (metres)."""
    config.validate()
    t_start = time.perf_counter()
    rng = np.random.default_rng(seed)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    pool = ray_pool(views, mask_dilation_px=config.mask_dilation_px,
                    background_fraction=config.background_ray_fraction, rng=rng)
    pool = RayPool(*(x.to(device) for x in (pool.origins, pool.directions, pool.rgb, pool.mask)))
    lo, hi = region_m
    stages = [(config.coarse_voxels, config.coarse_steps), (config.fine_voxels, config.fine_steps)]
    stages = [(n, s) for n, s in stages if s > 0]
    total = sum(s for _, s in stages)
    first_grid = VoxelGrid.covering(lo, hi, stages[0][0], table_z_m)
    t_hull = time.perf_counter()
    init_density, carved, carving = hull_density(views, first_grid, config, progress, device)
    hull_and_carving_s = time.perf_counter() - t_hull
    field, done, curve = None, 0, []
    for voxels, steps in stages:
        grid = VoxelGrid.covering(lo, hi, voxels, table_z_m)
        occupancy = field_occupancy(views, grid, config) & ~_deep_carved(carved, first_grid, grid,
                                                                           config.carved_margin_voxels)
        if field is None:
            field = VoxelRadianceField(grid, occupancy, feature_channels=config.feature_channels,
                                       init_density=init_density, device=device, generator=gen)
        else:
            field = field.upsampled(grid, occupancy)
        done = _optimise(field, pool, config, steps, done, total, gen, progress, curve)
    return TrainResult(field=field, loss_curve=tuple(curve), seconds=time.perf_counter() - t_start,
                       carved_voxels=int(carved.sum()), restored_voxels=carving.restored_voxels if carving else 0,
                       opened_voxels=carving.opened_voxels if carving else 0,
                       hull_and_carving_seconds=hull_and_carving_s)


def _optimise(field: VoxelRadianceField, pool: RayPool, config: FieldConfig, steps: int, done: int, total: int,
              gen: torch.Generator, progress: ProgressFn | None, curve: list) -> int:
    """``steps`` Adam steps on ``field``; appends (step, mean loss) to ``curve``; returns the steps done so far."""
    t_in, t_out = occupancy_ranges(field, pool.origins, pool.directions)
    # fused: one kernel over the whole grid; the per-tensor loop took a quarter of each step
    grid_opt = torch.optim.Adam([{"params": [field.density_table], "lr": config.lr_density, "base": config.lr_density},
                                 {"params": [field.feature_table], "lr": config.lr_features, "base": config.lr_features}],
                                fused=True)
    dec_opt = torch.optim.Adam(field.decoder.parameters(), lr=config.lr_decoder)
    window: list[torch.Tensor] = []  # losses on the device, read once per reporting window (a GPU sync)
    report_every = max(steps // 20, 1)
    device = field.device
    for step in range(steps):
        # the grid's learning rate decays tenfold over each stage
        for group in grid_opt.param_groups:
            group["lr"] = group["base"] * 0.1 ** (step / max(steps, 1))
        pick = torch.randint(len(pool.origins), (config.rays_per_step,), generator=gen).to(device)
        jitter = torch.rand(config.rays_per_step, generator=gen).to(device)
        background = torch.rand(config.rays_per_step, 3, generator=gen).to(device)
        out = field.render(pool.origins[pick], pool.directions[pick], step_voxels=config.step_voxels,
                           view_dependent=config.view_dependent,
                           jitter=jitter, t_range_m=(t_in[pick], t_out[pick]))
        m = pool.mask[pick][:, None]
        target = m * pool.rgb[pick] + (1 - m) * background
        predicted = out.rgb + (1 - out.opacity)[:, None] * background
        loss = torch.mean((predicted - target) ** 2)
        grid_opt.zero_grad(set_to_none=True)
        dec_opt.zero_grad(set_to_none=True)
        loss.backward()
        grid_opt.step()
        dec_opt.step()
        window.append(loss.detach())
        done += 1
        if step % report_every == report_every - 1 or step == steps - 1:
            curve.append((done, float(torch.stack(window).mean())))
            window = []
        if progress:
            progress(f"training field ({field.grid.shape[0]}x{field.grid.shape[1]}x{field.grid.shape[2]})", done, total)
    return done
