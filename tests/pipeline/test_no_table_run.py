"""`run` on a capture without a table (issue 28 part 5): the can on a thin stand, cameras above it.

The asset's flat bottom is closed where the object's own lowest seen points are
(real2sim.pipeline.support), not at z = 0 nor at the reconstruction's lowest vertex: nothing
under the can is seen, and the visual hull there is a cone some 15 mm deep. The dataset's world
frame is moved up by 30 mm, so that z = 0 is not the object's bottom (the old rule, the table's
z = 0, refused this dataset; the lowest vertex stood the asset on the cone's tip). The same
capture with the ``table_plane`` key removed is a dataset with a table at z = 0 again. A dataset
that states its support's height (``support_z_m``, as ``capture --no-table`` writes) is cut and
stood there instead.
24 noise-free views at 80x60 px, hull on 48 voxels, no ground truth in the runs (its comparison
costs more than the run): the true can is read from the capture's ground_truth/ here.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from real2sim.cli import main
from tests.reconstruct.conftest import edit_transforms, raised_dataset

FAST = ["--backend", "hull", "--voxels", "48", "--max-faces", "2000", "--texture-px", "64", "--collision", "mesh",
        "--mass-kg", "0.35", "--no-refine-poses"]
RAISE_M = 0.03


@pytest.fixture(scope="module")
def stand_capture(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("no_table")
    assert main(["capture", "can", "--out", str(root / "can"), "--views", "24", "--width-px", "80", "--height-px", "60",
                 "--no-table", "--pose-noise-mm", "0", "--pose-noise-deg", "0"]) == 0
    return root / "can"


def _without_truth(dataset: Path) -> Path:
    shutil.rmtree(dataset / "ground_truth")
    return dataset


def _true_can(capture: Path):
    """The true can in the capture's world frame (its lowest point at z = 0) and its mass properties."""
    from real2sim.reconstruct.truth import load_truth

    mesh = load_truth(capture)
    assert mesh.is_watertight and abs(mesh.bounds[0, 2]) < 1e-6
    return mesh


def _support(asset: Path) -> tuple[float, str]:
    config = json.loads((asset / "asset_config.json").read_text())
    entry = json.loads((asset / ".run" / "run.json").read_text())["stages"]["asset"]
    return config["support_height_m"], entry["support"]


def _unstated(data: dict) -> dict:
    del data["support_z_m"]
    return data


def test_without_a_table_the_asset_stands_on_the_objects_own_bottom(stand_capture, tmp_path):
    import trimesh

    dataset = _without_truth(raised_dataset(stand_capture, tmp_path / "raised", RAISE_M))
    edit_transforms(dataset, _unstated)
    assert json.loads((dataset / "transforms.json").read_text())["table_plane"] is False
    asset = tmp_path / "asset"
    assert main(["run", str(dataset), "--out", str(asset), *FAST]) == 0
    support_m, how = _support(asset)
    recon = trimesh.load(asset / ".run" / "reconstruct" / "mesh.obj", force="mesh")
    assert recon.bounds[0, 2] < RAISE_M - 0.008  # the unseen cone under the can, which the support leaves out
    assert "no table plane" in how and abs(support_m - RAISE_M) < 0.002, (support_m, how)

    # It stands on its bottom: a flat disc nearly as wide as the can, the centre of mass above its middle.
    true = _true_can(stand_capture)
    visual = trimesh.load(asset / "visual" / "collision_reference.obj", force="mesh")
    low = visual.vertices[visual.vertices[:, 2] < visual.bounds[0, 2] + 5e-4]
    width_m = true.extents[0]
    assert np.ptp(low[:, 0]) > 0.85 * width_m and np.ptp(low[:, 1]) > 0.85 * width_m
    props = json.loads((asset / "physical_properties.json").read_text())
    com_above_bottom_m = props["com_m"][2] - visual.bounds[0, 2]
    true_com_above_bottom_m = true.center_mass[2]  # a uniform solid, as the asset's estimate
    assert abs(com_above_bottom_m - true_com_above_bottom_m) < 0.002
    assert abs(np.linalg.norm(props["com_m"][:2])) < 0.002
    true_moments = np.linalg.eigvalsh(true.moment_inertia * (0.35 / true.mass))
    moments = np.linalg.eigvalsh(np.asarray(props["inertia_kg_m2"]))
    assert np.all(np.abs(moments - true_moments) / true_moments < 0.06), (moments, true_moments)


def test_a_stated_support_cuts_the_unseen_cone_and_the_asset_stands_on_it(stand_capture, tmp_path):
    import trimesh

    dataset = _without_truth(raised_dataset(stand_capture, tmp_path / "raised", RAISE_M))
    data = json.loads((dataset / "transforms.json").read_text())
    assert data["table_plane"] is False and data["support_z_m"] == pytest.approx(RAISE_M)
    asset = tmp_path / "asset"
    assert main(["run", str(dataset), "--out", str(asset), *FAST]) == 0
    support_m, how = _support(asset)
    assert support_m == pytest.approx(RAISE_M) and "support_z_m" in how, (support_m, how)
    recon = trimesh.load(asset / ".run" / "reconstruct" / "mesh.obj", force="mesh")
    assert RAISE_M - 1e-6 < recon.bounds[0, 2] < RAISE_M + 1e-3  # no cone below the stand's top
    report = json.loads((asset / ".run" / "reconstruct" / "report.json").read_text())
    assert "support plane" in report["table"]
    # its bottom is the can's whole base, not a cone's cross-section
    bottom = recon.vertices[recon.vertices[:, 2] < recon.bounds[0, 2] + 5e-4]
    width_m = _true_can(stand_capture).extents[0]
    assert np.ptp(bottom[:, 0]) > 0.85 * width_m and np.ptp(bottom[:, 1]) > 0.85 * width_m


def test_a_support_height_that_is_not_a_number_is_one_line_and_exit_2(stand_capture, tmp_path, capsys):
    dataset = tmp_path / "bad"
    shutil.copytree(stand_capture, dataset, ignore=shutil.ignore_patterns("ground_truth"))
    edit_transforms(dataset, lambda data: {**data, "support_z_m": "low"})
    code = main(["run", str(dataset), "--out", str(tmp_path / "asset"), *FAST])
    err = capsys.readouterr().err
    assert code == 2 and "support_z_m must be a number" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "asset").exists()


def test_the_same_capture_with_a_table_plane_closes_the_bottom_at_z_0(stand_capture, tmp_path):
    dataset = tmp_path / "with_table"
    shutil.copytree(stand_capture, dataset, ignore=shutil.ignore_patterns("ground_truth"))
    data = json.loads((dataset / "transforms.json").read_text())
    del data["table_plane"], data["support_z_m"]
    (dataset / "transforms.json").write_text(json.dumps(data))
    asset = tmp_path / "asset"
    assert main(["run", str(dataset), "--out", str(asset), *FAST]) == 0
    support_m, how = _support(asset)
    assert support_m == 0.0 and how == "the dataset's table plane, z = 0 m"


def test_a_table_height_for_a_dataset_without_a_table_is_refused(stand_capture, tmp_path, capsys):
    code = main(["run", str(stand_capture), "--out", str(tmp_path / "asset"), "--table-z-m", "0.01", *FAST])
    err = capsys.readouterr().err
    assert code == 2 and "has no table plane" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "asset").exists()
