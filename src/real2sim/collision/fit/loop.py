"""The optimisation loop (eq. 14) with dead-primitive revival; torch's global state is left as found.

The loop uses the torch CPU threads it is given: the program chooses them once (the CLI's
``--threads``), a library call does not change them.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager

import numpy as np
import torch

from real2sim.collision.primitive_sdf import HAS_ROTATION, PARAM_DIM, SIZE_DIM
from real2sim.collision.fit.config import FitConfig, FitResult
from real2sim.collision.fit.params import Layout, unconstrain, constrain_all, PrimitiveNet, DirectParams
from real2sim.collision.fit.contact_weights import contact_weights, hull_planes
from real2sim.collision.fit.initialization import interior_fill_points, initial_packed, packed_from_blobs
from real2sim.collision.fit.losses import sdf_loss, regularizers
from real2sim.collision.fit.schedule import StepSchedule
from real2sim.collision.fit.union import closest, paired_distance, truncate_estimates, alive
from real2sim.plumbing.progress import ProgressFn, null_progress


@contextmanager
def _deterministic():
    """Deterministic kernels for the fit only: on 2 CPU threads, the accumulating scatter in the
    backward of the per-sample parameter gather otherwise differs in the last bit between runs,
    and 1000 Adam steps amplify that into visibly different fits.

    torch has no local form of this switch (``use_deterministic_algorithms`` is process-wide,
    with no context manager or per-tensor option), so it is set for the fit and put back as it
    was, warn-only flag included, however the fit ends."""
    before = torch.are_deterministic_algorithms_enabled()
    warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(before, warn_only=warn_only)


def fit_primitives(
    samples_points_unit,
    samples_sdf,
    parts: tuple[tuple[str, int], ...],
    config: FitConfig = FitConfig(),
    *,
    device: str | None = None,
    seed: int | None = None,
    progress: ProgressFn | None = None,
) -> FitResult:
    """Fit one union of primitives (all families of ``parts`` jointly) to SDF samples.

    ``samples_points_unit`` (N, 3) and ``samples_sdf`` (N,) are in unit-sphere coordinates
    (numpy or torch). ``parts`` are (family, count) pairs as in :class:`real2sim.formats.spec.CollisionSpec`
    (``"boxes"`` or the kind ``"box"``). ``device``/``seed`` override the config's.
    ``progress("fit", iteration, max_iterations)`` is called every few iterations.
    Deterministic for a given seed, device and thread count (torch's, as the caller set it).
    """
    device = device or config.device
    seed = config.seed if seed is None else seed
    layout = Layout.of(tuple(parts))
    if layout.total < 1:
        raise ValueError("at least one primitive is needed")
    t0 = time.perf_counter()
    points_np = np.asarray(samples_points_unit, dtype=np.float32)
    target_np = np.asarray(samples_sdf, dtype=np.float32).reshape(-1)
    if points_np.ndim != 2 or points_np.shape[1] != 3 or len(points_np) != len(target_np) or len(points_np) == 0:
        raise ValueError("samples must be (N, 3) points with N signed distances, N > 0")
    n_samples = len(points_np)
    # The hull comes from the samples alone (not the fill points, which are deep inside anyway).
    gain = config.contact_gain(layout.kinds)
    planes = hull_planes(points_np, target_np, config.contact_band) if gain > 0 else None
    if config.fill_interior:
        fill = interior_fill_points(points_np, target_np, config.fill_resolution, seed)
        points_np = np.concatenate((points_np, fill))
        target_np = np.concatenate((target_np, np.full(len(fill), -1e-3, dtype=np.float32)))
    points = torch.as_tensor(points_np).to(device)
    target = torch.as_tensor(target_np).to(device)
    weight = None  # None: eq. 9's plain mean, bit for bit as without the option
    if planes is not None:
        weight = torch.as_tensor(contact_weights(points_np, target_np, config.contact_band, gain,
                                                 planes=planes)).to(device)

    # Seed only the generators this fit draws from, inside a fork that restores them: a library
    # call must leave the caller's RNG streams (CPU and every CUDA device) as it found them.
    cuda_devices = list(range(torch.cuda.device_count())) if points.device.type == "cuda" else []
    with _deterministic(), torch.random.fork_rng(devices=cuda_devices):
        torch.random.default_generator.manual_seed(seed)
        if cuda_devices:
            torch.cuda.manual_seed_all(seed)
        gen = torch.Generator(device="cpu").manual_seed(seed)
        init = initial_packed(layout, points, target, config, gen)
        base = torch.cat([unconstrain(k, p, config.min_size, config.superquadric_exponent_gain).reshape(-1) for k, p in zip(layout.kinds, init)])
        if config.parameterization == "network":
            model: torch.nn.Module = PrimitiveNet(base.cpu(), config.latent_dim, config.hidden_dim).to(device)
        else:
            model = DirectParams(base.cpu()).to(device)
        optimiser = torch.optim.Adam(model.parameters(), lr=config.lr)
        iteration, history, revived, stop_reason = _iterate(model, optimiser, layout, points, target, weight, config, gen,
                                               progress or null_progress)

        with torch.no_grad():
            raws = layout.split(model())
            packed = constrain_all(layout, raws, config)
            dist, arg = closest(layout, packed, points)
            keep = alive(arg, dist, target, layout.total) if config.remove_dead else torch.ones(layout.total, dtype=torch.bool, device=device)
            if not bool(keep.any()):
                keep[0] = True  # never return an empty representation
            kept_layout, kept = _subset(layout, packed, keep)
            final_dist, _ = closest(kept_layout, kept, points)
            final_loss = float(sdf_loss(final_dist[:n_samples], target[:n_samples]).mean())

    kinds, rows = _rows(kept_layout, kept)
    return FitResult(
        kinds=tuple(kinds),
        parameters=tuple(rows),
        final_loss=final_loss,
        iterations=iteration,
        stop_reason=stop_reason,
        fit_seconds=time.perf_counter() - t0,
        effective_count=len(rows),
        requested_count=layout.total,
        device=str(device),
        history=tuple(history),
        revived=revived,
        contact_weight=gain,
    )



def _iterate(model: torch.nn.Module, optimiser: torch.optim.Optimizer, layout: Layout, points: torch.Tensor,
             target: torch.Tensor, weight: torch.Tensor | None, config: FitConfig, gen: torch.Generator,
             progress: ProgressFn) -> tuple[int, list[float], int, str]:
    """The Adam steps on minibatches, with revival and the schedule's stop: (iterations, history,
    revived, stop reason: "converged", "plateau" or "max_iterations").

    ``weight`` (N,) per point (contact-aware fitting) turns eq. 9's minibatch mean into the
    weighted mean; None keeps the plain mean."""
    device = points.device
    n = len(points)
    batch = min(config.batch_size, n)
    history: list[float] = []
    schedule = StepSchedule(config)
    revived = 0
    cover_counts = torch.zeros(layout.total, dtype=torch.long, device=device)
    iteration, reason = 0, "max_iterations"
    for iteration in range(1, config.max_iterations + 1):
        for group in optimiser.param_groups:
            group["lr"] = schedule.lr
        idx = torch.randint(n, (batch,), generator=gen).to(device)
        x, s = points[idx], target[idx]
        raw = model()
        raws = layout.split(raw)
        packed = constrain_all(layout, raws, config)
        dist, arg = closest(layout, [p.detach() for p in packed], x)
        d = paired_distance(layout, packed, x, arg)
        if "superquadric" in layout.kinds:
            d, s = truncate_estimates(layout, arg, d, s, config.superquadric_truncation)
        per_sample = sdf_loss(d, s, config.inside_loss, config.protrusion_weight)
        if weight is None:
            data_loss = per_sample.mean()
        else:
            w = weight[idx]
            data_loss = (per_sample * w).sum() / w.sum()
        loss = data_loss + regularizers(layout, raws, config)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()

        value = float(loss.detach())
        covered = (s < 0) & (dist <= 0)
        cover_counts += torch.bincount(arg[covered], minlength=layout.total)
        if config.revive_dead and iteration % config.revive_every == 0 and iteration < 0.7 * config.max_iterations:
            revived += _revive(model, layout, cover_counts, points, target, config, gen)
            cover_counts.zero_()
        if iteration % 10 == 0:
            history.append(value)
            progress("fit", iteration, config.max_iterations)
        stop = schedule.step(iteration, value)
        if stop:
            reason = stop
            break
    return iteration, history, revived, reason


def _rows(layout: Layout, packed: list[torch.Tensor]) -> tuple[list[str], list[tuple[float, ...]]]:
    """Each primitive's kind and parameter row (quaternions normalised, w >= 0)."""
    kinds: list[str] = []
    rows: list[tuple[float, ...]] = []
    for kind, p in zip(layout.kinds, packed):
        p = p.detach().double().cpu().clone()
        if HAS_ROTATION[kind]:
            q = p[:, -4:]
            q = q / q.norm(dim=1, keepdim=True)
            p[:, -4:] = torch.where(q[:, :1] < 0, -q, q)  # w >= 0: same rotation, canonical sign
        for row in p.numpy():
            kinds.append(kind)
            rows.append(tuple(float(v) for v in row))
    return kinds, rows

def _subset(layout: Layout, packed: list[torch.Tensor], keep: torch.Tensor) -> tuple[Layout, list[torch.Tensor]]:
    parts, kept = [], []
    for kind, p, off, count in zip(layout.kinds, packed, layout.offsets, layout.counts):
        m = keep[off : off + count]
        if bool(m.any()):
            parts.append((kind, int(m.sum())))
            kept.append(p[m])
    return Layout.of(tuple(parts)), kept


@torch.no_grad()
def _revive(
    model: torch.nn.Module,
    layout: Layout,
    cover_counts: torch.Tensor,
    points: torch.Tensor,
    target: torch.Tensor,
    config: FitConfig,
    gen: torch.Generator,
) -> int:
    """Re-seed primitives that covered no interior sample since the last call at the interior
    samples that are worst covered, as small primitives (beyond the paper). Returns how many."""
    dead = (cover_counts == 0).nonzero().squeeze(1)
    if len(dead) == 0:
        return 0
    probe = torch.randint(len(points), (min(len(points), 65_536),), generator=gen).to(points.device)
    x, s = points[probe], target[probe]
    raws = layout.split(model())
    packed = constrain_all(layout, raws, config)
    dist, _ = closest(layout, packed, x)
    miss = torch.where(s < 0, dist, torch.zeros_like(dist))  # how far an interior sample is from being covered
    order = miss.argsort(descending=True)
    order = order[miss[order] > 0]
    if len(order) == 0:
        return 0
    dead = dead[: len(order)]
    seeds = x[order[: len(dead)]]
    # Spread out the seeds a little: the worst samples often sit in one uncovered pocket.
    size = torch.clamp(miss[order[: len(dead)]], min=2 * config.min_size)
    count = 0
    for kind, off, ro, n in zip(layout.kinds, layout.offsets, layout.raw_offsets, layout.counts):
        sel = ((dead >= off) & (dead < off + n)).nonzero().squeeze(1)
        if len(sel) == 0:
            continue
        sigma = size[sel, None].expand(-1, 3) / math.sqrt(3.0)
        new_packed = packed_from_blobs(kind, seeds[sel], sigma, config.superquadric_init_exponent)
        s_dim = SIZE_DIM[kind]
        new_packed[:, 3 : 3 + s_dim] = new_packed[:, 3 : 3 + s_dim].clamp(min=2 * config.min_size)
        new_raw = unconstrain(kind, new_packed, config.min_size, config.superquadric_exponent_gain)
        d = PARAM_DIM[kind]
        rows = dead[sel] - off
        flat = (ro + rows[:, None] * d + torch.arange(d, device=rows.device)[None, :]).reshape(-1)
        model.reset_rows(flat, new_raw.reshape(-1))
        count += len(sel)
    return count
