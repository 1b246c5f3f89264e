"""The settings of one asset build (:class:`AssetConfig`), and the record of them that
``asset_config.json`` holds (:func:`config_record`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from real2sim.formats.contact import ContactProperties, MujocoConfig
from real2sim.formats.physical import PhysicalProperties
from real2sim.formats.spec import CollisionSpec
from real2sim.plumbing.errors import UserInputError

#: Relative tolerance of ``--mass-kg`` against a properties file's mass when the file gives no standard
#: error of it (or a smaller one): the rounding of a mass typed to three or four digits.
MASS_AGREEMENT_RTOL = 1e-3


def mass_agreement_kg(given: PhysicalProperties) -> float:
    """How far ``--mass-kg`` may lie from ``given.mass_kg`` and still agree with it: the larger of 3 x the
    file's standard error of the mass (when it gives one) and :data:`MASS_AGREEMENT_RTOL` of the mass."""
    return max(3.0 * (given.mass_standard_error_kg or 0.0), MASS_AGREEMENT_RTOL * given.mass_kg)


@dataclass(frozen=True)
class AssetConfig:
    """Everything ``real2sim asset`` needs besides the mesh and the output folder."""

    mass_kg: float
    """Mass of the object, kg: finite and > 0. With :attr:`given_properties` it must agree with their
    mass within :func:`mass_agreement_kg`."""
    specs: tuple[CollisionSpec, ...]
    """The collision representations to build, one folder each: at least one, none twice."""
    flat_bottom: bool = False
    """Crop the mesh at :attr:`support_height_m` and close it with a flat bottom
    (:func:`real2sim.asset.bottom.close_flat_bottom`) before anything else: for a reconstruction whose
    underside no camera saw."""
    support_height_m: float = 0.0
    """Height of the table plane in the input mesh frame (+z up), metres whatever :attr:`mesh_units`
    says; used by :attr:`flat_bottom`. Finite, below the mesh's top, and no further below its bottom
    than :data:`~real2sim.asset.checks.SUPPORT_BELOW_TOLERANCE` of its height. A capture stands the
    object on z = 0."""
    pca_up: bool = False
    """True: the longest principal axis becomes the asset's +z, as the paper does (which tilts squat objects
    such as a mug). False: the input's +z stays the asset's +z, and PCA picks only x, in the horizontal
    plane; a capture's input stands on its table, and robotics meshes are z-up
    (why: docs/design-notes/pipeline.md#keep-up)."""
    mesh_units: str = "m"
    """Units of the mesh file's coordinates: a key of :data:`~real2sim.geometry.mesh_io.MESH_UNITS_M`
    (m, cm, mm, in); everything else, :attr:`support_height_m` included, is in metres."""
    formats: tuple[str, ...] = ("urdf",)
    """Model files each representation gets, from :data:`~real2sim.asset.export.writers.ASSET_FORMATS`
    ("urdf", "sdf", "mjcf", "usd"); model.urdf and model_portable.urdf are written whatever it says."""
    seed: int = 0
    """Seed of every random draw of the build (floater and inertia samples, fits, decompositions,
    fidelity samples): one configuration builds the same asset."""
    device: str = "cpu"
    """Torch device of the primitive fits ("cpu", "cuda", "cuda:1", ...); decompositions run on the CPU."""
    contact: ContactProperties = field(default_factory=ContactProperties)
    """Contact material written into every model file (:class:`~real2sim.formats.contact.ContactProperties`)."""
    mujoco: MujocoConfig = field(default_factory=MujocoConfig)
    """MuJoCo's settings written into every ``scene.xml`` (the world's options, and every geom's contact
    default; ``model.xml`` keeps MuJoCo's defaults for the scenes that include it): the ones the evaluation
    measured closest to the Drake reference
    (:class:`~real2sim.formats.contact.MujocoConfig`; why: docs/design-notes/evaluate.md#mujoco-contact-settings)."""
    fit_config: object | None = None
    """Settings of the primitive fits (:class:`real2sim.collision.fit.config.FitConfig`); None: its
    defaults, the paper's settings."""
    coacd_config: object | None = None
    """Settings of the ``coacd`` baseline (:class:`real2sim.collision.decomposition.CoacdConfig`);
    None: its defaults, the paper's settings."""
    vhacd_config: object | None = None
    """Settings of the ``vhacd`` baseline (:class:`real2sim.collision.decomposition.VhacdConfig`);
    None: its defaults, the paper's settings."""
    sdf_cache_dir: Path | str | None = None
    """Folder where signed-distance samples are cached across builds ("auto": $REAL2SIM_CACHE or
    ~/.cache/real2sim). None: cached for this build only, so several primitive SPECs of one build
    sample the mesh once."""
    given_properties: PhysicalProperties | None = None
    """Mass, CoM and inertia measured rather than assumed (`real2sim identify`, ``--properties``), in
    the frame :attr:`given_properties_frame` names; their CoM must lie inside the object
    (:func:`~real2sim.asset.checks.check_given_com`). None: uniform density."""
    given_properties_frame: str = "asset"
    """Frame of :attr:`given_properties`: "mesh" (:data:`~real2sim.formats.physical.MESH_FRAME`, the
    input mesh's frame, what `real2sim identify` writes) or "asset" (the asset frame)."""
    given_properties_source: str = ""
    """Path of the file :attr:`given_properties` were read from: named in messages and in
    asset_config.json, and declared as an input the output may not touch. "": none (given in code)."""
    fit_workers: int | None = None
    """Processes that fit the collision SPECs side by side, >= 1, at most one per SPEC and one per thread
    this process may use; None: that many when the fits are long (``FitConfig.max_iterations`` >= 500),
    else 1 (:func:`real2sim.asset.fits.fit_processes`). It changes results only by the rounding of sums
    split over other threads, so asset_config.json does not record it (why:
    docs/design-notes/asset.md#fits-side-by-side)."""
    fill_cavities_m: float | None = None
    """None, or the radius (m, > 0) of a ball the collision fits see the solid closed with
    (:func:`real2sim.geometry.envelope.filled_envelope`): a cup's cavity or a handle's hole narrower
    than the ball is filled before any SPEC is fitted or decomposed. For pushing, tilting and placing,
    where nothing enters them; not for grasping by a rim. Mass properties, the visual and the fidelity
    reference stay those of the true solid."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass_kg) and self.mass_kg > 0):
            raise UserInputError(f"mass must be a finite number > 0 kg, got {self.mass_kg}")
        if not self.specs:
            raise UserInputError("no collision SPEC given (e.g. --collision cylinders:10)")
        given = self.given_properties
        if given is not None and abs(self.mass_kg - given.mass_kg) > mass_agreement_kg(given):
            se = given.mass_standard_error_kg
            raise UserInputError(
                f"--mass-kg {self.mass_kg:g} kg disagrees with the properties' mass {given.mass_kg:g} kg: they differ by "
                f"{abs(self.mass_kg - given.mass_kg):.3g} kg, more than {mass_agreement_kg(given):.3g} kg (the larger of "
                f"3 x its standard error, {'%.3g kg' % se if se is not None else 'none given'}, and "
                f"{100 * MASS_AGREEMENT_RTOL:g} % of it); give one of them")
        if self.fill_cavities_m is not None and not (np.isfinite(self.fill_cavities_m) and self.fill_cavities_m > 0):
            raise UserInputError(f"--fill-cavities-m must be a radius > 0 m, got {self.fill_cavities_m}")
        if self.fit_workers is not None and not (isinstance(self.fit_workers, int) and self.fit_workers >= 1):
            raise UserInputError(f"--fit-workers must be a whole number >= 1, got {self.fit_workers}")
        names = [s.name for s in self.specs]
        if len(set(names)) != len(names):
            raise UserInputError(f"a collision SPEC is given twice: {names}")
        from real2sim.asset.export.writers import ASSET_FORMATS

        bad = set(self.formats) - set(ASSET_FORMATS)
        if bad:
            raise UserInputError(f"unknown --format {sorted(bad)}; known: {', '.join(ASSET_FORMATS)}")


def _software_versions() -> dict[str, str]:
    from importlib import metadata

    versions = {}
    for package in ("real2sim", "numpy", "torch", "trimesh", "drake", "coacd", "vhacdx", "manifold3d", "libigl"):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def config_record(config: AssetConfig) -> dict:
    """What asset_config.json holds: every setting of the build, the stages' effective defaults
    included, and the package versions (so that an asset can be rebuilt and compared)."""
    import platform

    from real2sim.collision.decomposition import CoacdConfig, VhacdConfig
    from real2sim.collision.fit.config import FitConfig

    return {
        "mass_kg": config.mass_kg,
        "collision": [spec.text for spec in config.specs],
        "flat_bottom": config.flat_bottom,
        "support_height_m": config.support_height_m,
        "pca_up": config.pca_up,
        "mesh_units": config.mesh_units,
        "formats": list(config.formats),
        "seed": config.seed,
        "device": config.device,
        "contact": config.contact,
        "mujoco": config.mujoco,
        "fit_config": config.fit_config or FitConfig(),
        "fill_cavities_m": config.fill_cavities_m,
        "coacd_config": config.coacd_config or CoacdConfig(),
        "vhacd_config": config.vhacd_config or VhacdConfig(),
        "properties": ({"source": config.given_properties_source, "frame": config.given_properties_frame,
                        "method": config.given_properties.method} if config.given_properties else "uniform density"),
        "software": {"python": platform.python_version(), **_software_versions()},
    }
