"""Settings (:class:`FitConfig`) and result (:class:`FitResult`) of the primitive fit."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.collision.primitive_sdf import PARAM_DIM, SUPERQUADRIC_EXPONENT_RANGE


#: Primitive kinds fitted with contact-aware weighting by default, and its gain (FitConfig.contact_gain;
#: why: docs/design-notes/collision.md#contact-aware-fitting).
CONTACT_AWARE_KINDS = frozenset({"cylinder", "ellipsoid"})
CONTACT_AWARE_GAIN = 5.0


@dataclass(frozen=True)
class FitConfig:
    """Settings of the primitive fit (lengths in unit-sphere coordinates); defaults follow the
    paper where it gives them."""

    parameterization: str = "direct"
    """How the raw parameters are produced: "direct" (optimised themselves) or "network" (the
    paper's ``g_theta()``, eq. 10, Fig. 3). (why: docs/design-notes/collision.md#parameterization)"""
    init: str = "kmeans"
    """Where primitives start: "kmeans" (clusters of the interior samples, beyond the paper) or
    "random" (the paper's random positions and sizes in the middle of the unit sphere)."""
    box_init: str = "cover"
    """Start of a fit of axis-aligned boxes alone (boxes:N): "cover" (a greedy cover of the solid
    by maximal inscribed boxes, :mod:`.box_cover`) or "kmeans"; "cover" needs ``init="kmeans"``.
    (why: docs/design-notes/collision.md#box-cover)"""
    learning_rate: float | None = None
    """Adam's step size, > 0; None takes the parameterization's default (:attr:`lr`: 1e-4 for
    "network", whose output moves by roughly ``lr * hidden_dim`` per step, 2e-2 for "direct")."""
    lr_schedule: str = "cosine"
    """"cosine" (from ``lr`` down to ``final_lr_fraction * lr`` over ``max_iterations``),
    "plateau" (``lr`` held while the smoothed loss improves, cut by ``lr_decay`` after
    ``decay_patience`` steps without progress, down to ``final_lr_fraction * lr``; the fit stops
    when that smallest step size plateaus too) or "constant". "plateau" is an option, not the
    default: measured, it fitted as well or better but saved no iterations.
    (why: docs/design-notes/collision.md#convergence-stop)"""
    final_lr_fraction: float = 0.02
    """The schedule's smallest step size as a fraction of ``lr``, in [0, 1]: the cosine schedule's
    last, the plateau schedule's floor."""
    lr_decay: float = 0.3
    """The plateau schedule's factor on the step size at each plateau, in (0, 1); other schedules ignore it.
    (why: docs/design-notes/collision.md#convergence-stop)"""
    decay_patience: int = 50
    """Steps without progress of the smoothed loss (``plateau_tolerance``) after which the plateau
    schedule cuts the step size, or stops the fit at its smallest step size, >= 1; other schedules
    ignore it (they stop after ``patience``).
    (why: docs/design-notes/collision.md#convergence-stop)"""
    batch_size: int = 8192
    """Samples per minibatch, >= 1 (all of them when there are fewer)."""
    max_iterations: int = 1000
    """Adam steps at most, >= 0."""
    min_iterations: int = 300
    """Steps before which the early stop never acts, >= 0."""
    patience: int = 150
    """Early stop after this many steps without progress of the smoothed loss, >= 1."""
    plateau_tolerance: float = 2e-3
    """Relative drop of the smoothed loss that counts as progress, >= 0."""
    inside_loss: str = "squared"
    """Eq. 9's inside term: "hinge" max(d, 0) (the paper) or "squared" max(d, 0)^2 (beyond the
    paper). (why: docs/design-notes/collision.md#inside-loss)"""
    weight_centre: float = 1e-3
    """w_c of eq. 11 (centres outside the unit sphere), >= 0."""
    weight_quaternion: float = 1e-3
    """w_q of eq. 12 (raw quaternions away from unit length), >= 0."""
    weight_rotation: float = 0.1
    """w_r of eq. 13 (rotations beyond pi/4), >= 0."""
    rotation_range_kinds: tuple[str, ...] = ("rotated_box", "cylinder")
    """Primitive kinds eq. 13 applies to."""
    min_size: float = 0.004
    """Smallest half-size / radius (unit sphere), > 0, added to a softplus of the raw size."""
    superquadric_truncation: float = 0.1
    """Samples whose closest primitive is a superquadric compare min(distance, this) (unit
    sphere), > 0: that distance is a first-order estimate, too small away from the surface near
    edges. (why: docs/design-notes/collision.md#superquadric-truncation)"""
    superquadric_exponent_gain: float = 4.0
    """Factor on the raw superquadric exponents before their sigmoid, > 0, so that they take larger
    steps than the sizes: only samples near edges and corners inform them, so their minibatch
    gradient is noisy and Adam moves them slowly."""
    superquadric_init_exponent: float = 0.3
    """Both exponents of a new superquadric, inside ``SUPERQUADRIC_EXPONENT_RANGE`` (0.02, 2); 1
    would start it as an ellipsoid, near 0 as a box. (why: docs/design-notes/collision.md#superquadric-start)"""
    latent_dim: int = 128
    """Length of the learned latent vector of the network parameterization (Fig. 3), >= 1."""
    hidden_dim: int = 512
    """Width of the network's FC layers (with a dense concat skip of the latent), >= 1."""
    fill_interior: bool = True
    """Add labelled-inside points in the enclosed interior (beyond the paper), so that the union
    is solid rather than a shell. (why: docs/design-notes/collision.md#interior-fill)"""
    fill_resolution: int = 64
    """Voxels along the longest side of the interior's bounding box, for the interior fill and the
    box cover, >= 1."""
    contact_weight: float | None = None
    """Contact-aware fitting's gain (beyond the paper, :mod:`.contact_weights`), >= 0: samples
    within ``contact_band`` of the hull of the samples weigh ``1 + contact_weight`` in eq. 9's
    mean; 0 is off; None takes the family's default (:meth:`contact_gain`).
    (why: docs/design-notes/collision.md#contact-aware-fitting)"""
    contact_band: float = 0.02
    """Half-width of the band around the samples' hull whose samples are weighted (unit sphere), > 0."""
    protrusion_weight: float = 0.0
    """Extra weight, >= 0, of outside samples the union reaches past (it comes nearer them than
    the true surface) in eq. 9's outside square (:func:`.losses.sdf_loss`); 0 is the paper's
    symmetric square. (why: docs/design-notes/collision.md#protrusion-weight)"""
    revive_dead: bool = True
    """Re-seed dead primitives at the worst-covered interior samples during the fit (beyond the paper)."""
    revive_every: int = 200
    """Steps between revivals, >= 1 (no revival after ``0.7 * max_iterations``)."""
    remove_dead: bool = True
    """Drop the primitives still dead at the end (``FitResult.effective_count``)."""
    seed: int = 0
    """Seed of the fit's random draws (minibatches, initialisation, revival)."""
    device: str = "cpu"
    """Torch device of the fit ("cpu", "cuda", "cuda:1", ...)."""

    def __post_init__(self) -> None:
        if self.parameterization not in ("network", "direct"):
            raise ValueError(f"parameterization must be 'network' or 'direct', got {self.parameterization!r}")
        if self.init not in ("kmeans", "random"):
            raise ValueError(f"init must be 'kmeans' or 'random', got {self.init!r}")
        if self.box_init not in ("cover", "kmeans"):
            raise ValueError(f"box_init must be 'cover' or 'kmeans', got {self.box_init!r}")
        if self.lr_schedule not in ("plateau", "cosine", "constant"):
            raise ValueError(f"lr_schedule must be 'plateau', 'cosine' or 'constant', got {self.lr_schedule!r}")
        if not 0 < self.lr_decay < 1 or self.decay_patience < 1:
            raise ValueError("lr_decay must lie in (0, 1) and decay_patience be >= 1")
        if self.inside_loss not in ("hinge", "squared"):
            raise ValueError(f"inside_loss must be 'hinge' or 'squared', got {self.inside_loss!r}")
        if self.batch_size < 1 or self.max_iterations < 0:
            raise ValueError("batch_size must be >= 1 and max_iterations >= 0")
        if not self.superquadric_truncation > 0 or not self.superquadric_exponent_gain > 0:
            raise ValueError("superquadric_truncation and superquadric_exponent_gain must be positive")
        if (self.contact_weight is not None and not self.contact_weight >= 0) or not self.contact_band > 0:
            raise ValueError("contact_weight must be >= 0 and contact_band > 0")
        if not self.protrusion_weight >= 0:
            raise ValueError(f"protrusion_weight must be >= 0, got {self.protrusion_weight}")
        lo, hi = SUPERQUADRIC_EXPONENT_RANGE
        if not lo < self.superquadric_init_exponent < hi:
            raise ValueError(f"superquadric_init_exponent must lie in ({lo}, {hi})")

    def contact_gain(self, kinds: tuple[str, ...]) -> float:
        """The contact weighting's gain for a fit of primitives of these ``kinds``: ``contact_weight``
        when it is set, else :data:`CONTACT_AWARE_GAIN` for cylinders and ellipsoids alone and 0 for the rest.

        By family because the weighting brought cylinders nearer the reference, left ellipsoids
        as they were, and cost the box families and spheres accuracy
        (docs/design-notes/collision.md#contact-aware-fitting).
        """
        if self.contact_weight is not None:
            return float(self.contact_weight)
        return CONTACT_AWARE_GAIN if kinds and set(kinds) <= CONTACT_AWARE_KINDS else 0.0

    @property
    def lr(self) -> float:
        if self.learning_rate is not None:
            return self.learning_rate
        return 1e-4 if self.parameterization == "network" else 2e-2


@dataclass(frozen=True)
class FitResult:
    """Fitted primitives in UNIT-SPHERE coordinates.

    ``parameters[i]`` is primitive i's packed row (layout in
    :mod:`real2sim.collision.primitive_sdf`; sizes are half-extents / radii / half-lengths,
    quaternions unit w, x, y, z); ``kinds[i]`` its kind. ``history`` is the
    minibatch loss (eq. 14) every ``history_every`` iterations.
    """

    kinds: tuple[str, ...]
    parameters: tuple[tuple[float, ...], ...]
    final_loss: float  # eq. 9 mean over all samples after dead removal
    iterations: int
    fit_seconds: float
    effective_count: int
    requested_count: int
    device: str
    history: tuple[float, ...] = ()
    history_every: int = 10
    revived: int = 0  # re-seedings of dead primitives during the fit
    contact_weight: float = 0.0  # the contact weighting's gain the fit used (FitConfig.contact_gain)
    stop_reason: str = "max_iterations"  # "converged" (plateau schedule), "plateau" (early stop) or "max_iterations"

    def packed(self, kind: str) -> np.ndarray:
        """(P_kind, D) array of the rows of one kind, in order."""
        rows = [p for k, p in zip(self.kinds, self.parameters) if k == kind]
        return np.asarray(rows, dtype=np.float64).reshape(len(rows), PARAM_DIM[kind])


def iteration_limits(max_iterations: int) -> dict:
    """FitConfig fields for a cap of ``max_iterations`` steps (>= 1): the cap, and the early stop's
    floor lowered to it when the cap is below the default floor."""
    return {"max_iterations": int(max_iterations),
            "min_iterations": min(int(max_iterations), FitConfig.min_iterations)}
