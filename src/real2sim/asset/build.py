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
      preview.png                the visual mesh beside each representation's collision geometry
      README.md                  what made the folder, from what, its mass properties, the file per simulator,
                                 the fit of each representation (real2sim.asset.readme)
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
import numpy as np
import trimesh

from real2sim.asset.checks import check_given_com, check_mesh_for_config
from real2sim.asset.config import AssetConfig, config_record
from real2sim.asset.fits import Fitted, fit_all
from real2sim.asset.reuse import reuse_collision, reusable_representations
from real2sim.formats.asset_config import ASSET_CONFIG_NAME, write_asset_config
from real2sim.formats.contact import ContactProperties, MujocoConfig
from real2sim.geometry.mesh_io import export_textured_mesh, load_mesh, validate_mesh
from real2sim.plumbing.digests import file_sha256
from real2sim.plumbing.outputs import atomic_output_dir
from real2sim.formats.physical import MESH_FRAME, PhysicalProperties, write_physical_properties
from real2sim.plumbing.progress import ProgressFn, null_progress

VISUAL_RELPATH = "visual/model.obj"


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


def given_in_asset_frame(config: AssetConfig, transform: np.ndarray) -> PhysicalProperties:
    """``config.given_properties`` in the asset frame (``transform``: asset from input mesh)."""
    from real2sim.formats.physical import moved_properties

    given = config.given_properties
    method = f"{given.method} [given: {config.given_properties_source or 'properties'}]"
    if config.given_properties_frame == MESH_FRAME:
        return moved_properties(given, transform, method)
    return moved_properties(given, np.eye(4), method)


def geometry_only(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh's surface with coincident vertices merged (UV seams closed), no visuals."""
    solid = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=True)
    solid.remove_unreferenced_vertices()
    return solid


def build_asset(
    mesh_path: Path | str,
    out_dir: Path | str,
    config: AssetConfig,
    *,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    reuse_from: Path | str | None = None,
    command: str | None = None,
) -> AssetResult:
    """Build the asset folder ``out_dir`` from the mesh at ``mesh_path`` (metres).

    The folder appears whole or not at all. ``progress`` receives one message per step
    (``total`` 0) and the counted work of each primitive fit. ``reuse_from``: an earlier asset
    folder; a representation of the same SPEC whose geometry settings are unchanged there (the
    same mesh bytes and every setting but mass, contact, formats and the list of SPECs, see
    :func:`reusable_representations`) is copied instead of refitted, its model files rewritten
    with this build's mass properties, contact and formats. ``command``: the command line or call
    that asked for the build, for the folder's README.md (default: this process's ``real2sim`` command
    line, or "a call from Python").
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
        transform = canonical_transform(solid, up_axis=None if config.pca_up else (0.0, 0.0, 1.0))
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
        _write_readme_and_preview(tmp, [r.name for r in results], str(mesh_path), command, say)

    return AssetResult(Path(out_dir), props, transform, tuple(results))


def _write_readme_and_preview(tmp: Path, names: list[str], mesh: str, command: str | None, say: ProgressFn) -> None:
    """preview.png and README.md into the staged folder ``tmp``, after everything they describe."""
    from real2sim.asset.readme import PREVIEW_NAME, PREVIEW_PANEL_PX, invocation, write_asset_readme
    from real2sim.report.preview import write_asset_preview

    say("drawing preview.png, writing README.md", 0, 0)
    if not write_asset_preview(tmp, tmp / PREVIEW_NAME, names, panel_px=PREVIEW_PANEL_PX):
        say("warning: no preview.png: the visual mesh could not be read back", 0, 0)
    write_asset_readme(tmp, mesh=mesh, command=command or invocation())


def _write_representations(solid: trimesh.Trimesh, props: PhysicalProperties, tmp: Path, out_dir: Path,
                           config: AssetConfig, say: ProgressFn, reusable: dict[str, Path] | None = None
                           ) -> list[RepresentationResult]:
    """Each SPEC's folder in ``tmp``: collision.json, the model files, fit_report.json; a SPEC in
    ``reusable`` is copied from there (:func:`reusable_representations`) instead of fitted."""
    from real2sim.asset.export.mjcf import mjcf_notes
    from real2sim.asset.export.writers import write_representation

    build_cache = tmp / ".sdf_cache"
    sdf_cache = config.sdf_cache_dir if config.sdf_cache_dir is not None else build_cache
    fitted_solid, filled = solid, None
    if config.fill_cavities_m is not None and any(spec.text not in (reusable or {}) for spec in config.specs):
        from real2sim.geometry.envelope import filled_envelope

        say(f"filling cavities narrower than a {config.fill_cavities_m:g} m ball for the collision fits", 0, 0)
        fitted_solid = filled_envelope(solid, config.fill_cavities_m)
        filled = {"fitted_to": f"the solid closed by a {config.fill_cavities_m:g} m ball (--fill-cavities-m)",
                  "filled_volume_m3": float(fitted_solid.volume - solid.volume)}
        say(f"filled {1e6 * filled['filled_volume_m3']:.1f} cm^3 ({100 * filled['filled_volume_m3'] / solid.volume:.0f} % "
            "of the solid)", 0, 0)
    to_fit = [spec for spec in config.specs if spec.text not in (reusable or {})]
    for spec in config.specs:
        (tmp / spec.name).mkdir()
    written: dict[str, RepresentationResult] = {}

    def write(spec, fitted: Fitted | None) -> None:
        """One representation's files, as soon as its fit is done (``fitted`` None: reused)."""
        rep_dir = tmp / spec.name
        if fitted is None:
            say(f"collision {spec.text}: unchanged, reused", 0, 0)
            geometry, report = reuse_collision(reusable[spec.text], rep_dir)
        else:
            geometry, report = fitted.geometry, {**fitted.report, **(filled or {})}
        say(f"collision {spec.text}: writing {', '.join(config.formats)}", 0, 0)
        write_representation(
            rep_dir, geometry, props, config.contact, visual_mesh_relpath=f"../{VISUAL_RELPATH}",
            formats=config.formats, model_name=spec.name, mujoco=config.mujoco,
        )
        if "reused" not in report:
            report = {
                "spec": spec.text,
                "num_primitives": len(geometry.shapes),
                **fitted.fidelity,
                **report,
            }
        if "mjcf" in config.formats:
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
        written[spec.text] = RepresentationResult(spec.name, out_dir / spec.name / "model.urdf", report)

    for spec in config.specs:
        if spec.text in (reusable or {}):
            write(spec, None)
    fit_all(solid, fitted_solid, to_fit, tmp, config, sdf_cache, progress=say, on_fitted=write)
    results = [written[spec.text] for spec in config.specs]
    shutil.rmtree(build_cache, ignore_errors=True)
    return results


def rewrite_models(asset_dir: Path | str, contact: ContactProperties, formats: tuple[str, ...] = ("urdf",)) -> list[Path]:
    """Re-write every representation's model files of an asset with new contact properties.

    Geometry (collision.json) and mass properties (physical_properties.json) are
    kept: changing friction, stiffness or hydroelastic settings needs no refit.
    asset_config.json records the new material, which the evaluation's reference reads;
    scene.xml keeps the MuJoCo settings asset_config.json records (the defaults if none).
    Returns the URDF paths written.
    """
    from real2sim.asset.export.writers import write_representation
    from real2sim.formats.collision import read_collision_json
    from real2sim.formats.physical import read_physical_properties

    asset_dir = Path(asset_dir)
    props = read_physical_properties(asset_dir / "physical_properties.json")
    config_path = asset_dir / ASSET_CONFIG_NAME
    record = json.loads(config_path.read_text()) if config_path.is_file() else None
    mujoco = MujocoConfig.from_record(record.get("mujoco", {})) if record else MujocoConfig()
    written = []
    for collision_json in sorted(asset_dir.glob("*/collision.json")):
        rep_dir = collision_json.parent
        write_representation(rep_dir, read_collision_json(collision_json), props, contact,
                             visual_mesh_relpath=f"../{VISUAL_RELPATH}", formats=formats, model_name=rep_dir.name,
                             mujoco=mujoco)
        written.append(rep_dir / "model.urdf")
    if record is not None:
        write_asset_config({**record, "contact": contact}, config_path)
    return written

