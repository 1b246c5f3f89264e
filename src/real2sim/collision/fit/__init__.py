"""Fit a union of primitive shapes to signed-distance samples (paper IV-C3).

The target is a set of points in unit-sphere coordinates with the mesh's signed
distance at each (negative inside). The representation is a union (eq. 7: the
minimum) of primitive SDFs from :mod:`real2sim.collision.primitive_sdf`; its parameters are
found by minimising the truncated loss of eq. 9 plus the regularizers of eqs.
11-13 (eq. 14), either through an over-parameterized network ``g_theta()`` with
no input (eq. 10, Fig. 3) or directly.

Beyond the paper (each is a switch in :class:`FitConfig`; why each default is what it is, with
the measurements: docs/design-notes/collision.md):

* ``parameterization="direct"`` by default: the parameters are optimised directly (the paper's
  network ``g_theta()`` remains available as ``"network"``);
* ``inside_loss="squared"``: eq. 9's linear inside hinge is much steeper near zero error than
  its squared outside term, so the union bulges out; a squared hinge balances the two.
  ``final_loss`` is always the paper's eq. 9;
* ``fill_interior``: near-surface samples leave the deep interior unconstrained, so eq. 9 alone
  accepts a hollow shell; labelled-inside points in the enclosed interior (from the samples
  alone) make the union solid;
* ``init="kmeans"``: primitives start at k-means clusters of the interior samples (target
  sdf < 0, including the fill points), sized from each cluster's spread, instead of wherever a
  randomly initialised network puts them;
* ``box_init="cover"``: axis-aligned boxes alone (``boxes:N``) start instead from a greedy cover
  of the solid by maximal inscribed boxes (:mod:`.box_cover`), because k-means patches of the
  shell leave a staircase on the sides an object rolls on;
* only each sample's closest primitive (the argmin of eq. 7) is evaluated with autograd: the
  gradient of a minimum flows only to its argmin anyway, so this gives exactly the same gradient
  for a fraction of the cost of the dense (P x N) graph;
* dead primitives (the closest primitive of no interior sample) are re-seeded at the
  worst-covered interior samples during the fit, and the ones still dead at the end are dropped
  (``effective_count``);
* contact-aware fitting (``contact_weight``; by default on for cylinders and ellipsoids alone:
  ``FitConfig.contact_gain``): the samples within ``contact_band`` of the convex hull of the
  samples weigh ``1 + contact_weight`` in eq. 9's minibatch mean (:mod:`.contact_weights`). The
  dynamics depend most on the surfaces that touch, and those are all on the hull: the bottom the
  object stands on (the support plane is a hull face), the sides it rolls on, the edges it tips
  over; a concave pocket or waist touches no floor or wall. ``final_loss`` stays the unweighted
  eq. 9;
* ``protrusion_weight`` (off by default): outside samples the union reaches past weigh
  ``1 + protrusion_weight`` in eq. 9's outside square, so that the pieces stand less proud of the
  object;
* superquadrics (``superquadrics:N``): two shape exponents per piece, fitted like the sizes
  (bounded to the convex range by a sigmoid); their distance is a first-order estimate, so
  samples they are closest to compare distances clamped at ``superquadric_truncation``. They
  leave the fitter as convex mesh pieces.

Units: everything here is in unit-sphere coordinates (the sampler scales the mesh
into the unit sphere); :func:`.convert.to_collision_geometry` converts to metres in the
asset frame with ``asset = centre_m + scale_m * unit``.

The modules, in the order the fit uses them: :mod:`.config` (settings, result),
:mod:`.params` (parameter layout), :mod:`.initialization` (with :mod:`.box_cover`), :mod:`.contact_weights`,
:mod:`.losses`, :mod:`.union`
(the union's distance), :mod:`.loop` (the optimisation), :mod:`.convert` (to metres),
:mod:`.stage` (:func:`fit_collision`, what the asset stage calls).
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "FitConfig": "config",
    "FitResult": "config",
    "fit_collision": "stage",
    "fit_primitives": "loop",
    "result_sdf": "convert",
    "sdf_loss": "losses",
    "superquadric_parameters": "convert",
    "to_collision_geometry": "convert",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
