"""Per-view corrections learnt with the radiance field: each training view's camera pose and its colour.

**Pose.** A robot's camera poses are a few millimetres and about a degree off; when
`refine-poses` cannot fix them the field would blur the object over the spread of the
views (docs/design-notes/reconstruct.md#field-pose-refinement). So every training view gets a small rigid
correction, learnt by the same gradient steps as the field: a rotation vector
``rotation_rad`` (world axes, about the camera's centre) and a move ``translation_m`` of
the camera's centre (world axes, metres). The corrected camera-to-world pose is
``[R(w) R | c + t]``: a ray from the view keeps its pixel but leaves from ``c + t`` along
``R(w) d``. World axes rather than the camera's own make the gauge below linear and
leave the rays of the pool (already in the world frame) to be rotated as they are.

Three things keep the corrections honest:

* a Gaussian prior toward zero (``prior_deg``, ``prior_mm`` its scales), so a view whose
  images say little (a featureless side) stays where the robot put it;
* a fixed gauge: the field can follow any rigid motion of the whole rig, and any growth of
  it about the object, so after every step the motion that best explains all corrections
  together (least squares: a small rotation about the views' common point, a shift, a
  growth) is taken out of them. The world frame and its scale stay the robot's, with the
  table at z = 0;
* coarse to fine: the poses learn while the field is on its coarse grid, where the
  trilinear blend of big voxels gives every misaligned pixel a gradient that reaches a
  few millimetres (the idea of BARF's band-limited start), with a decaying rate, and are
  kept as they are on the fine grid (:meth:`ViewCorrections.freeze_poses`) instead of
  chasing its detail. They start after ``warmup_steps``, once the field's colours
  roughly match the images (before that every gradient says "change colour").

**Colour.** Real photos change exposure and white balance from view to view; a field
with one colour per point explains that with floaters in front of the darker views.
Every view gets a per-channel gain ``exp(g)`` and bias ``b`` applied to the colour the
field renders for it (the bias scaled by the opacity, so the background stays what it
is), initialised to the identity, with a prior toward it and a gauge (mean ``g`` and
mean ``b`` over the views are zero, so the field keeps the views' average look). The
field's own colours are that average look: texture baking and held-out views use them
as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class CorrectionConfig:
    """How the per-view pose and colour corrections learn with the field: Adam's rates and their schedule,
    and the Gaussian prior that holds the corrections toward none."""

    lr_rotation_rad: float = 1e-3
    """Adam's learning rate of the rotation corrections, radians per step; the camera moves learn at this
    times the median camera distance (metres per step), so that both move a pixel alike; > 0."""
    lr_colour: float = 2e-2
    """Adam's learning rate of the colour gains (log units) and biases; > 0."""
    lr_final_fraction: float = 0.01
    """The rates decay exponentially to this share of their start by the last step; in (0, 1]."""
    warmup_steps: int = 40
    """Steps before the pose corrections start to learn, so that the field's colours roughly match the
    images first (before that every gradient says "change colour"); >= 0. The colours have no warm-up."""
    prior_deg: float = 2.0
    """The scale of the prior on the rotation corrections, degrees; > 0."""
    prior_mm: float = 10.0
    """The scale of the prior on the camera moves, millimetres; > 0."""
    prior_gain: float = 1.0
    """The scale of the prior on the colour gains, log units; > 0."""
    prior_bias: float = 0.1
    """The scale of the prior on the colour biases (RGB in [0, 1]); > 0. Held closer to zero than the gains:
    on a low-contrast surface an offset imitates a gain, and an exposure change is a gain."""
    prior_weight: float = 1e-2
    """The prior's weight, added to the photometric loss (mean squared error) as a mean over the views; >= 0."""

    def validate(self) -> None:
        from real2sim.plumbing.errors import UserInputError

        for name in ("lr_rotation_rad", "lr_colour", "prior_deg", "prior_mm", "prior_gain", "prior_bias"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"correction setting {name} must be > 0 (got {getattr(self, name)})")
        if self.warmup_steps < 0 or self.prior_weight < 0 or not 0 < self.lr_final_fraction <= 1:
            raise UserInputError("correction warmup and prior weight must be >= 0, the final rate fraction in (0, 1]")


def rotation_matrices(rotvec: torch.Tensor) -> torch.Tensor:
    """(N, 3, 3) rotation matrices of rotation vectors (N, 3) (radians), differentiable at zero."""
    theta2 = (rotvec * rotvec).sum(dim=-1)
    theta = torch.sqrt(theta2 + 1e-20)
    small = theta < 1e-3
    # sin(t)/t and (1 - cos t)/t^2 by their series where t is small (float32 loses them there)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2.clamp_min(1e-20))
    zero = torch.zeros_like(rotvec[:, 0])
    x, y, z = rotvec.unbind(-1)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).view(-1, 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(k)
    return eye + a[:, None, None] * k + b[:, None, None] * (k @ k)


class ViewCorrections(torch.nn.Module):
    """Pose and colour corrections of ``c2w_cv.shape[0]`` views; see the module docstring.

    ``c2w_cv``: (V, 4, 4) the views' given camera-to-world poses (OpenCV axes, metres);
    ``pivot_m``: (3,) the point the views look at (the gauge's rotation centre); ``poses``, ``colours``:
    which corrections are learnt (the others stay the identity).
    """

    def __init__(self, c2w_cv: np.ndarray, pivot_m: np.ndarray, config: CorrectionConfig = CorrectionConfig(), *,
                 poses: bool = True, colours: bool = True, device: str | torch.device = "cpu"):
        super().__init__()
        views = len(c2w_cv)
        self.config, self.poses, self.colours = config, poses, colours
        self.rotation_rad = torch.nn.Parameter(torch.zeros(views, 3, device=device))
        self.translation_m = torch.nn.Parameter(torch.zeros(views, 3, device=device))
        self.log_gain = torch.nn.Parameter(torch.zeros(views, 3, device=device))
        self.bias = torch.nn.Parameter(torch.zeros(views, 3, device=device))
        self.c2w_cv = np.asarray(c2w_cv, dtype=np.float64)
        self._arm_m = torch.tensor(self.c2w_cv[:, :3, 3] - np.asarray(pivot_m, dtype=float), dtype=torch.float32,
                                   device=device)  # camera centre relative to the pivot
        self.distance_m = float(np.median(np.linalg.norm(self._arm_m.cpu().numpy(), axis=1)))

    def optimiser(self) -> torch.optim.Adam:
        c = self.config
        groups = []
        if self.poses:
            groups += [{"params": [self.rotation_rad], "lr": c.lr_rotation_rad, "base": c.lr_rotation_rad,
                        "warmup": True},
                       {"params": [self.translation_m], "lr": c.lr_rotation_rad * self.distance_m,
                        "base": c.lr_rotation_rad * self.distance_m, "warmup": True}]
        if self.colours:  # no warm-up: a gain has no wrong basin to fall into, and late it finds the field adapted
            groups += [{"params": [self.log_gain, self.bias], "lr": c.lr_colour, "base": c.lr_colour,
                        "warmup": False}]
        return torch.optim.Adam(groups or [{"params": [], "base": 0.0}])

    def schedule(self, optimiser: torch.optim.Adam, done: int, total: int) -> None:
        """Learning rates for the step after ``done`` of ``total``: zero during the poses' warm-up, then an
        exponential decay to ``lr_final_fraction``."""
        c = self.config
        for group in optimiser.param_groups:
            start = c.warmup_steps if group.get("warmup") else 0
            if done < start:
                group["lr"] = 0.0
            else:
                group["lr"] = group["base"] * c.lr_final_fraction ** ((done - start) / max(total - start, 1))

    @property
    def poses_learning(self) -> bool:
        """The pose corrections are learnt (False when off, or once frozen: then only applied to the rays)."""
        return self.poses and self.rotation_rad.requires_grad

    def freeze_poses(self) -> None:
        """Keep the pose corrections as they are from now on (the fine grid): they still move the rays, but
        get no gradients, no prior and no gauge, and the rays' stretches need no recasting."""
        self.rotation_rad.requires_grad_(False)
        self.translation_m.requires_grad_(False)

    # -- applying them ---------------------------------------------------------------------------
    def rays(self, view: torch.Tensor, origins: torch.Tensor, directions: torch.Tensor):
        """Corrected world rays (R, 3) of the pool rays ``origins``, ``directions`` of views ``view`` (R,)."""
        if not self.poses:
            return origins, directions
        rotations = rotation_matrices(self.rotation_rad)
        turned = (rotations[view] @ directions[:, :, None])[:, :, 0]
        return origins + self.translation_m[view], turned

    def colour(self, view: torch.Tensor, rgb: torch.Tensor, opacity: torch.Tensor) -> torch.Tensor:
        """The field's colour (R, 3) as view ``view`` (R,) sees it: gain times colour plus bias times opacity."""
        if not self.colours:
            return rgb
        return torch.exp(self.log_gain[view]) * rgb + self.bias[view] * opacity[:, None]

    def prior_loss(self) -> torch.Tensor:
        """The Gaussian prior toward no correction, averaged over the views (added to the photometric loss)."""
        c = self.config
        terms = torch.zeros((), device=self.rotation_rad.device)
        if self.poses_learning:
            terms = terms + (self.rotation_rad ** 2).sum(-1).mean() / np.radians(c.prior_deg) ** 2 \
                + (self.translation_m ** 2).sum(-1).mean() / (1e-3 * c.prior_mm) ** 2
        if self.colours:
            terms = terms + (self.log_gain ** 2).sum(-1).mean() / c.prior_gain ** 2 \
                + (self.bias ** 2).sum(-1).mean() / c.prior_bias ** 2
        return c.prior_weight * terms

    @torch.no_grad()
    def fix_gauge(self) -> None:
        """Take out of the corrections the rigid motion of the whole rig (pose) and the common
        gain and bias (colour) that best explain them; see the module docstring."""
        if self.poses_learning:
            w, _, _, moves = rig_motion(self.rotation_rad, self.translation_m, self._arm_m, self.distance_m)
            self.rotation_rad -= w
            self.translation_m -= moves
        if self.colours:
            self.log_gain -= self.log_gain.mean(dim=0)
            self.bias -= self.bias.mean(dim=0)

    # -- reading them ----------------------------------------------------------------------------
    def corrected_c2w(self) -> np.ndarray:
        """(V, 4, 4) the corrected camera-to-world poses (OpenCV axes, metres)."""
        c2w = self.c2w_cv.copy()
        if self.poses:
            with torch.no_grad():
                rotations = rotation_matrices(self.rotation_rad.double()).cpu().numpy()
            c2w[:, :3, :3] = rotations @ c2w[:, :3, :3]
            c2w[:, :3, 3] += self.translation_m.detach().double().cpu().numpy()
        return c2w

    def moved_m(self, rotation_since: torch.Tensor, translation_since: torch.Tensor, reach_m: float) -> torch.Tensor:
        """(V,) how far each view's rays moved, within ``reach_m`` of its camera, since the corrections were
        ``rotation_since``, ``translation_since`` (metres; first order in the rotation)."""
        with torch.no_grad():
            turn = (self.rotation_rad - rotation_since).norm(dim=-1)
            shift = (self.translation_m - translation_since).norm(dim=-1)
            return shift + turn * reach_m

    def snapshot(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.rotation_rad.detach().clone(), self.translation_m.detach().clone()


def rig_motion(rotation: torch.Tensor, translation: torch.Tensor, arm_m: torch.Tensor,
               distance_m: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The small motion of the whole rig closest, in least squares, to the per-view corrections (rotation
    vectors and camera-centre moves, (V, 3) each): a rotation vector w about the pivot, a shift t and a
    growth s of the rig about the pivot (the field scaled with it renders the same images), so view i
    turns by w and moves by w x arm_i + t + s arm_i (``arm_m``: camera centres less the pivot).
    Rotations are weighed by ``distance_m`` so that both residuals are in metres. Returns (w, t, s,
    the per-view moves (V, 3)), in ``rotation``'s dtype."""
    views = len(arm_m)
    dtype = torch.float64
    arm = arm_m.to(dtype)
    eye = torch.eye(3, dtype=dtype, device=arm.device)
    # w x a = -[a]x w
    skew = torch.zeros(views, 3, 3, dtype=dtype, device=arm.device)
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -arm[:, 2], arm[:, 1], -arm[:, 0]
    skew = skew - skew.transpose(1, 2)
    rows_rot = torch.cat([distance_m * eye.expand(views, 3, 3),
                          torch.zeros(views, 3, 4, dtype=dtype, device=arm.device)], dim=2)
    rows_move = torch.cat([-skew, eye.expand(views, 3, 3), arm[:, :, None]], dim=2)
    a = torch.cat([rows_rot, rows_move], dim=1).reshape(-1, 7)
    b = torch.cat([distance_m * rotation.to(dtype), translation.to(dtype)], dim=1).reshape(-1)
    solution = torch.linalg.lstsq(a.cpu(), b.cpu()[:, None]).solution[:, 0].to(arm.device)
    moves = (rows_move @ solution)  # (V, 3)
    solution = solution.to(rotation.dtype)
    return solution[:3], solution[3:6], solution[6], moves.to(rotation.dtype)


def correction_report(corrections: ViewCorrections, views, *, dataset_root=None,
                      region_m: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """The corrections of ``views`` (the :class:`PosedViews` they were learnt for) for ``report.json``: per view name the pose correction's angle (deg) and camera
    move (mm) and the colour gain and bias (R, G, B), the corrections that were learnt; with
    ``dataset_root/ground_truth/transforms.json``, the poses' errors against the true ones before and
    after (``pose_error_vs_truth``: mean and max angle in degrees, camera centre in mm and, for the
    corners and centre of the box ``region_m``, pixels from where the true cameras see them)."""
    names, per_view = views.names, {}
    with torch.no_grad():
        angle_deg = np.degrees(corrections.rotation_rad.norm(dim=-1).cpu().numpy())
        move_mm = 1000.0 * corrections.translation_m.norm(dim=-1).cpu().numpy()
        gain = torch.exp(corrections.log_gain).cpu().numpy()
        bias = corrections.bias.cpu().numpy()
    for i, name in enumerate(names):
        entry = {}
        if corrections.poses:
            entry.update(rotation_deg=round(float(angle_deg[i]), 4), translation_mm=round(float(move_mm[i]), 3))
        if corrections.colours:
            entry.update(gain=[round(float(g), 4) for g in gain[i]], bias=[round(float(b), 4) for b in bias[i]])
        per_view[name] = entry
    report = {"poses": corrections.poses, "colours": corrections.colours, "views": per_view}
    if corrections.poses and dataset_root is not None:
        errors = pose_errors_vs_truth(corrections.c2w_cv, corrections.corrected_c2w(), names, dataset_root, region_m,
                                      views.intrinsics)
        if errors is not None:
            report["pose_error_vs_truth"] = errors
    return report


def pose_errors_vs_truth(given_c2w: np.ndarray, corrected_c2w: np.ndarray, names: tuple[str, ...], dataset_root,
                         region_m: tuple[np.ndarray, np.ndarray] | None = None,
                         intrinsics=None) -> dict | None:
    """Errors of the given and corrected poses (N, 4, 4) of views ``names`` against the dataset's true
    poses (``ground_truth/transforms.json``); None without them. See :func:`correction_report`."""
    from real2sim.formats.dataset import pose_errors, read_dataset, read_ground_truth

    truth = read_ground_truth(dataset_root)
    if truth is None:
        return None
    true_by_name = dict(zip((f.file_path for f in truth.frames), truth.poses_c2w_cv()))
    index = [i for i, n in enumerate(names) if n in true_by_name]
    if not index:
        return None
    true = np.stack([true_by_name[names[i]] for i in index])
    points = None
    if region_m is not None:
        lo, hi = (np.asarray(a, dtype=float) for a in region_m)
        corners = np.stack(np.meshgrid(*np.stack([lo, hi]).T, indexing="ij"), axis=-1).reshape(-1, 3)
        points = np.vstack([corners, 0.5 * (lo + hi)])
        intrinsics = intrinsics or read_dataset(dataset_root, check_files=False).intrinsics
    out = {"views": len(index)}
    for label, c2w in (("before", given_c2w[index]), ("after", corrected_c2w[index])):
        angle, move = pose_errors(c2w, true)
        entry = {"rotation_mean_deg": float(angle.mean()), "rotation_max_deg": float(angle.max()),
                 "translation_mean_mm": float(move.mean()), "translation_max_mm": float(move.max())}
        if points is not None:
            entry["reprojection_mean_px"] = _reprojection_px(intrinsics, c2w, true, points)
        out[label] = entry
    return out


def _reprojection_px(intrinsics, c2w: np.ndarray, true_c2w: np.ndarray, points_m: np.ndarray) -> float:
    """Mean distance (px) between where cameras ``c2w`` and ``true_c2w`` see ``points_m``."""
    from real2sim.multiview.views import project

    seen, _ = project(intrinsics, c2w, points_m)
    true, _ = project(intrinsics, true_c2w, points_m)
    return float(np.linalg.norm(seen - true, axis=-1).mean())
