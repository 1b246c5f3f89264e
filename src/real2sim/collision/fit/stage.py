"""The fitter as a stage: sample the canonical mesh's SDF, fit a SPEC, convert to metres."""

from __future__ import annotations

from real2sim.collision.fit.config import FitConfig
from real2sim.collision.fit.convert import superquadric_parameters, to_collision_geometry
from real2sim.collision.fit.loop import fit_primitives
from real2sim.formats.collision import CollisionGeometry
from real2sim.plumbing.progress import ProgressFn
from real2sim.formats.spec import CollisionSpec


def fit_collision(
    mesh_canonical,
    spec: CollisionSpec,
    *,
    fit_config: FitConfig = FitConfig(),
    sampling_config=None,
    cache_dir=None,
    rep_dir=None,
    device: str = "cpu",
    seed: int = 0,
    progress: ProgressFn | None = None,
) -> tuple[CollisionGeometry, dict]:
    """Sample the canonical mesh's SDF, fit ``spec``'s primitives, convert to the asset frame.

    ``rep_dir`` receives the mesh pieces of superquadrics (see :func:`to_collision_geometry`).
    Returns the geometry and a report: final_loss, fit_seconds, effective_count,
    requested_count, iterations, stop_reason (why the fit ended: :class:`FitResult`), device, contact_weight (the gain of contact-aware fitting the fit
    used), and the superquadrics' parameters when there are any.
    ``progress``: the SDF sampling's steps ("sdf: ..."), then the fit's iterations ("fit").
    """
    from real2sim.collision.sdf_sampling import SdfSamplingConfig, sample_sdf

    if not spec.is_primitive_fit:
        raise ValueError(f"SPEC {spec.text!r} is a baseline, not a primitive fit")
    samples = sample_sdf(mesh_canonical, sampling_config or SdfSamplingConfig(), cache_dir=cache_dir,
                         progress=progress)
    result = fit_primitives(samples.points, samples.sdf, spec.parts, fit_config, device=device, seed=seed,
                            progress=progress)
    geometry = to_collision_geometry(result, samples.centre_m, samples.scale_m, spec, rep_dir)
    report_dict = {
        "final_loss": result.final_loss,
        "fit_seconds": result.fit_seconds,
        "effective_count": result.effective_count,
        "requested_count": result.requested_count,
        "iterations": result.iterations,
        "stop_reason": result.stop_reason,
        "device": result.device,
        "contact_weight": result.contact_weight,
    }
    if "superquadric" in result.kinds:
        report_dict["superquadrics"] = superquadric_parameters(result, samples.scale_m)
    return geometry, report_dict
