"""The asset stage: an object mesh in, a simulation asset folder out.

mesh -> (flat bottom) -> canonical pose -> inertia -> one collision
representation per SPEC -> URDF/SDFormat + fidelity report. The folder layout
is the contract of DESIGN.md ("Files on disk"):

    ASSETDIR/
      asset_config.json          the configuration it was built with (contact, fit, seed, versions)
      physical_properties.json   mass_kg, com_m, inertia_kg_m2 (about the CoM, asset axes)
      canonical_transform.json   4x4 from the input mesh frame to the asset frame
      visual/model.obj           textured visual mesh with normals (asset frame)
      <representation>/          model.urdf, [model.sdf], [model.xml for MuJoCo], collision.json, fit_report.json
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
import numpy as np
import trimesh

from real2sim.asset.reuse import reuse_collision, reusable_representations
from real2sim.formats.asset_config import ASSET_CONFIG_NAME, write_asset_config
from real2sim.formats.collision import CollisionGeometry, write_collision_json
from real2sim.formats.contact import ContactProperties
from real2sim.plumbing.errors import UserInputError
from real2sim.geometry.mesh_io import MAX_EXTENT_M, check_object_size, export_textured_mesh, load_mesh, validate_mesh  # noqa: F401
from real2sim.plumbing.digests import file_sha256
from real2sim.plumbing.outputs import atomic_output_dir
from real2sim.formats.physical import MESH_FRAME, PhysicalProperties, write_physical_properties
from real2sim.plumbing.progress import ProgressFn, null_progress, prefixed
from real2sim.formats.spec import CollisionSpec

VISUAL_RELPATH = "visual/model.obj"

#: Largest object per resolution hint: Drake meshes compliant curved primitives with edges about
#: the hint long. Measured (Drake 1.51, compliant sphere): 100 hints across took 0.4 GB and 7 s
#: to mesh, 300 hints 1.4 GB and 41 s; past that a single primitive costs gigabytes.
MAX_EXTENT_PER_RESOLUTION_HINT = 300.0
#: How far below the mesh the support plane may lie, as a fraction of the mesh's height:
#: a reconstruction's bottom may stop a little above the table.
SUPPORT_BELOW_TOLERANCE = 0.05
#: How far outside the object's axis-aligned bounds a given centre of mass may lie, as a fraction of
#: the object's largest extent: room for a reconstruction that misses a little of the object and an
#: identified CoM's millimetres of error; a file in another frame or unit lies far further out.
COM_MARGIN_FRACTION = 0.1
#: Relative tolerance of ``--mass`` against a properties file's mass when the file gives no standard
#: error of it (or a smaller one): the rounding of a mass typed to three or four digits.
MASS_AGREEMENT_RTOL = 1e-3


def mass_agreement_kg(given: PhysicalProperties) -> float:
    """How far ``--mass`` may lie from ``given.mass_kg`` and still agree with it: the larger of 3 x the
    file's standard error of the mass (when it gives one) and :data:`MASS_AGREEMENT_RTOL` of the mass."""
    return max(3.0 * (given.mass_standard_error_kg or 0.0), MASS_AGREEMENT_RTOL * given.mass_kg)


def check_given_com(config: AssetConfig, vertices: np.ndarray, label: str) -> None:
    """Refuse given properties whose centre of mass lies outside the object: beyond the axis-aligned
    bounds of ``vertices`` (the object in the frame the properties are given in, m) grown on every side by
    :data:`COM_MARGIN_FRACTION` of the bounds' largest side. UserInputError naming ``--properties``."""
    if config.given_properties is None:
        return
    vertices = np.asarray(vertices, dtype=float)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    margin = COM_MARGIN_FRACTION * float((hi - lo).max())
    com = np.asarray(config.given_properties.com_m, dtype=float)
    if np.all(com >= lo - margin) and np.all(com <= hi + margin):
        return
    frame = "the mesh's frame" if config.given_properties_frame == MESH_FRAME else "the asset frame"

    def shown(v: np.ndarray) -> str:
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"

    raise UserInputError(
        f"--properties {config.given_properties_source or '(given properties)'}: the centre of mass "
        f"{shown(com)} m ({frame}) lies outside {label}, whose bounds {shown(lo)} .. {shown(hi)} m grown by "
        f"{100 * COM_MARGIN_FRACTION:g} % of its largest extent ({margin:.3g} m) must hold it: a file in another "
        "frame or unit?")


def support_below_mesh(bottom_m: float, top_m: float, support_m: float) -> bool:
    """Whether a support plane at height ``support_m`` lies below a mesh spanning ``bottom_m`` ..
    ``top_m`` (same frame, +z up) by more than :data:`SUPPORT_BELOW_TOLERANCE` of its height: there
    is nothing to crop there and no bottom to close."""
    return support_m < bottom_m - SUPPORT_BELOW_TOLERANCE * (top_m - bottom_m)


@dataclass(frozen=True)
class AssetConfig:
    """Everything ``real2sim asset`` needs besides the mesh and the output folder.

    support_height_m: height of the table plane in the input mesh frame (+z up),
        used by ``flat_bottom``; a capture stands the object on z = 0.
    mesh_units: the units the mesh file's coordinates are in (m, cm, mm, in); everything
        else, ``support_height_m`` included, is in metres.
    keep_up: keep the input's +z as the asset's +z (PCA only picks x in the
        horizontal plane); without it the longest principal axis becomes +z, as the
        paper does, which tilts squat objects such as a mug.
    fit_config / coacd_config / vhacd_config: None means each stage's defaults
        (the paper's settings, documented in those modules).
    given_properties: mass, CoM and inertia measured rather than assumed (`real2sim identify`,
        ``--properties``), in the input mesh's frame when ``given_properties_frame`` is "mesh", else
        in the asset frame; ``mass_kg`` must agree with their mass within :func:`mass_agreement_kg`, and
        their CoM lie inside the object (:func:`check_given_com`). None: uniform density.
    sdf_cache_dir: where signed-distance samples are cached across builds ("auto":
        $REAL2SIM_CACHE or ~/.cache/real2sim); None caches them for this build only,
        so several primitive SPECs of one build sample the mesh once.
    fill_cavities_m: None, or the radius (m) of a ball the collision fits see the solid closed with
        (:func:`real2sim.geometry.envelope.filled_envelope`): a cup's cavity or a handle's hole
        narrower than the ball is filled before any SPEC is fitted or decomposed. For pushing,
        tilting and placing, where nothing enters them; not for grasping by a rim. Mass
        properties, the visual and the fidelity reference stay those of the true solid.
    """

    mass_kg: float
    specs: tuple[CollisionSpec, ...]
    flat_bottom: bool = False
    support_height_m: float = 0.0
    keep_up: bool = False
    mesh_units: str = "m"
    formats: tuple[str, ...] = ("urdf",)
    seed: int = 0
    device: str = "cpu"
    contact: ContactProperties = field(default_factory=ContactProperties)
    fit_config: object | None = None
    coacd_config: object | None = None
    vhacd_config: object | None = None
    sdf_cache_dir: Path | str | None = None
    given_properties: PhysicalProperties | None = None
    given_properties_frame: str = "asset"
    given_properties_source: str = ""
    fill_cavities_m: float | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass_kg) and self.mass_kg > 0):
            raise UserInputError(f"mass must be a finite number > 0 kg, got {self.mass_kg}")
        if not self.specs:
            raise UserInputError("no collision SPEC given (e.g. --collision cylinders:10)")
        given = self.given_properties
        if given is not None and abs(self.mass_kg - given.mass_kg) > mass_agreement_kg(given):
            se = given.mass_standard_error_kg
            raise UserInputError(
                f"--mass {self.mass_kg:g} kg disagrees with the properties' mass {given.mass_kg:g} kg: they differ by "
                f"{abs(self.mass_kg - given.mass_kg):.3g} kg, more than {mass_agreement_kg(given):.3g} kg (the larger of "
                f"3 x its standard error, {'%.3g kg' % se if se is not None else 'none given'}, and "
                f"{100 * MASS_AGREEMENT_RTOL:g} % of it); give one of them")
        if self.fill_cavities_m is not None and not (np.isfinite(self.fill_cavities_m) and self.fill_cavities_m > 0):
            raise UserInputError(f"--fill-cavities must be a radius > 0 m, got {self.fill_cavities_m}")
        names = [s.name for s in self.specs]
        if len(set(names)) != len(names):
            raise UserInputError(f"a collision SPEC is given twice: {names}")
        from real2sim.asset.export.writers import ASSET_FORMATS

        bad = set(self.formats) - set(ASSET_FORMATS)
        if bad:
            raise UserInputError(f"unknown --format {sorted(bad)}; known: {', '.join(ASSET_FORMATS)}")


@dataclass(frozen=True)
class RepresentationResult:
    name: str
    urdf_path: Path
    fit_report: dict


@dataclass(frozen=True)
class AssetResult:
    asset_dir: Path
    physical: PhysicalProperties
    canonical_transform: np.ndarray
    representations: tuple[RepresentationResult, ...]


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
        "keep_up": config.keep_up,
        "mesh_units": config.mesh_units,
        "formats": list(config.formats),
        "seed": config.seed,
        "device": config.device,
        "contact": config.contact,
        "fit_config": config.fit_config or FitConfig(),
        "fill_cavities_m": config.fill_cavities_m,
        "coacd_config": config.coacd_config or CoacdConfig(),
        "vhacd_config": config.vhacd_config or VhacdConfig(),
        "properties": ({"source": config.given_properties_source, "frame": config.given_properties_frame,
                        "method": config.given_properties.method} if config.given_properties else "uniform density"),
        "software": {"python": platform.python_version(), **_software_versions()},
    }


def given_in_asset_frame(config: AssetConfig, transform: np.ndarray) -> PhysicalProperties:
    """``config.given_properties`` in the asset frame (``transform``: asset from input mesh)."""
    from real2sim.formats.physical import moved_properties

    given = config.given_properties
    method = f"{given.method} [given: {config.given_properties_source or 'properties'}]"
    if config.given_properties_frame == MESH_FRAME:
        return moved_properties(given, transform, method)
    return moved_properties(given, np.eye(4), method)


def check_mesh_for_config(mesh: trimesh.Trimesh, config: AssetConfig, label: str = "mesh") -> None:
    """Refuse, before any work, a mesh this configuration cannot turn into a usable asset.

    UserInputError (one line): an object smaller than :data:`MIN_EXTENT_M` or larger than :data:`MAX_EXTENT_M`
    after ``mesh_units`` (the message names the units that fit); an object more than
    :data:`MAX_EXTENT_PER_RESOLUTION_HINT` resolution hints across when its shapes are
    hydroelastic (Drake would mesh them with millions of elements); with ``flat_bottom``, a
    support plane that is not finite, that leaves nothing of the mesh above it, or that lies
    below the mesh by more than :data:`SUPPORT_BELOW_TOLERANCE` of its height (nothing to crop,
    no bottom to close there).
    """
    vertices = np.asarray(mesh.vertices, dtype=float)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    extent = check_object_size(mesh, label, config.mesh_units)
    hint = config.contact.resolution_hint_m
    if config.contact.hydroelastic != "none" and extent > MAX_EXTENT_PER_RESOLUTION_HINT * hint:
        raise UserInputError(f"{label} is {extent:.4g} m across, over {MAX_EXTENT_PER_RESOLUTION_HINT:g} x "
                             f"--resolution-hint {hint:g} m = {MAX_EXTENT_PER_RESOLUTION_HINT * hint:.4g} m: Drake would "
                             f"mesh its shapes with millions of elements; use --resolution-hint "
                             f">= {extent / MAX_EXTENT_PER_RESOLUTION_HINT:.3g}")
    if config.fill_cavities_m is not None:
        from real2sim.geometry.envelope import check_fill_radius

        check_fill_radius(config.fill_cavities_m, extent, label)
    if config.flat_bottom:
        height = config.support_height_m
        bottom, top = float(lo[2]), float(hi[2])
        if not np.isfinite(height):
            raise UserInputError(f"--support-height must be a finite number of metres, got {height}")
        if height >= top:
            raise UserInputError(f"--support-height {height:g} m leaves nothing of {label} above it "
                                 f"(the mesh spans z = {bottom:.4g} .. {top:.4g} m)")
        if support_below_mesh(bottom, top, height):
            raise UserInputError(f"--support-height {height:g} m lies {bottom - height:.4g} m below {label} "
                                 f"(the mesh spans z = {bottom:.4g} .. {top:.4g} m): nothing to crop and no bottom to "
                                 "close there; give the table's height in the mesh frame")


def geometry_only(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh's surface with coincident vertices merged (UV seams closed), no visuals."""
    solid = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=True)
    solid.remove_unreferenced_vertices()
    return solid


def build_collision(
    mesh_canonical: trimesh.Trimesh, spec: CollisionSpec, rep_dir: Path, config: AssetConfig,
    sdf_cache_dir: Path | str | None = None, progress: ProgressFn | None = None,
) -> tuple[CollisionGeometry, dict]:
    """One collision representation of the canonical mesh, with its fitting report.

    Baselines and superquadric fits write their convex pieces under ``rep_dir/pieces``;
    a primitive fit reports its SDF sampling and iterations to ``progress``. CoACD and V-HACD
    decompose the closed solid the mesh bounds (:func:`real2sim.asset.bottom.closed_solid`: an open
    scan is remeshed closed first, and ``input_closed_by`` in the report says so); primitive fits
    read the mesh's winding number, which holes do not upset.
    """
    start = time.perf_counter()
    if spec.baseline is not None:
        from real2sim.collision.decomposition import decompose

        closed_by = None
        if spec.baseline in ("coacd", "vhacd"):
            from real2sim.asset.bottom import closed_solid

            mesh_canonical = closed_solid(mesh_canonical)
            closed_by = mesh_canonical.metadata["closed_by"]
            if closed_by != "as is" and progress is not None:
                progress(f"the mesh is not closed: {spec.baseline} decomposes it remeshed closed", 0, 0)
        kwargs = {}
        if spec.baseline == "coacd" and config.coacd_config is not None:
            kwargs["coacd_config"] = config.coacd_config
        if spec.baseline == "vhacd" and config.vhacd_config is not None:
            kwargs["vhacd_config"] = config.vhacd_config
        geometry = decompose(mesh_canonical, spec.baseline, rep_dir, seed=config.seed, **kwargs)
        report = {"method": spec.baseline, "final_loss": None, "device": "cpu"}
        if closed_by is not None:
            report["input_closed_by"] = closed_by
    else:
        from real2sim.collision.fit.config import FitConfig
        from real2sim.collision.fit.stage import fit_collision

        geometry, report = fit_collision(
            mesh_canonical,
            spec,
            fit_config=config.fit_config or FitConfig(),
            cache_dir=sdf_cache_dir,
            rep_dir=rep_dir,
            device=config.device,
            seed=config.seed,
            progress=progress,
        )
        report = dict(report)
        report.setdefault("method", "primitive fit (paper IV-C3)")
    report["fit_seconds"] = round(time.perf_counter() - start, 3)
    return geometry, report


def build_asset(
    mesh_path: Path | str,
    out_dir: Path | str,
    config: AssetConfig,
    *,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    reuse_from: Path | str | None = None,
) -> AssetResult:
    """Build the asset folder ``out_dir`` from the mesh at ``mesh_path`` (metres).

    The folder appears whole or not at all. ``progress`` receives one message per step
    (``total`` 0) and the counted work of each primitive fit. ``reuse_from``: an earlier asset
    folder; a representation of the same SPEC whose geometry settings are unchanged there (the
    same mesh bytes and every setting but mass, contact, formats and the list of SPECs, see
    :func:`reusable_representations`) is copied instead of refitted, its model files rewritten
    with this build's mass properties, contact and formats.
    """
    say = progress or null_progress
    out_dir = Path(out_dir)
    mesh = load_mesh(mesh_path, config.mesh_units)
    solid = geometry_only(mesh)
    validate_mesh(solid, str(mesh_path))
    check_mesh_for_config(solid, config, str(mesh_path))
    if config.given_properties_frame == MESH_FRAME:
        check_given_com(config, solid.vertices, str(mesh_path))

    from real2sim.asset.canonical import canonical_transform
    from real2sim.asset.inertia import estimate_physical_properties

    read = [mesh_path, *([config.given_properties_source] if config.given_properties_source else [])]
    with atomic_output_dir(out_dir, overwrite=overwrite, inputs=read, made_by="real2sim asset") as tmp:
        write_asset_config({**config_record(config), "input_mesh_sha256": file_sha256(Path(mesh_path))},
                           tmp / ASSET_CONFIG_NAME)
        reusable = reusable_representations(reuse_from, tmp / ASSET_CONFIG_NAME) if reuse_from else {}
        if config.flat_bottom:
            from real2sim.asset.bottom import close_flat_bottom

            say(f"closing a flat bottom at z = {config.support_height_m} m (input frame)", 0, 0)
            solid = close_flat_bottom(solid, support_height_m=config.support_height_m)

        from real2sim.asset.floaters import without_floaters

        # inertia drops debris apart from the object; collision geometry and the canonical pose must too
        solid = without_floaters(solid, seed=config.seed)
        if solid.metadata["floater_faces_dropped"]:
            say(f"dropped {solid.metadata['floater_faces_dropped']} faces of debris apart from the object "
                "(under 1 % of its surface)", 0, 0)
        transform = canonical_transform(solid, up_axis=(0.0, 0.0, 1.0) if config.keep_up else None)
        solid = solid.copy()
        solid.apply_transform(transform)
        if config.given_properties_frame != MESH_FRAME:
            check_given_com(config, solid.vertices, f"{mesh_path} in the asset frame")
        visual = mesh.copy()
        visual.apply_transform(transform)
        (tmp / "canonical_transform.json").write_text(
            json.dumps(
                {
                    "T_asset_from_input": transform.tolist(),
                    "description": "4x4 homogeneous transform: p_asset = T @ p_input (metres). "
                    "Asset frame: centred, principal axis +z, minor axis +x.",
                },
                indent=1,
            )
        )
        export_textured_mesh(visual, tmp / VISUAL_RELPATH)
        # The closed geometry the collision and inertia stages saw: the reference for fidelity.
        solid.export(tmp / "visual" / "collision_reference.obj")

        say(f"estimating inertia for {config.mass_kg} kg (uniform density)", 0, 0)
        props = estimate_physical_properties(solid, config.mass_kg, seed=config.seed)
        extra = None
        if config.given_properties is not None:
            uniform, props = props, given_in_asset_frame(config, transform)
            extra = {"source": config.given_properties_source, "uniform_density": uniform.to_json()}
        write_physical_properties(props, tmp / "physical_properties.json", extra)
        results = _write_representations(solid, props, tmp, out_dir, config, say, reusable)

    return AssetResult(Path(out_dir), props, transform, tuple(results))


def _write_representations(solid: trimesh.Trimesh, props: PhysicalProperties, tmp: Path, out_dir: Path,
                           config: AssetConfig, say: ProgressFn, reusable: dict[str, Path] | None = None
                           ) -> list[RepresentationResult]:
    """Each SPEC's folder in ``tmp``: collision.json, the model files, fit_report.json; a SPEC in
    ``reusable`` is copied from there (:func:`reusable_representations`) instead of fitted."""
    from real2sim.asset.export.writers import write_representation
    from real2sim.geometry.fidelity import measure_fidelity

    results = []
    build_cache = tmp / ".sdf_cache"
    sdf_cache = config.sdf_cache_dir if config.sdf_cache_dir is not None else build_cache
    fitted_solid, filled = solid, None
    if config.fill_cavities_m is not None and any(spec.text not in (reusable or {}) for spec in config.specs):
        from real2sim.geometry.envelope import filled_envelope

        say(f"filling cavities narrower than a {config.fill_cavities_m:g} m ball for the collision fits", 0, 0)
        fitted_solid = filled_envelope(solid, config.fill_cavities_m)
        filled = {"fitted_to": f"the solid closed by a {config.fill_cavities_m:g} m ball (--fill-cavities)",
                  "filled_volume_m3": float(fitted_solid.volume - solid.volume)}
        say(f"filled {1e6 * filled['filled_volume_m3']:.1f} cm^3 ({100 * filled['filled_volume_m3'] / solid.volume:.0f} % "
            "of the solid)", 0, 0)
    for spec in config.specs:
        rep_dir = tmp / spec.name
        rep_dir.mkdir()
        if spec.text in (reusable or {}):
            say(f"collision {spec.text}: unchanged, reused", 0, 0)
            geometry, report = reuse_collision(reusable[spec.text], rep_dir)
        else:
            say(f"collision {spec.text}: fitting", 0, 0)
            geometry, report = build_collision(fitted_solid, spec, rep_dir, config, sdf_cache,
                                               progress=prefixed(say, f"collision {spec.text}"))
            report = {**report, **(filled or {})}
            write_collision_json(geometry, rep_dir / "collision.json")
        write_representation(
            rep_dir, geometry, props, config.contact, visual_mesh_relpath=f"../{VISUAL_RELPATH}",
            formats=config.formats, model_name=spec.name,
        )
        if "reused" not in report:
            fidelity = measure_fidelity(solid, geometry, rep_dir, seed=config.seed)
            if filled is not None:  # how well it fits what it was fitted to, beside the true solid
                to_filled = measure_fidelity(fitted_solid, geometry, rep_dir, seed=config.seed)
                fidelity["filled_solid"] = {"iou": to_filled["iou"], "chamfer_mm": to_filled["chamfer_mm"]}
            report = {
                "spec": spec.text,
                "num_primitives": len(geometry.shapes),
                **fidelity,
                **report,
            }
        if "mjcf" in config.formats:
            from real2sim.asset.export.mjcf import mjcf_notes

            notes = mjcf_notes(geometry)
            if notes:
                report["mjcf_notes"] = notes
            for note in notes:
                say(f"warning: {note}", 0, 0)
        (rep_dir / "fit_report.json").write_text(json.dumps(report, indent=1, default=float))
        took = "fitted by an earlier build" if "reused" in report else f"{report['fit_seconds']:.1f} s"
        say(
            f"collision {spec.text}: {len(geometry.shapes)} pieces, IoU {report.get('iou', float('nan')):.3f}, "
            f"Chamfer {report.get('chamfer_mm', float('nan')):.2f} mm"
            + (f" (filled solid: IoU {report['filled_solid']['iou']:.3f}, Chamfer "
               f"{report['filled_solid']['chamfer_mm']:.2f} mm)" if "filled_solid" in report else "")
            + f", {took}", 0, 0
        )
        results.append(RepresentationResult(spec.name, out_dir / spec.name / "model.urdf", report))
    shutil.rmtree(build_cache, ignore_errors=True)
    return results


def rewrite_models(asset_dir: Path | str, contact: ContactProperties, formats: tuple[str, ...] = ("urdf",)) -> list[Path]:
    """Re-write every representation's model files of an asset with new contact properties.

    Geometry (collision.json) and mass properties (physical_properties.json) are
    kept: changing friction, stiffness or hydroelastic settings needs no refit.
    asset_config.json records the new material, which the evaluation's reference reads.
    Returns the URDF paths written.
    """
    from real2sim.asset.export.writers import write_representation
    from real2sim.formats.collision import read_collision_json
    from real2sim.formats.physical import read_physical_properties

    asset_dir = Path(asset_dir)
    props = read_physical_properties(asset_dir / "physical_properties.json")
    written = []
    for collision_json in sorted(asset_dir.glob("*/collision.json")):
        rep_dir = collision_json.parent
        write_representation(rep_dir, read_collision_json(collision_json), props, contact,
                             visual_mesh_relpath=f"../{VISUAL_RELPATH}", formats=formats, model_name=rep_dir.name)
        written.append(rep_dir / "model.urdf")
    config_path = asset_dir / ASSET_CONFIG_NAME
    if config_path.is_file():
        record = json.loads(config_path.read_text())
        write_asset_config({**record, "contact": contact}, config_path)
    return written

