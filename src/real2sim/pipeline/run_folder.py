"""The folders a `real2sim run` is given: the dataset it reads (checked, and the files whose
contents key its stages) and the asset folder it writes (resumed, replaced or refused; what a run that
stopped leaves there). :mod:`real2sim.pipeline.run` chains the stages over them."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from real2sim.formats.dataset import is_model_frame, read_dataset
from real2sim.plumbing.errors import UserInputError
from real2sim.pipeline import manifest as mf
from real2sim.capture.phone.normalise import check_frame_options, sparse_point_files
from real2sim.plumbing import digests


def kept_note(asset_dir: Path | str) -> str:
    """What a run that stopped leaves in ``asset_dir``, for its one-line message: the finished stages
    kept for a resume (a deliberate cache, docs/reliability.md), or that nothing was kept."""
    manifest = mf.Manifest.load(Path(asset_dir))
    stages = list(manifest.data["stages"]) if manifest is not None else []
    if not stages:
        return f"no finished stage is kept in {asset_dir}" if Path(asset_dir).is_dir() else "nothing was written"
    return (f"the finished stages ({', '.join(stages)}) are kept in {Path(asset_dir) / mf.RUN_DIRNAME}: fix the "
            "cause and run the same command again to resume from them")


def poses_to_refine(dataset: Path | str) -> bool:
    """Whether ``dataset`` has poses that COLMAP refinement can improve: a transforms.json of given poses
    (a robot's, a calibration's) that `refine-poses` has not refined yet. A COLMAP model or an
    ns-process-data folder holds COLMAP's own poses already: nothing to refine."""
    ds = read_dataset(Path(dataset), check_files=False)
    return not is_model_frame(ds) and "real2sim_refinement" not in ds.extra


def dataset_files(root: Path) -> list[str]:
    """What the stages read from a dataset: transforms.json, the frames' images and masks, ground_truth/."""
    ds = read_dataset(root, check_files=False)
    files = ["transforms.json"]
    if is_model_frame(ds):  # its poses' frame and the sparse points the table is found in
        files += sparse_point_files(ds)
    for frame in ds.frames:
        files.append(frame.file_path)
        if frame.mask_path:
            files.append(frame.mask_path)
    for folder in ("ground_truth", "background"):  # background/: the empty scene, for background masks
        if (root / folder).is_dir():
            files += [f"{folder}/{rel}" for rel in digests.tree_files(root / folder)]
    return files


def check_dataset(dataset: Path, masks_needed: bool = True, scale_given: bool = False) -> Path:
    """The resolved dataset folder; UserInputError when it cannot be used as it is (one line).

    ``scale_given``: --object-height-m or --scale was given; a COLMAP dataset needs one, a
    transforms.json dataset (metric already) takes neither.
    """
    dataset = Path(dataset).resolve()
    if dataset.is_file() and dataset.name == "transforms.json":
        dataset = dataset.parent
    ds = read_dataset(dataset)
    check_frame_options(ds, scale_given)
    missing = [f.file_path for f in ds.frames if not f.mask_path]
    if missing and masks_needed:
        # `real2sim mask` writes mask paths into a transforms.json, which a bare COLMAP model lacks
        later = "" if ds.extra.get("source") == "colmap" else ", or make them first with `real2sim mask`"
        raise UserInputError(f"{len(missing)} of {len(ds.frames)} frames of {dataset} have no mask; pass "
                             f"--mask provided|maskrcnn|background{later}")
    return dataset


def prepare_asset_dir(asset_dir: Path, dataset: Path, overwrite: bool) -> tuple[mf.Manifest, bool]:
    """The manifest to resume from (or a fresh one) and whether ASSETDIR is new. Writes nothing yet."""
    if asset_dir.exists() and not asset_dir.is_dir():
        raise UserInputError(f"output path {asset_dir} exists and is not a folder")
    if not asset_dir.exists():
        return mf.Manifest(asset_dir, dataset), True
    if overwrite:
        return mf.Manifest(asset_dir, dataset), False
    previous = mf.Manifest.load(asset_dir)
    if previous is None:
        raise UserInputError(f"output folder {asset_dir} exists and holds no run to resume; "
                             "pass --overwrite to replace it")
    if previous.dataset != dataset:
        raise UserInputError(f"output folder {asset_dir} holds a run of another dataset ({previous.dataset}); "
                             "pass --overwrite to replace it")
    return previous, False


def remove_stale_temporaries(asset_dir: Path) -> None:
    """Temporary folders and files a killed run left behind (names from mkdtemp: '.NAME.tmp-XXXX')."""
    for folder in (asset_dir, asset_dir / mf.RUN_DIRNAME):
        for path in folder.glob(".*"):
            if ".tmp-" in path.name or ".old-" in path.name:
                shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink(missing_ok=True)


def discard(asset_dir: Path) -> None:
    """Remove ``asset_dir`` (for --overwrite): renamed aside first, so a half-deleted folder never holds its name."""
    old = asset_dir.with_name(f".{asset_dir.name}.old-{os.getpid()}")
    asset_dir.rename(old)
    shutil.rmtree(old, ignore_errors=True)
