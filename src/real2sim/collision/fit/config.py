"""Settings (:class:`FitConfig`) and result (:class:`FitResult`) of the primitive fit."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.collision.primitive_sdf import PARAM_DIM, SUPERQUADRIC_EXPONENT_RANGE


#: Primitive kinds fitted with contact-aware weighting by default, and its gain (FitConfig.contact_gain).
CONTACT_AWARE_KINDS = frozenset({"cylinder", "ellipsoid"})
CONTACT_AWARE_GAIN = 5.0


@dataclass(frozen=True)
class FitConfig:
    """Settings of the primitive fit; defaults follow the paper where it gives them.

    Lengths are in unit-sphere coordinates. ``learning_rate=None`` picks the
    default of the parameterization (the network's output moves by roughly
    ``lr * hidden_dim`` per step, so it needs a much smaller step than ``direct``).
    """

    parameterization: str = "direct"  # "direct" or "network" (the paper's eq. 10, Fig. 3); see docs/benchmarks/fitting.md
    init: str = "kmeans"  # "kmeans" (beyond the paper) or "random"
    # Axis-aligned boxes alone (boxes:N) start from a greedy cover of the solid by maximal boxes
    # ("cover", fit/box_cover.py) rather than k-means patches ("kmeans"); needs init="kmeans".
    box_init: str = "cover"
    learning_rate: float | None = None
    lr_schedule: str = "cosine"  # "cosine" (to final_lr_fraction * lr) or "constant"
    final_lr_fraction: float = 0.02
    batch_size: int = 8192
    max_iterations: int = 1000
    min_iterations: int = 300  # no early stop before this
    patience: int = 150  # early stop when the smoothed loss has not improved for this many steps
    plateau_tolerance: float = 2e-3  # relative improvement that counts as progress
    inside_loss: str = "squared"  # eq. 9 inside term: "hinge" max(d, 0) (paper) or "squared" max(d, 0)^2
    weight_centre: float = 1e-3  # w_c, eq. 11
    weight_quaternion: float = 1e-3  # w_q, eq. 12
    weight_rotation: float = 0.1  # w_r, eq. 13
    rotation_range_kinds: tuple[str, ...] = ("rotated_box", "cylinder")  # eq. 13 applies to these
    min_size: float = 0.004  # smallest half-size / radius (unit sphere), added to a softplus
    # Samples whose closest primitive is a superquadric compare min(distance, this) (unit sphere):
    # its distance is a first-order estimate, too small away from the surface near edges, and
    # fitting those far values rounds boxes off (a box's samples pulled e2 to 0.38, not ~0).
    superquadric_truncation: float = 0.1
    # Raw superquadric exponents are multiplied by this before their sigmoid, i.e. they take larger
    # steps than the sizes: only samples near edges and corners inform them, so their minibatch
    # gradient is noisy and Adam moves them slowly.
    superquadric_exponent_gain: float = 4.0
    # Both exponents of a new superquadric; 1 would start it as an ellipsoid. The box-like 0.3 ties
    # on IoU (fitting_superquadric_ablations_*.md) but simulates better: in the Table I protocol,
    # superquadrics:10 from 0.3 scored OCAE 0.0087 m against 0.0118 m from 1 (table1_superquadrics*.md).
    superquadric_init_exponent: float = 0.3
    latent_dim: int = 128  # Fig. 3: latent vector ...
    hidden_dim: int = 512  # ... through FC layers of this width, with a dense (concat) skip
    fill_interior: bool = True  # add labelled-inside points in the enclosed interior (beyond the paper)
    fill_resolution: int = 64  # voxels along the longest side of the interior's bounding box
    # Contact-aware fitting (beyond the paper, fit/contact_weights.py): samples within contact_band
    # (unit sphere) of the hull of the samples weigh 1 + contact_weight in eq. 9's mean; 0 is off.
    # The hull holds every surface the object touches a floor or wall with: the bottom it stands
    # on, the sides it rolls on, the edges it tips over. None takes the family's measured default
    # (:meth:`contact_gain`).
    contact_weight: float | None = None
    contact_band: float = 0.02
    # Outside samples the union reaches past (it comes nearer them than the true surface) weigh
    # 1 + protrusion_weight in eq. 9's outside square (losses.sdf_loss); 0: the paper's symmetric
    # square. A piece standing proud of the object is what a reset to the object's pose presses
    # into a stiff support.
    protrusion_weight: float = 0.0
    revive_dead: bool = True  # re-seed dead primitives during the fit (beyond the paper)
    revive_every: int = 200
    remove_dead: bool = True  # drop primitives that are still dead at the end
    seed: int = 0
    device: str = "cpu"

    def __post_init__(self) -> None:
        if self.parameterization not in ("network", "direct"):
            raise ValueError(f"parameterization must be 'network' or 'direct', got {self.parameterization!r}")
        if self.init not in ("kmeans", "random"):
            raise ValueError(f"init must be 'kmeans' or 'random', got {self.init!r}")
        if self.box_init not in ("cover", "kmeans"):
            raise ValueError(f"box_init must be 'cover' or 'kmeans', got {self.box_init!r}")
        if self.lr_schedule not in ("cosine", "constant"):
            raise ValueError(f"lr_schedule must be 'cosine' or 'constant', got {self.lr_schedule!r}")
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

        Why by family: in the Table I protocol (bundled bottle and can, 10 runs, both contact models;
        docs/benchmarks/table1_contact_weight5.md against the unweighted sweep of the same code) gain 5
        brought cylinders:10 closer to the reference (OCAE 0.0168 -> 0.0143 m hydroelastic, 0.0265 ->
        0.0232 m point) and left ellipsoids:64 where they were (0.0089 -> 0.0089, 0.0169 -> 0.0171), and
        on the two generated shapes (table1_shapes_cw.md) it improved 7 of their 8 rows; the box
        families and spheres lost (boxes:10 0.0297 -> 0.0318 m hydroelastic, rotated_boxes:50 0.0212 ->
        0.0305, spheres:128 0.0144 -> 0.0150) and boxes:400 broke (the can fitted with 65 boxes instead
        of 112, its ramp runs 0.36 m off): boxes gain nothing from it.
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

    def packed(self, kind: str) -> np.ndarray:
        """(P_kind, D) array of the rows of one kind, in order."""
        rows = [p for k, p in zip(self.kinds, self.parameters) if k == kind]
        return np.asarray(rows, dtype=np.float64).reshape(len(rows), PARAM_DIM[kind])
