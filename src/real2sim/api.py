"""The Python front door: an asset from a mesh, from a capture, its evaluation, and a reader of an
asset folder, with keyword arguments that carry their units and SPEC strings as the CLI takes them.

    import real2sim
    asset = real2sim.build_asset("can.obj", "can_asset", mass_kg=0.4, collision=["cylinders:10", "coacd"],
                                 formats=["urdf", "mjcf"])
    asset.model_for("mujoco")          # Path to can_asset/cylinders_10/scene.xml

Every mistake in what is asked is a :class:`~real2sim.plumbing.errors.UserInputError` whose message
is the line the command line prints.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Sequence

from real2sim.asset.build import AssetConfig
from real2sim.asset.build import build_asset as _build
from real2sim.asset.export.writers import SIMULATOR_FILES  # the file each simulator takes (asset folders' README too)
from real2sim.collision.fit.config import FitConfig, iteration_limits
from real2sim.evaluate.sweep import EvaluationConfig, EvaluationResult
from real2sim.evaluate.sweep import evaluate as _evaluate
from real2sim.formats.contact import ContactProperties
from real2sim.formats.physical import PhysicalProperties, read_given_properties, read_physical_properties
from real2sim.formats.spec import CollisionSpec, parse_spec
from real2sim.pipeline.run import RunConfig, RunResult, run_pipeline
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn

FORMATS = ("urdf", "sdf", "mjcf", "usd")


def _specs(collision: str | Iterable[str | CollisionSpec]) -> tuple[CollisionSpec, ...]:
    items = [collision] if isinstance(collision, (str, CollisionSpec)) else list(collision)
    if not items:
        raise UserInputError("collision: give at least one SPEC, e.g. 'cylinders:10'")
    return tuple(item if isinstance(item, CollisionSpec) else parse_spec(str(item)) for item in items)


def _formats(formats: str | Iterable[str]) -> tuple[str, ...]:
    items = [formats] if isinstance(formats, str) else list(formats)
    unknown = [f for f in items if f not in FORMATS]
    if unknown:
        raise UserInputError(f"unknown format {unknown[0]!r}; known: {', '.join(FORMATS)}")
    return tuple(dict.fromkeys(["urdf", *items]))


@dataclass(frozen=True)
class Representation:
    """One collision representation of an asset: its folder and what is in it.

    Every file in the folder is in the asset frame: metres, kilograms, the centre of the visual
    mesh's footprint at the origin, +z up.
    """

    name: str
    """Canonical SPEC name, e.g. ``cylinders_10``."""
    folder: Path
    """The representation's folder inside the asset folder."""
    fit_report: dict = field(default_factory=dict, compare=False, repr=False)
    """``fit_report.json``: ``num_primitives``, ``iou``, ``chamfer_mm``, ``fit_seconds``, ..."""

    def model_for(self, simulator: str) -> Path:
        """The file a simulator loads for this representation.

        Args:
            simulator: a key of `SIMULATOR_FILES`: ``"drake"``, ``"drake_point"``, ``"mujoco"``,
                ``"pybullet"``, ``"isaac"``, ``"gazebo"`` or ``"urdf"``.

        Returns:
            The path of that file inside `folder`.

        Raises:
            UserInputError: an unknown simulator, or a file the asset was built without (the message
                names the ``formats=`` / ``--format`` that writes it).
        """
        if simulator not in SIMULATOR_FILES:
            raise UserInputError(f"unknown simulator {simulator!r}; known: {', '.join(SIMULATOR_FILES)}")
        name, fmt = SIMULATOR_FILES[simulator]
        path = self.folder / name
        if not path.is_file():
            raise UserInputError(f"{self.folder} has no {name} for {simulator}: build the asset with "
                                 f"formats=[..., {fmt!r}] (--format {fmt})")
        return path


@dataclass(frozen=True)
class Asset:
    """An asset folder as ``real2sim asset`` / ``run`` wrote it (docs/formats.md), read by `load_asset`.

    ``asset["cylinders:10"]`` is one representation, by SPEC or by folder name.
    """

    folder: Path
    """The asset folder."""
    physical_properties: PhysicalProperties
    """Mass (kg), centre of mass (m, asset frame) and inertia about it (kg m^2)."""
    representations: tuple[Representation, ...]
    """One per collision SPEC, in the order they were asked for."""

    def __getitem__(self, name: str) -> Representation:
        """One representation, by SPEC or canonical name.

        Args:
            name: a SPEC (``"cylinders:10"``, ``"boxes:20+cylinders:20"``) or its folder's name
                (``"cylinders_10"``).

        Returns:
            The `Representation` of that name.

        Raises:
            UserInputError: the asset has no such representation (the message lists those it has).
        """
        wanted = name.replace(":", "_").replace("+", "_")
        for rep in self.representations:
            if rep.name == wanted:
                return rep
        raise UserInputError(f"{self.folder} has no representation {name!r}; it has "
                             f"{', '.join(r.name for r in self.representations) or 'none'}")

    def model_for(self, simulator: str, representation: str | None = None) -> Path:
        """The file a simulator loads, of one representation.

        Args:
            simulator: a key of `SIMULATOR_FILES` (``"drake"``, ``"mujoco"``, ``"isaac"``, ...).
            representation: a SPEC or folder name; None: the first representation built.

        Returns:
            The path of the file, e.g. ``ASSET/cylinders_10/scene.xml`` for ``"mujoco"``.

        Raises:
            UserInputError: the asset holds no representation, has no such one, or was built without
                the file (see `Representation.model_for`).
        """
        if not self.representations:
            raise UserInputError(f"{self.folder} holds no collision representation")
        rep = self[representation] if representation else self.representations[0]
        return rep.model_for(simulator)


def load_asset(folder: str | Path) -> Asset:
    """Read an asset folder: its physical properties and representations.

    Args:
        folder: an asset folder written by `build_asset`, ``real2sim asset`` or ``real2sim run``
            (it holds ``asset_config.json`` and ``physical_properties.json``).

    Returns:
        The `Asset`: mass (kg), centre of mass (m) and inertia (kg m^2) in the asset frame, and one
        `Representation` per collision SPEC, in the order they were asked for.

    Raises:
        UserInputError: ``folder`` is not an asset folder, or its ``asset_config.json`` is not readable JSON.
    """
    folder = Path(folder)
    config_path = folder / "asset_config.json"
    if not config_path.is_file():
        raise UserInputError(f"{folder} is not an asset folder (no asset_config.json)")
    try:
        config = json.loads(config_path.read_text())
    except (OSError, ValueError) as exc:
        raise UserInputError(f"{config_path} is not readable JSON ({exc})") from None
    props = read_physical_properties(folder / "physical_properties.json")
    names = [str(spec).replace(":", "_").replace("+", "_") for spec in config.get("collision", [])]
    names = [n for n in names if (folder / n).is_dir()] or sorted(
        p.name for p in folder.iterdir() if (p / "collision.json").is_file())
    reps = []
    for name in names:
        report = folder / name / "fit_report.json"
        try:
            fit = json.loads(report.read_text()) if report.is_file() else {}
        except (OSError, ValueError):
            fit = {}
        reps.append(Representation(name=name, folder=folder / name, fit_report=fit))
    return Asset(folder=folder, physical_properties=props, representations=tuple(reps))


def build_asset(mesh: str | Path, out: str | Path, *, mass_kg: float | None = None,
                collision: str | Sequence[str | CollisionSpec] = ("cylinders:10",),
                formats: str | Sequence[str] = ("urdf",), properties: str | Path | None = None,
                flat_bottom: bool = False, support_height_m: float = 0.0, pca_up: bool = False,
                mesh_units: str = "m", contact: ContactProperties | None = None, max_iterations: int | None = None,
                seed: int = 0, device: str = "cpu", overwrite: bool = False,
                progress: ProgressFn | None = None) -> Asset:
    """Build an asset folder from a mesh, as ``real2sim asset`` does.

    Args:
        mesh: the object's mesh file (OBJ, PLY, STL, GLB, OFF), in ``mesh_units``.
        out: the asset folder to write (new, or an earlier real2sim output with ``overwrite``).
        mass_kg: the measured mass, kg, in (0, 1000]; optional when ``properties`` gives it.
        collision: SPEC strings (``"cylinders:10"``, ``"boxes:20+cylinders:20"``, ``"coacd"``), one folder each.
        formats: model formats besides the URDFs always written: ``"sdf"``, ``"mjcf"``, ``"usd"``.
        properties: a props.json of ``real2sim identify`` or a physical_properties.json (measured mass,
            centre of mass and inertia instead of uniform density).
        flat_bottom: crop below the support plane and close the bottom flat (paper IV-C1).
        support_height_m: the support (table) height in the mesh frame, m, +z up.
        pca_up: make the longest principal axis the asset's +z, as the paper does (default: the mesh's +z stays up).
        mesh_units: ``"m"``, ``"cm"``, ``"mm"`` or ``"in"``.
        contact: Drake contact properties (default: :class:`ContactProperties`'s).
        max_iterations: at most this many fitting steps per primitive SPEC (default: the fit's own rule).
        seed: random seed of sampling and fitting.
        device: torch device for primitive fitting (``"cpu"``, ``"cuda"``).
        overwrite: replace ``out`` when it is an earlier real2sim output.
        progress: ``progress(label, done, total)`` for long work, or None.

    Returns:
        The `Asset` read back from ``out``.

    Raises:
        UserInputError: a bad argument (an unknown SPEC or format, a mass out of range, an unreadable
            mesh, an ``out`` that may not be written), with the line ``real2sim asset`` prints.
    """
    given, frame, source = None, "asset", ""
    if properties is not None:
        given, frame = read_given_properties(Path(properties))
        source = str(properties)
    if mass_kg is None and given is None:
        raise UserInputError("mass_kg is required (or properties= with the measured mass properties)")
    config = AssetConfig(mass_kg=float(mass_kg if mass_kg is not None else given.mass_kg), specs=_specs(collision),
                         formats=_formats(formats), given_properties=given, given_properties_frame=frame,
                         given_properties_source=source, flat_bottom=flat_bottom, support_height_m=support_height_m,
                         pca_up=pca_up, mesh_units=mesh_units, seed=seed, device=device)
    if contact is not None:
        config = replace(config, contact=contact)
    if max_iterations is not None:
        if int(max_iterations) < 1:
            raise UserInputError(f"max_iterations must be at least 1, got {max_iterations}")
        config = replace(config, fit_config=FitConfig(**iteration_limits(max_iterations)))
    _build(Path(mesh), Path(out), config, overwrite=overwrite, progress=progress)
    return load_asset(out)


def run(dataset: str | Path, out: str | Path, *, config: RunConfig, overwrite: bool = False,
        progress: ProgressFn | None = None) -> RunResult:
    """Images (a dataset folder, phone photos or a video) to an asset folder, as ``real2sim run`` does.

    Resumable: run again with the same ``out``, it skips the stages whose inputs and settings are
    unchanged and resumes an interrupted run.

    Args:
        dataset: a dataset folder (nerfstudio ``transforms.json`` with ``images/``, poses in metres,
            table top at z = 0), a COLMAP model (``images/`` + ``sparse/0``, with
            ``config.object_height_m`` or ``config.scale``), a folder of phone photos, or a video file.
        out: the asset folder: new, or an earlier run of the same dataset (resumed).
        config: every stage's settings, e.g. ``RunConfig(asset=AssetConfig(mass_kg=0.35,
            specs=(parse_spec("cylinders:10"),)))``. Unlike the command line, the API refines poses only
            when ``config.refine`` is given; photos and videos are masked ``"auto"`` unless
            ``config.mask_method`` says otherwise, as on the command line.
        overwrite: discard ``out`` first (its cached stages and results).
        progress: ``progress(label, done, total)`` for long work, or None.

    Returns:
        The run's result: ``asset_dir``, each stage's status (``"ran"`` or ``"skipped"``), the URDFs
        written, ``truth`` (errors against a simulated capture's ground truth, else None) and the
        warnings of every stage.

    Raises:
        UserInputError: a bad dataset or setting, with the line ``real2sim run`` prints.
    """
    return run_pipeline(Path(dataset), Path(out), config, overwrite=overwrite, progress=progress)


def evaluate(assets: str | Path | Sequence[str | Path], out: str | Path, *, config: EvaluationConfig | None = None,
             reference_mesh: str | Path | None = None, overwrite: bool = False,
             progress: ProgressFn | None = None) -> EvaluationResult:
    """Simulate every representation of some assets against their reference in Drake, as
    ``real2sim evaluate`` does.

    The paper's protocol: planar pushing by a sphere and a tilting ramp, point and hydroelastic
    contact, the candidate's state reset onto the reference's every 0.1 s (equation error). Needs the
    ``[sim]`` extra (Drake). Resumable: rows already in ``out/runs.csv`` are not simulated again.

    Args:
        assets: one asset folder or several.
        out: the results folder to write (``runs.csv``, ``summary.csv``, Pareto plots, ``report.html``).
        config: tasks, contact models, runs per task, parallel jobs, ...; None: the defaults
            (both tasks, both contact models, 10 runs each).
        reference_mesh: the mesh every asset is judged against, in the asset frame, metres; None: each
            asset's own closed mesh (``visual/collision_reference.obj``).
        overwrite: discard the results at ``out`` first.
        progress: ``progress(label, done, total)`` for long work, or None.

    Returns:
        The evaluation: ``out_dir``, every run's row (``ate_m``, ``ocae_m``, ``cpd_m_per_s``,
        ``sim_time_s``, ...), the summary rows (one per representation and contact model), the plots,
        ``report_path``, and how many rows were simulated, skipped as done, or failed.

    Raises:
        UserInputError: a bad argument, with the line ``real2sim evaluate`` prints.
    """
    folders = [Path(assets)] if isinstance(assets, (str, Path)) else [Path(a) for a in assets]
    return _evaluate(folders, Path(out), config or EvaluationConfig(), reference_mesh=reference_mesh,
                     overwrite=overwrite, progress=progress)
