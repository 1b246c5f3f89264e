"""The reconstruct stage: posed, masked images -> textured mesh in the dataset's world frame.

``field`` (default): visual hull to bound and carve space, a voxel radiance field
trained on the masked images, a surface extracted from it (``density``: marching
cubes on the density, the default; ``tsdf``: the paper's TSDF fusion of rendered
depth), clean-up, texture from the field. ``hull``: the visual hull's surface,
textured from the images; the baseline that shows what the field buys.

Held-out views (every 10th) are never used to build anything; they give the
PSNR of the field and of the textured mesh; with the field's pose refinement their
poses are first fitted to the trained field, which stays frozen (they have no
correction of their own otherwise; the training views use their corrected poses). With ``DATASET/ground_truth/`` the
mesh is compared with the true object (:mod:`real2sim.reconstruct.truth`).
"""

from __future__ import annotations

import resource
import sys
import time
import warnings
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Iterator

import numpy as np
import torch
import trimesh

from real2sim.formats.dataset import has_table_plane, read_dataset, stated_support_z_m
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn
from real2sim.reconstruct.config import ReconstructConfig, carving_after_alignment, field_poses_after_alignment
from real2sim.multiview.views import MIN_VIEWS, PosedViews, held_out_split, load_views, refined_mask_edges


@dataclass(frozen=True)
class Reconstruction:
    """A textured mesh (world frame, metres), the stage's report (JSON-ready), and the trained
    field (``field`` backend; None otherwise) for callers that render or extract more."""

    mesh: trimesh.Trimesh
    report: dict
    field: object | None = None


def resolve_device(device: str) -> str:
    """'cpu', 'cuda' or 'cuda:N'; UserInputError when CUDA is asked for and absent."""
    if device == "cpu":
        return device
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            raise UserInputError(f"--device {device}: this torch build sees no CUDA GPU")
        return device
    raise UserInputError(f"--device must be cpu or cuda (got {device!r})")


class _StageClock:
    """Wall seconds and the process's peak resident memory after each named step."""

    def __init__(self):
        self.stages: dict[str, dict] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        self.stages[name] = {"seconds": round(time.perf_counter() - start, 3),
                             "peak_memory_mb": round(peak_kb / (1024 if sys.platform != "darwin" else 1024**2), 1)}


def reconstruct(dataset: Path | str, config: ReconstructConfig = ReconstructConfig(), *, device: str = "cpu",
                seed: int = 0, progress: ProgressFn | None = None) -> Reconstruction:
    """Run the stage on a dataset folder; see the module docstring. Raises UserInputError for unusable input."""
    from real2sim.multiview.hull import carve, object_region
    from real2sim.multiview.voxel_grid import VoxelGrid, largest_parts, simplified, surface_from_grid
    from real2sim.reconstruct.truth import load_truth

    config.validate()
    device = resolve_device(device)
    clock = _StageClock()
    report: dict = {"backend": config.backend, "device": device, "seed": seed}
    with clock.stage("load"):
        ds = read_dataset(dataset)
        views = load_views(ds, max_side_px=config.max_image_side_px)
        table_z_m = config.table_z_m if has_table_plane(ds) else None  # None: the images show no table
        support_z_m = stated_support_z_m(ds)  # a stand's top the dataset states (None with a table)
        truth = load_truth(dataset)
    if config.mask_edges in ("auto", "colour"):
        with clock.stage("mask_edges"):
            views, report["mask_edges"] = refined_mask_edges(views)
    else:
        report["mask_edges"] = {"method": "as-given"}
    if not config.silhouette_poses and views.unrefined:
        report["unrefined_poses"] = "taken as given (--no-silhouette-poses)"
        views = replace(views, unrefined=())
    if views.unrefined and views.count - len(views.unrefined) < MIN_VIEWS:
        # refine-poses refined (almost) none: no good views to align the others to, so all are aligned
        # to each other, held-out ones too (their colours never train the field; their masks help place it)
        with clock.stage("all_poses"):
            from real2sim.reconstruct.poses.silhouette import align_all

            views, report["silhouette_poses"] = align_all(views, table_z_m=table_z_m, progress=progress)
            if report["silhouette_poses"]["method"] == "none":
                warnings.warn(f"poses not aligned: {report['silhouette_poses']['reason']}", RuntimeWarning,
                              stacklevel=2)
            else:
                report["silhouette_poses"].update(_errors_vs_truth(dataset, ds, views))
                config, report["photo_carving"] = carving_after_alignment(config)
                config, report["field_poses"] = field_poses_after_alignment(config)
    train_idx, held_idx = held_out_split(views.count, config.held_out_every)
    train, held = views.subset(train_idx), views.subset(held_idx)
    if views.unrefined:  # refine-poses could not refine them: the robot's poses, millimetres off
        with clock.stage("unrefined_poses"):
            from real2sim.reconstruct.poses.silhouette import align_unrefined

            train, report["unrefined_views"] = align_unrefined(
                train, outlier_fraction=config.hull_outlier_fraction, table_z_m=config.table_z_m, progress=progress,
                device=device)
            if report["unrefined_views"]:  # a held-out view with a wrong pose would judge the pose, not the field
                report["held_out_views_left_out_unrefined"] = list(held.unrefined)
                held = held.subset(np.nonzero(~held.is_unrefined)[0])
    if progress:
        progress("visual hull", 0, 0)
    with clock.stage("visual_hull"):
        region = object_region(train, outlier_fraction=config.hull_outlier_fraction, table_z_m=table_z_m,
                               device=device)
    if table_z_m is None and support_z_m is not None and support_z_m > region[0][2]:
        # no table in the images, but the rig says where the object stands: nothing of it is below, and
        # the unseen cone the views leave under its bottom (they all look down at it) is cut there
        report["table"] = (f"none (the dataset has no table plane); cut at the support plane it states, "
                           f"z = {support_z_m:g} m")
        region = (np.array([*region[0][:2], support_z_m]), region[1])
        config = replace(config, table_z_m=support_z_m)
    elif table_z_m is None:  # no table: nothing to cut at; the grids' floor is the region's own
        report["table"] = "none (the dataset has no table plane): the object is not cut below"
        config = replace(config, table_z_m=float(region[0][2]))
    report["region_m"] = [region[0].tolist(), region[1].tolist()]
    if config.backend == "hull":
        with clock.stage("hull_surface"):
            grid = VoxelGrid.covering(*region, config.hull_voxels, config.table_z_m)
            scores = carve(train, grid, config.hull_outlier_fraction, device=device)
            mesh = largest_parts(surface_from_grid(scores, grid, 0.5, config.table_z_m), config.min_part_volume_fraction)
            mesh = simplified(mesh, config.max_faces)
        with clock.stage("texture"):
            from real2sim.reconstruct.field.texture import bake_texture_from_images

            if progress:
                progress("texture", 0, 0)
            textured = bake_texture_from_images(mesh, train, size_px=config.texture_px)
    else:
        from real2sim.reconstruct.field.extract import (SURFACE_DENSITY_PER_VOXEL, density_mesh, render_view,
                                                  silhouette_surface_level, tsdf_mesh)
        from real2sim.reconstruct.field.texture import bake_texture
        from real2sim.reconstruct.field.train import train_field

        with clock.stage("train_field"):
            trained = train_field(train, region, config.field, device=device, seed=seed, progress=progress,
                                  table_z_m=config.table_z_m)
        if trained.corrections is not None:  # per-view pose and colour corrections (view_corrections.py)
            from real2sim.reconstruct.field.view_corrections import correction_report

            report["view_corrections"] = correction_report(trained.corrections, train, dataset_root=dataset,
                                                           region_m=region)
            train = trained.corrected_views(train)  # all that follows sees the views as the field was fitted to them
        report["loss_curve"] = [[int(s), float(v)] for s, v in trained.loss_curve]
        report["field_grid"] = list(trained.field.grid.shape)
        report["photo_carved_voxels"] = trained.carved_voxels
        report["photo_carving_restored_voxels"] = trained.restored_voxels  # many: poses not refined?
        report["photo_carving_opened_voxels"] = trained.opened_voxels
        if config.field.photo_carving:  # how it decided which views see a voxel (carving/views.py)
            from real2sim.reconstruct.carving.views import visibility_method

            report["photo_carving_visibility"] = visibility_method(config.field.carving.visibility, device)
        if trained.carving_exposure is not None:
            report["photo_carving_exposure"] = trained.carving_exposure
        report["hull_and_carving_seconds"] = trained.hull_and_carving_seconds  # part of train_field's
        report["train_field_phase_seconds"] = trained.phase_seconds  # where train_field's time went
        report["field_batches"] = {"rays_per_step": trained.config.rays_per_step,
                                   "coarse_steps": trained.config.coarse_steps, "fine_steps": trained.config.fine_steps}
        # per grid, the steps it trained and why it ended: its cap, or its loss flattened (FieldConfig.convergence)
        report["field_stages"] = [{"voxels": v, "steps": n, "ended": e} for v, n, e in trained.stages]
        report["field_voxel_mm"] = 1000.0 * trained.field.grid.voxel_m
        with clock.stage("extract_mesh"):
            if progress:
                progress(f"mesh ({config.extraction})", 0, 0)
            if config.extraction == "tsdf":
                mesh = tsdf_mesh(trained.field, train, table_z_m=config.table_z_m, progress=progress)
            else:
                level = SURFACE_DENSITY_PER_VOXEL
                if config.surface_level == "silhouettes":
                    report["surface_level"] = silhouette_surface_level(trained.field, train, seed=seed)
                    level = report["surface_level"]["level_per_voxel"]
                mesh = density_mesh(trained.field, table_z_m=config.table_z_m, level_per_voxel=level,
                                    report=report.setdefault("extraction", {}))
            mesh = simplified(largest_parts(mesh, config.min_part_volume_fraction), config.max_faces)
        with clock.stage("texture"):
            if progress:
                progress("texture", 0, 0)
            textured = bake_texture(mesh, trained.field, size_px=config.texture_px)
        if held.count:
            with clock.stage("held_out_field_psnr"):
                if config.field.pose_refinement:  # held-out views never trained the field: fit their poses to it
                    from real2sim.reconstruct.field.train import fit_views_to_field
                    from real2sim.reconstruct.field.view_corrections import correction_report

                    fitted = fit_views_to_field(trained.field, held, config.field, seed=seed)
                    report["held_out_pose_fit"] = correction_report(fitted, held, dataset_root=dataset, region_m=region)
                    held = replace(held, c2w_cv=fitted.corrected_c2w())
                report["psnr_field_held_out_db"] = _field_psnr(trained.field, held, render_view)
    if held.count:
        with clock.stage("held_out_mesh_psnr"):
            report["psnr_mesh_held_out_db"] = _mesh_psnr(textured, held)
    check_seen_together(mesh, train, region)
    report["held_out_views"] = list(held.names)
    report["train_views"] = int(train.count)
    report["mesh"] = {"vertices": int(len(textured.vertices)), "faces": int(len(textured.faces)),
                      "watertight": bool(mesh.is_watertight), "bounds_m": mesh.bounds.tolist()}
    if truth is not None:
        from real2sim.reconstruct.truth import compare_to_truth

        with clock.stage("compare_to_truth"):
            report["truth"] = compare_to_truth(mesh, truth, seed=seed)
    report["stages"] = clock.stages
    report["total_seconds"] = round(sum(s["seconds"] for s in clock.stages.values()), 3)
    report["config"] = asdict(config)
    return Reconstruction(mesh=textured, report=report, field=None if config.backend == "hull" else trained.field)


def _errors_vs_truth(dataset: Path | str, ds, views: PosedViews) -> dict:
    """``{"pose_error_vs_truth": ...}``: the given and the aligned poses of ``views`` against the dataset's
    true ones (ground_truth/), with how far the working volume's corners move in the image; {} without them."""
    from real2sim.formats.dataset import read_ground_truth
    from real2sim.multiview.hull import object_region
    from real2sim.reconstruct.field.view_corrections import pose_errors_vs_truth

    if read_ground_truth(dataset) is None:
        return {}
    given = dict(zip((f.file_path for f in ds.frames), ds.poses_c2w_cv()))
    region = object_region(views, table_z_m=None)
    errors = pose_errors_vs_truth(np.stack([given[n] for n in views.names]), views.c2w_cv, views.names, dataset,
                                  region_m=region, intrinsics=views.intrinsics)
    return {} if errors is None else {"pose_error_vs_truth": errors}


class UnboundedReconstruction(UserInputError):
    """The reconstruction reaches where the views do not see together: refused rather than written."""


def check_seen_together(mesh: trimesh.Trimesh, views: PosedViews, region: tuple[np.ndarray, np.ndarray],
                        max_outside_fraction: float = 0.01, max_points: int = 20_000) -> None:
    """Refuse (UnboundedReconstruction) a mesh (world frame, metres) larger than the region its views see
    together: more than ``max_outside_fraction`` of its vertices outside the hull's box ``region`` (by more
    than a tenth of the box's size) or where fewer than enough views see from far enough apart
    (:func:`real2sim.multiview.hull.seen_together`). Nothing the views cannot bound is a result."""
    from real2sim.multiview.hull import MIN_SPREAD_DEG, seen_together

    verts = np.asarray(mesh.vertices)
    if len(verts) > max_points:
        verts = verts[np.random.default_rng(0).choice(len(verts), max_points, replace=False)]
    lo, hi = region
    slack = 0.1 * float(np.max(hi - lo))
    outside_box = ((verts < lo - slack) | (verts > hi + slack)).any(axis=1)
    unseen = ~seen_together(views, verts)
    bad = outside_box | unseen
    if bad.mean() > max_outside_fraction:
        size_mm = 1000.0 * (verts.max(axis=0) - verts.min(axis=0))
        raise UnboundedReconstruction(
            f"the reconstruction ({size_mm[0]:.0f} x {size_mm[1]:.0f} x {size_mm[2]:.0f} mm) reaches beyond the region "
            f"the views see together ({100 * bad.mean():.0f} % of its surface): refused; check that the poses and "
            f"masks belong together and that the object is seen from directions at least "
            f"{MIN_SPREAD_DEG:g} degrees apart")


def _psnr_region(views: PosedViews, i: int, covered: np.ndarray) -> np.ndarray:
    return (views.mask[i] > 0.5) | covered


def _field_psnr(field, held: PosedViews, render_view) -> float:
    from real2sim.reconstruct.truth import psnr

    values = []
    for i in range(held.count):
        rgb, opacity, _ = render_view(field, held, held.c2w_cv[i])
        target = held.rgb[i] * held.mask[i][..., None]
        values.append(psnr(rgb, target, _psnr_region(held, i, opacity > 0.5)))
    return float(np.mean(values))


def _mesh_psnr(mesh: trimesh.Trimesh, held: PosedViews) -> float:
    from real2sim.reconstruct.field.texture import render_textured_mesh
    from real2sim.reconstruct.truth import psnr

    values = []
    for i in range(held.count):
        rgb, covered = render_textured_mesh(mesh, held.intrinsics, held.c2w_cv[i])
        target = held.rgb[i] * held.mask[i][..., None]
        values.append(psnr(rgb, target, _psnr_region(held, i, covered)))
    return float(np.mean(values))


def write_reconstruction(result: Reconstruction, out_dir: Path | str, *, overwrite: bool = False,
                         inputs: tuple = ()) -> Path:
    """Write ``mesh.obj`` (+ .mtl, .png) and ``report.json`` into ``out_dir``, whole or not at all."""
    import json

    from real2sim.geometry.mesh_io import export_textured_mesh
    from real2sim.plumbing.outputs import atomic_output_dir

    out_dir = Path(out_dir)
    with atomic_output_dir(out_dir, overwrite=overwrite, inputs=inputs, made_by="real2sim reconstruct") as tmp:
        export_textured_mesh(result.mesh, tmp / "mesh.obj")
        (tmp / "report.json").write_text(json.dumps(result.report, indent=2, default=_json_default))
    return out_dir.resolve()


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, set)):
        return list(value)
    return str(value)


def import_external(dataset: Path | str, mesh_path: Path | str, dataparser_transforms: Path | str, *,
                    config: ReconstructConfig = ReconstructConfig()) -> Reconstruction:
    """A nerfstudio-exported mesh put back in the dataset's world frame and cleaned, with the same report."""
    from real2sim.reconstruct.external import import_nerfstudio_mesh
    from real2sim.reconstruct.truth import compare_to_truth, load_truth

    clock = _StageClock()
    with clock.stage("import"):
        read_dataset(dataset)  # the frame the mesh is put back into must exist and be readable
        mesh = import_nerfstudio_mesh(mesh_path, dataparser_transforms, table_z_m=config.table_z_m,
                                      min_part_volume_fraction=config.min_part_volume_fraction)
    report: dict = {"backend": "nerfstudio-import", "source_mesh": Path(mesh_path).name,
                    "mesh": {"vertices": int(len(mesh.vertices)), "faces": int(len(mesh.faces)),
                             "watertight": bool(mesh.is_watertight), "bounds_m": mesh.bounds.tolist()}}
    truth = load_truth(dataset)
    if truth is not None:
        with clock.stage("compare_to_truth"):
            report["truth"] = compare_to_truth(mesh, truth)
    report["stages"] = clock.stages
    report["total_seconds"] = round(sum(s["seconds"] for s in clock.stages.values()), 3)
    return Reconstruction(mesh=mesh, report=report)
