"""Training the voxel radiance field on masked images (the paper's loss, eq. 3).

Every training ray gets a random background colour: the target is the image
where the mask is set and that colour elsewhere, the prediction is the field's
colour composited over the same colour. So the field must be transparent
wherever the mask is not (the table is never learned) and opaque where it is;
this is the mask used as alpha.

Empty space is carved first: the field lives only inside a relaxed, dilated
visual hull. Training runs coarse-to-fine: a coarse grid first, then the field
is resampled onto a finer grid and trained further.

Each training view's pose and colour are corrected alongside
(:mod:`real2sim.reconstruct.field.view_corrections`): the rays of a view leave from its
corrected camera and the colour it sees is the field's through its gain and bias.
The fine grid's region is the visual hull of the corrected views.
"""

from __future__ import annotations

import time
from contextlib import ExitStack
from dataclasses import dataclass, field as dataclass_field, replace

import numpy as np
import torch
from scipy.ndimage import binary_dilation, binary_erosion

from real2sim.plumbing.progress import ProgressFn
from real2sim.reconstruct.field.radiance import VoxelRadianceField
from real2sim.multiview.hull import carve
from real2sim.multiview.voxel_grid import VoxelGrid
from real2sim.reconstruct.carving.photo import CarvingConfig, CarvingResult, photo_carve
from real2sim.reconstruct.field.convergence import ConvergenceConfig, StageSchedule
from real2sim.reconstruct.field.ray_pool import PoolRanges, RayPool, ray_pool
from real2sim.reconstruct.field.view_corrections import CorrectionConfig, ViewCorrections
from real2sim.multiview.views import PosedViews


@dataclass(frozen=True)
class FieldConfig:
    """How the radiance field is trained: its two grids, its steps and rates, what it starts from (the
    visual hull, photo-carved) and the per-view corrections learnt with it."""

    coarse_voxels: int = 80
    """Voxels along the object's longest side of the coarse grid, trained first; >= 4."""
    fine_voxels: int = 160
    """Voxels along the object's longest side of the fine grid, the coarse field resampled onto it; >= 4."""
    coarse_steps: int = 400
    """Training steps on the coarse grid; >= 0, 0 skips it."""
    fine_steps: int = 800
    """Training steps on the fine grid; >= 1."""
    rays_per_step: int = 2048
    """Rays drawn for each step (on a CPU; ``device_batch_scale`` times as many on a GPU); >= 4. 4096 gave the
    same mesh in nearly twice the time (why: docs/design-notes/reconstruct.md#rays-per-step)."""
    lr_density: float = 0.02
    """Adam's learning rate of the density grid at the start of each grid (it decays tenfold over it); > 0.
    Five times slower than the features: the field starts as the visual hull, and a fast density lets the
    view-dependent colour trade geometry for shading (why: docs/design-notes/reconstruct.md#density-rate)."""
    lr_features: float = 0.1
    """Adam's learning rate of the colour features, decaying as ``lr_density``'s; > 0."""
    lr_decoder: float = 3e-3
    """Adam's learning rate of the colour decoder (a small network of the features and the viewing
    direction); > 0."""
    init_density: float = 4.0
    """The starting density inside the visual hull, per voxel length of the coarse grid (about 1e-3 of it
    outside and where photo carving removed the hull); > 0."""
    feature_channels: int = 12
    """Colour features stored per voxel; >= 4."""
    step_voxels: float = 0.5
    """The rays' sampling step, in voxels of the grid being trained; > 0."""
    hull_outlier_fraction: float = 0.03
    """The share of the views that see a point that may put it outside their masks while the starting
    visual hull keeps it; in [0, 1)."""
    carve_outlier_fraction: float = 0.1
    """The same share for the relaxed visual hull that bounds where the field may fill (its occupancy);
    in [0, 1)."""
    carve_dilation_voxels: int = 2
    """That relaxed hull is dilated by this many voxels; >= 1."""
    view_dependent: bool = True
    """The colour depends on the viewing direction (shading); False: a Lambertian field."""
    mask_dilation_px: int = 3
    """Training rays go through every pixel within this many pixels of the mask; >= 0."""
    background_ray_fraction: float = 0.05
    """... and through this share of the other pixels, drawn at random; in [0, 1]."""
    photo_carving: bool = True
    """Carve the visual hull where the views disagree about its colour before training
    (:mod:`real2sim.reconstruct.carving.photo`), the field starting empty there: training cannot open a
    concavity the hull filled by itself (a lid across a mug's cavity with a painted top renders nearly as well)."""
    carved_margin_voxels: int = 2
    """The field may fill carved space again only within this many voxels (of the coarse grid) of what
    carving kept; deeper carved space is left out of the field, so rays into an opened cavity skip it;
    < 0 keeps all of it in the field."""
    carving: CarvingConfig = dataclass_field(default_factory=CarvingConfig)
    """How photo carving runs, when ``photo_carving``."""
    pose_refinement: bool = True
    """Correct each training view's pose with the field while it is on its coarse grid, then keep it
    (:mod:`real2sim.reconstruct.field.view_corrections`): it brings a few bad views among good ones back
    (why: docs/design-notes/reconstruct.md#field-pose-refinement)."""
    colour_correction: bool = True
    """Learn each view's exposure and white balance (a gain and a bias per channel) all through training."""
    corrections: CorrectionConfig = dataclass_field(default_factory=CorrectionConfig)
    """The rates and priors of the pose and colour corrections."""
    convergence: ConvergenceConfig = dataclass_field(default_factory=ConvergenceConfig)
    """When each grid's training ends before its steps (then caps) because its loss has flattened, the rates
    decaying with that progress (why: docs/design-notes/reconstruct.md#field-convergence)."""
    device_batch_scale: int = 2
    """On a GPU, each step draws this many times ``rays_per_step`` and the steps (and the poses' warm-up) are
    as many times fewer, so training sees the same rays; >= 1, 1 trains on a GPU as on a CPU. A GPU step is
    bound by launching its operators, not by its rays (why: docs/design-notes/reconstruct.md#device-batches)."""

    def on_device(self, device: str | torch.device) -> "FieldConfig":
        """These settings as trained on ``device``: on anything but a CPU, ``device_batch_scale`` times the
        rays per step in as many times fewer steps (``device_batch_scale``)."""
        scale = 1 if torch.device(device).type == "cpu" else int(self.device_batch_scale)
        if scale == 1:
            return self
        fewer = lambda steps: -(-steps // scale)  # rounded up: a stage of one step keeps it
        return replace(self, rays_per_step=self.rays_per_step * scale, coarse_steps=fewer(self.coarse_steps),
                       fine_steps=fewer(self.fine_steps),
                       corrections=replace(self.corrections, warmup_steps=self.corrections.warmup_steps // scale),
                       convergence=self.convergence.on_device(scale))

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
        prior, :mod:`real2sim.reconstruct.carving.photo`) on or off."""
        return replace(self, photo_carving=photo_carving, carving=replace(self.carving, hollow_prior=hollow_prior))

    def validate(self) -> None:
        from real2sim.plumbing.errors import UserInputError

        for name in ("coarse_voxels", "fine_voxels", "rays_per_step", "feature_channels"):
            if int(getattr(self, name)) < 4:
                raise UserInputError(f"field setting {name} must be at least 4 (got {getattr(self, name)})")
        if int(self.device_batch_scale) < 1:
            raise UserInputError(f"field setting device_batch_scale must be at least 1 (got {self.device_batch_scale})")
        if self.coarse_steps < 0 or self.fine_steps < 1:
            raise UserInputError("field training needs at least one fine step")
        self.corrections.validate()
        self.convergence.validate()


@dataclass(frozen=True)
class TrainResult:
    field: VoxelRadianceField
    loss_curve: tuple[tuple[int, float], ...]  # (steps trained, mean MSE over the last reporting window)
    seconds: float
    carved_voxels: int = 0  # coarse-grid voxels of the visual hull removed by photo-consistent carving
    restored_voxels: int = 0  # carving-grid voxels it removed and the masks' rays put back (see photo_carving)
    opened_voxels: int = 0  # carving-grid voxels the second pass (the hollow prior, see photo_carving) removed
    carving_exposure: dict | None = None  # the views' exposure and white balance as photo carving found them
    corrections: ViewCorrections | None = None  # the per-view corrections learnt (None: neither poses nor colours)
    # (N, 4, 4) the training views' camera-to-world poses the field was fitted to: the corrected ones
    c2w_cv: np.ndarray | None = None
    # where ``seconds`` went: the rays' pool, the starting density, then per grid (named by its longest side
    # in voxels) the setup (the region the field may fill, the field made or upsampled) and its training steps
    phase_seconds: dict[str, float] = dataclass_field(default_factory=dict)
    # the settings the field trained with: the ones given, as this device takes them (FieldConfig.on_device)
    config: FieldConfig | None = None
    # per grid: (voxels along its longest side, steps trained, why it ended: "cap" or "converged")
    stages: tuple[tuple[int, int, str], ...] = ()

    @property
    def hull_and_carving_seconds(self) -> float:
        """Of ``seconds``, the starting density: the visual hull's score and photo-consistent carving."""
        return self.phase_seconds.get("hull_and_carving", 0.0)

    def corrected_views(self, views: PosedViews) -> PosedViews:
        """``views`` (the ones trained on) with the poses the field was fitted to."""
        return views if self.c2w_cv is None else replace(views, c2w_cv=self.c2w_cv)


def field_occupancy(views: PosedViews, grid: VoxelGrid, config: FieldConfig, device: str = "cpu") -> np.ndarray:
    """The carved region the field may fill: a relaxed visual hull, dilated by a few voxels."""
    inside = carve(views, grid, config.carve_outlier_fraction, device=device) >= 0.5
    return binary_dilation(inside, np.ones((3, 3, 3), bool), iterations=config.carve_dilation_voxels)


def hull_density(views: PosedViews, grid: VoxelGrid, config: FieldConfig,
                 progress: ProgressFn | None = None, device: str = "cpu") -> tuple[np.ndarray, np.ndarray, CarvingResult | None]:
    """Initial density per voxel (``grid.shape``): ``init_density`` inside the visual hull, fading to
    nearly nothing outside it over about a voxel (a smooth step of the silhouette score), and
    nearly nothing where photo-consistent carving removed the hull; the voxels carved (bool); and
    the carving's result on its own grid (None without photo carving)."""
    score = carve(views, grid, config.hull_outlier_fraction, device=device)
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
    them disagree (why: docs/design-notes/reconstruct.md#carving-grid)."""
    if max(grid.shape) >= config.carving.voxels:
        result = photo_carve(views, grid, hull, config.carving, progress=progress, device=device)
        return hull & ~result.solid, result
    lo, hi = grid.bounds_m
    fine = VoxelGrid.covering(lo, hi, config.carving.voxels, table_z_m=float(lo[2]))
    fine_hull = carve(views, fine, config.hull_outlier_fraction, device=device) >= 0.5
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


def train_field(views: PosedViews, region_m: tuple[np.ndarray, np.ndarray], config: FieldConfig = FieldConfig(), *,
                device: str = "cpu", seed: int = 0, progress: ProgressFn | None = None,
                table_z_m: float = 0.0) -> TrainResult:
    """Fit a :class:`VoxelRadianceField` to ``views`` inside the world box ``region_m`` (metres), with
    the views' corrections (``config.pose_refinement``, ``config.colour_correction``); on a GPU in fewer,
    larger steps (:meth:`FieldConfig.on_device`)."""
    config.validate()
    config = config.on_device(device)
    t_start = time.perf_counter()
    rng = np.random.default_rng(seed)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    pool = ray_pool(views, mask_dilation_px=config.mask_dilation_px,
                    background_fraction=config.background_ray_fraction, rng=rng).to(device)
    lo, hi = region_m
    corrections = None
    if config.pose_refinement or config.colour_correction:
        corrections = ViewCorrections(views.c2w_cv, 0.5 * (np.asarray(lo) + np.asarray(hi)), config.corrections,
                                      poses=config.pose_refinement, colours=config.colour_correction, device=device)
    stages = [(n, s) for n, s in ((config.coarse_voxels, config.coarse_steps), (config.fine_voxels, config.fine_steps))
              if s > 0]
    total = sum(s for _, s in stages)
    first_grid = VoxelGrid.covering(lo, hi, stages[0][0], table_z_m)
    t_hull = time.perf_counter()
    init_density, carved, carving = hull_density(views, first_grid, config, progress, device)
    hull_and_carving_s = time.perf_counter() - t_hull
    field, done, curve, ended = None, 0, [], []
    # the rays' pool put on the device comes first: on a GPU it pays for starting the device
    phases = {"ray_pool": t_hull - t_start, "hull_and_carving": hull_and_carving_s}
    learner = _Learner(corrections, total) if corrections is not None else None
    for voxels, steps in stages:
        t_setup = time.perf_counter()
        grid = VoxelGrid.covering(lo, hi, voxels, table_z_m)
        # the region the field may fill, seen by the views as they are now corrected
        now = views if field is None or corrections is None else replace(views, c2w_cv=corrections.corrected_c2w())
        occupancy = field_occupancy(now, grid, config, device) & ~_deep_carved(carved, first_grid, grid,
                                                                         config.carved_margin_voxels)
        if field is None:
            field = VoxelRadianceField(grid, occupancy, feature_channels=config.feature_channels,
                                       init_density=init_density, device=device, generator=gen)
        else:
            field = field.upsampled(grid, occupancy)
            if corrections is not None and corrections.poses_learning:
                # The poses learn on the coarse grid only, whose big voxels give a misplaced pixel a gradient
                # that reaches millimetres; on the fine grid they would chase its detail, and learning them
                # there costs time (rays cast again as they move, gradients through every sample's position)
                # for no gain (why: docs/design-notes/reconstruct.md#field-pose-refinement).
                corrections.freeze_poses()
        t_steps = time.perf_counter()
        schedule = StageSchedule(steps, config.convergence)
        done = _optimise(field, pool, config, steps, done, total, gen, progress, curve, learner, schedule=schedule)
        ended.append((voxels, schedule.trained, schedule.stopped))
        phases[f"grid_{voxels}_setup"] = t_steps - t_setup
        phases[f"grid_{voxels}_steps"] = time.perf_counter() - t_steps  # the loss read at its end waits for them
    return TrainResult(field=field, loss_curve=tuple(curve), seconds=time.perf_counter() - t_start,
                       carved_voxels=int(carved.sum()), restored_voxels=carving.restored_voxels if carving else 0,
                       opened_voxels=carving.opened_voxels if carving else 0,
                       carving_exposure=carving.exposure if carving else None,
                       corrections=corrections,
                       c2w_cv=corrections.corrected_c2w() if corrections is not None else None, phase_seconds=phases,
                       config=config, stages=tuple(ended))


@dataclass
class _Learner:
    """The corrections, their optimiser and schedule over ``total`` steps; ``gauge``: take the rig's
    common motion out after each step (off when the field is frozen and fixes the frame itself)."""

    corrections: ViewCorrections
    total: int
    gauge: bool = True

    def __post_init__(self):
        self.optimiser = self.corrections.optimiser()


def fit_views_to_field(field: VoxelRadianceField, views: PosedViews, config: FieldConfig, *, steps: int = 60,
                       seed: int = 0) -> ViewCorrections:
    """Corrections of ``views`` (poses, and colours with ``config.colour_correction``) that fit them to a
    trained, frozen ``field``: how held-out views, which never trained it, are placed on the field's
    frame before they judge it (as BARF evaluates). No gauge: the field fixes the frame."""
    gen = torch.Generator(device="cpu").manual_seed(seed)
    pool = ray_pool(views, mask_dilation_px=config.mask_dilation_px,
                    background_fraction=config.background_ray_fraction, rng=np.random.default_rng(seed)).to(field.device)
    centre = field.grid.bounds_m.mean(axis=0)
    corrections = ViewCorrections(views.c2w_cv, centre, replace(config.corrections, warmup_steps=0),
                                  poses=True, colours=config.colour_correction, device=field.device)
    learner = _Learner(corrections, steps, gauge=False)
    learning = [p.requires_grad for p in field.parameters()]
    field.requires_grad_(False)  # no gradients for the grid tables: the largest part of a step's backward
    try:
        _optimise(field, pool, config, steps, 0, steps, gen, None, [], learner, learn_field=False)
    finally:
        for p, flag in zip(field.parameters(), learning):
            p.requires_grad_(flag)
    return corrections


def _optimise(field: VoxelRadianceField, pool: RayPool, config: FieldConfig, steps: int, done: int, total: int,
              gen: torch.Generator, progress: ProgressFn | None, curve: list, learner: _Learner | None = None,
              learn_field: bool = True, schedule: StageSchedule | None = None) -> int:
    """Up to ``steps`` Adam steps on ``field`` (and on the corrections of ``learner``; on those alone when not
    ``learn_field``), fewer when ``schedule``'s rule finds the loss flat; appends (steps trained, mean loss)
    to ``curve``; returns the steps done so far, counting the stage's cap when it ended early."""
    corrections = learner.corrections if learner is not None else None
    schedule = schedule or StageSchedule(steps)
    start, trained_before = done, curve[-1][0] if curve else 0
    ranges = PoolRanges(field, pool, corrections)
    with ExitStack() as stack:
        optimisers = []
        if learn_field:
            # the rows a render reads, fused (why both: docs/design-notes/reconstruct.md#field-speed)
            density, features = stack.enter_context(field.compact_grid())
            grid_opt = torch.optim.Adam([{"params": [density], "lr": config.lr_density, "base": config.lr_density}, {
                "params": [features], "lr": config.lr_features, "base": config.lr_features}], fused=True)
            optimisers = [grid_opt, torch.optim.Adam(field.decoder.parameters(), lr=config.lr_decoder)]
        if learner is not None:
            optimisers.append(learner.optimiser)
        window: list[torch.Tensor] = []  # losses on the device, read once per reporting window (a GPU sync)
        device = field.device
        for step in range(steps):
            # the grid's learning rate decays tenfold over each stage, by its steps or by its loss's progress
            fraction = schedule.fraction(step)
            for group in optimisers[0].param_groups if learn_field else ():
                group["lr"] = group["base"] * 0.1 ** fraction
            if learner is not None:  # the corrections' schedule follows the same progress
                corrections.schedule(learner.optimiser, start + round(fraction * steps), learner.total)
            pick = torch.randint(len(pool.origins), (config.rays_per_step,), generator=gen).to(device)
            jitter = torch.rand(config.rays_per_step, generator=gen).to(device)
            background = torch.rand(config.rays_per_step, 3, generator=gen).to(device)
            origins, directions, view = pool.origins[pick], pool.directions[pick], pool.view[pick]
            t_range = ranges.batch(pick)
            if corrections is not None:
                origins, directions = corrections.rays(view, origins, directions)
            out = field.render(origins, directions, step_voxels=config.step_voxels, view_dependent=config.view_dependent,
                               jitter=jitter, t_range_m=t_range)
            rgb = out.rgb if corrections is None else corrections.colour(view, out.rgb, out.opacity)
            m = pool.mask[pick][:, None]
            target = m * pool.rgb[pick] + (1 - m) * background
            predicted = rgb + (1 - out.opacity)[:, None] * background
            loss = torch.mean((predicted - target) ** 2)
            if corrections is not None:
                loss = loss + corrections.prior_loss()
            for opt in optimisers:
                opt.zero_grad(set_to_none=True)
            loss.backward()
            for opt in optimisers:
                opt.step()
            if learner is not None and learner.gauge:
                corrections.fix_gauge()
            window.append(loss.detach())
            done += 1
            if step % schedule.window == schedule.window - 1 or step == steps - 1:
                curve.append((trained_before + step + 1,
                              schedule.observe(float(torch.stack(window).mean()), len(window), step)))
                window = []
            done = start + steps if schedule.stopped else done  # an early end: the progress line jumps to the stage's end
            if progress:
                progress(f"training field ({field.grid.shape[0]}x{field.grid.shape[1]}x{field.grid.shape[2]})", done, total)
            if schedule.stopped:
                break
        return done
