"""The report's pictures: one per representation and one of the visual mesh, same camera."""

from __future__ import annotations

from PIL import Image

from real2sim.report.pictures import asset_pictures


def test_one_picture_per_representation_and_the_visual(tmp_path):
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.objects import export_object

    mesh = export_object("can", tmp_path / "can" / "can.obj")
    from tests.progress_check import Recorder

    progress = Recorder()
    asset = build_asset(mesh, tmp_path / "can_asset",
                        AssetConfig(mass_kg=0.35, specs=(parse_spec("mesh"), parse_spec("coacd"))),
                        progress=progress).asset_dir
    assert any(m.startswith("collision coacd: ") for m, _, _ in progress.check(counted=False))
    written = asset_pictures(asset, tmp_path / "pictures", width_px=96, height_px=72)
    assert sorted(written) == ["coacd", "mesh", "visual"]
    images = {name: Image.open(path) for name, path in written.items()}
    assert all(im.size == (96, 72) for im in images.values())
    # Same camera: the mesh representation covers (nearly) the same pixels as the visual mesh.
    import numpy as np

    covered = {name: (np.asarray(im.convert("RGB")) != 255).any(axis=2) for name, im in images.items()}
    overlap = (covered["mesh"] & covered["visual"]).sum() / (covered["mesh"] | covered["visual"]).sum()
    assert overlap > 0.9
