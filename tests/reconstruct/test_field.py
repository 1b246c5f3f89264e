"""The voxel radiance field's renderer against the analytic case of a constant-density box
(Beer-Lambert opacity, expected depth, the decoder's colour), the occupancy that skips empty
space, and gradients reaching the grid tables."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import torch

from real2sim.reconstruct.field.radiance import VoxelRadianceField
from real2sim.multiview.voxel_grid import VoxelGrid

VOXEL = 0.01
SHAPE = (8, 6, 10)
GRID = VoxelGrid(origin_m=np.array([0.2, -0.1, 0.05]) + 0.5 * VOXEL, voxel_m=VOXEL, shape=SHAPE)
LO, HI = GRID.bounds_m
CENTRE = 0.5 * (LO + HI)


def _field(density: float, occupancy: np.ndarray | None = None, seed: int = 0) -> VoxelRadianceField:
    occ = np.ones(SHAPE, bool) if occupancy is None else occupancy
    return VoxelRadianceField(GRID, occ, feature_channels=6, hidden=16, init_density=density,
                              generator=torch.Generator().manual_seed(seed))


def _axis_ray(axis: int, start_before_m: float = 0.1, sign: float = 1.0):
    """A ray along +/- ``axis`` through the box centre, starting ``start_before_m`` outside the box."""
    direction = np.zeros(3)
    direction[axis] = sign
    origin = CENTRE.copy()
    origin[axis] = (LO[axis] - start_before_m) if sign > 0 else (HI[axis] + start_before_m)
    t_enter = start_before_m
    return origin, direction, t_enter


def _render(field, origins, directions, grad: bool = False, **kw):
    o = torch.tensor(np.atleast_2d(origins), dtype=torch.float32)
    d = torch.tensor(np.atleast_2d(directions), dtype=torch.float32)
    with torch.set_grad_enabled(grad):
        return field.render(o, d, **kw)


def _expected_depth(t0: float, length: float, sigma_per_m: float) -> float:
    """E[t | the ray stops in the box] for constant density: t0 + 1/sigma - L e^{-sigma L} / (1 - e^{-sigma L})."""
    e = np.exp(-sigma_per_m * length)
    return t0 + 1.0 / sigma_per_m - length * e / (1.0 - e)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("density", [0.02, 0.1, 0.3])
def test_constant_density_box_matches_beer_lambert(axis, density):
    """Opacity = 1 - exp(-d L / voxel) for a ray crossing length L of a box of density d per voxel;
    depth within half a sampling step of the analytic expected depth."""
    field = _field(density)
    origin, direction, t_enter = _axis_ray(axis)
    length = HI[axis] - LO[axis]
    step_voxels = 0.5
    out = _render(field, origin, direction, step_voxels=step_voxels)
    opacity = out.opacity[0].item()
    assert opacity == pytest.approx(1.0 - np.exp(-density * length / VOXEL), rel=1e-5)
    depth = float(out.depth_m[0]) / opacity  # the renderer's depth is sum(w t), weighted by opacity
    expected = _expected_depth(t_enter, length, density / VOXEL)
    step_m = step_voxels * VOXEL
    assert abs(depth - expected) <= 0.5 * step_m  # the spec: within half a step of the continuous depth
    # measured at most 6e-5 m (0.013 step, d = 0.3); samples off their step centres would miss by 0.5 step
    assert abs(depth - expected) <= 0.1 * step_m
    # from the other side, as far from the box, the same opacity and the same depth (the box is uniform)
    origin_b, direction_b, _ = _axis_ray(axis, sign=-1.0)
    out_b = _render(field, origin_b, direction_b, step_voxels=step_voxels)
    assert float(out_b.opacity[0]) == pytest.approx(opacity, rel=1e-5)
    assert float(out_b.depth_m[0]) / opacity == pytest.approx(depth, abs=1e-6)


def test_density_is_per_voxel_length_whatever_the_step():
    """A finer step renders the same opacity (the optical thickness of each step scales with it)."""
    field = _field(0.15)
    origin, direction, _ = _axis_ray(2)
    expected = 1.0 - np.exp(-0.15 * SHAPE[2])
    for step in (1.0, 0.5, 0.25, 0.1):
        assert float(_render(field, origin, direction, step_voxels=step).opacity[0]) == pytest.approx(expected, rel=1e-4)


def test_opaque_box_shows_the_decoders_colour():
    field = _field(5.0)
    features = torch.linspace(-2.0, 2.0, field.feature_channels)
    with torch.no_grad():
        field.feature_table.copy_(features.expand_as(field.feature_table))
    origin, direction, t_enter = _axis_ray(0)
    out = _render(field, origin, direction)
    with torch.no_grad():
        colour = field.colour(features[None], torch.tensor(direction[None], dtype=torch.float32))[0]
    assert float(out.opacity[0]) > 0.9999  # stops once the optical depth reaches 9: 1 - e^-10 here
    np.testing.assert_allclose(out.rgb[0].numpy(), colour.numpy(), atol=1e-3)
    assert float(colour.std()) > 0.01, "a constant grey would not tell colours apart"
    # an opaque surface is at the box's face (within a sampling step)
    assert abs(float(out.depth_m[0]) - t_enter) < 0.5 * VOXEL
    # the colour depends on the viewing direction through the decoder
    back, direction_b, _ = _axis_ray(0, sign=-1.0)
    out_b = _render(field, back, direction_b)
    with torch.no_grad():
        colour_b = field.colour(features[None], torch.tensor(direction_b[None], dtype=torch.float32))[0]
    np.testing.assert_allclose(out_b.rgb[0].numpy(), colour_b.numpy(), atol=1e-3)


def test_empty_occupancy_and_missed_rays_are_transparent():
    density = 0.2
    half = np.zeros(SHAPE, bool)
    half[: SHAPE[0] // 2] = True  # only the box's lower half in x may hold anything
    field = _field(density, half)
    origin, direction, t_enter = _axis_ray(0)
    out = _render(field, origin, direction)
    assert float(out.opacity[0]) == pytest.approx(1.0 - np.exp(-density * SHAPE[0] / 2), rel=1e-5)
    # a ray through the empty half only (along y at x in the upper half) sees nothing
    o = CENTRE.copy()
    o[0] = LO[0] + 0.75 * (HI[0] - LO[0])
    o[1] = LO[1] - 0.1
    out = _render(field, o, [0.0, 1.0, 0.0])
    assert float(out.opacity[0]) == 0.0 and float(out.rgb[0].abs().sum()) == 0.0
    # and rays that miss the box, or point away from it, see nothing either
    out = _render(field, [[0.0, 0.0, 1.0], origin.tolist()], [[1.0, 0.0, 0.0], (-direction).tolist()])
    assert out.opacity.tolist() == [0.0, 0.0]


def test_max_distance_cuts_the_ray():
    field = _field(0.1)
    origin, direction, t_enter = _axis_ray(0)
    cut = t_enter + 0.5 * (HI[0] - LO[0])  # half way through the box: half the optical depth
    out = _render(field, origin, direction, max_distance_m=cut)
    assert float(out.opacity[0]) == pytest.approx(1.0 - np.exp(-0.1 * SHAPE[0] / 2), rel=1e-4)


def test_jitter_keeps_opacity_and_moves_samples():
    """Jittered samples (training) see the same optical depth; their depths scatter about the analytic one."""
    field = _field(0.1)
    origin, direction, t_enter = _axis_ray(1)
    rays = 256
    o = torch.tensor(np.tile(origin, (rays, 1)), dtype=torch.float32)
    d = torch.tensor(np.tile(direction, (rays, 1)), dtype=torch.float32)
    with torch.no_grad():
        out = field.render(o, d, jitter=torch.rand(rays, generator=torch.Generator().manual_seed(1)))
    np.testing.assert_allclose(out.opacity.numpy(), 1.0 - np.exp(-0.1 * SHAPE[1]), rtol=1e-5)
    depth = (out.depth_m / out.opacity).numpy()
    # measured: standard deviation 1.4 mm (the step is 5 mm), mean 0.1 mm from the analytic depth
    assert depth.std() > 0.5e-3
    assert abs(depth.mean() - _expected_depth(t_enter, HI[1] - LO[1], 0.1 / VOXEL)) < 0.1 * 0.5 * VOXEL


def test_gradients_reach_the_grid_tables_and_decoder():
    field = _field(0.3)
    with torch.no_grad():
        field.feature_table.normal_(0.0, 0.5, generator=torch.Generator().manual_seed(2))
    origin, direction, _ = _axis_ray(2)
    out = _render(field, origin, direction, grad=True)
    loss = (out.rgb - torch.tensor([0.9, 0.1, 0.4])).pow(2).sum() + out.depth_m.sum()
    loss.backward()
    for name in ("density_table", "feature_table"):
        grad = getattr(field, name).grad
        assert grad is not None and torch.isfinite(grad).all(), name
        touched = grad.reshape(len(grad), -1).abs().sum(dim=1) > 0
        # a ray along z through the centre touches the four columns of voxels around it, no others
        assert 0 < int(touched.sum()) <= 4 * SHAPE[2], name
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in field.decoder.parameters())


def test_adam_on_the_compact_grid_is_adam_on_the_whole_grid():
    """compact_grid: the rows a render can read (the occupancy grown by one voxel) stepped alone give the
    same renders and the same tables as the whole grid stepped, and the grid takes their values back."""
    occupancy = np.zeros(SHAPE, bool)
    occupancy[2:6, 1:4, 3:8] = True  # a block inside the grid: the rest never lies on a sample
    rng = np.random.default_rng(3)
    origins = CENTRE + rng.normal(0.0, 0.01, (24, 3)) - [0.0, 0.0, 0.2]
    directions = np.tile([0.0, 0.0, 1.0], (24, 1)) + rng.normal(0.0, 0.05, (24, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    target = torch.tensor(rng.uniform(0.0, 1.0, (24, 3)), dtype=torch.float32)
    tables = {}
    for compact in (False, True):
        field = _field(0.3, occupancy)
        with torch.no_grad():
            field.feature_table.normal_(0.0, 0.5, generator=torch.Generator().manual_seed(2))
        initial = field.density_table.detach().clone()
        with field.compact_grid() if compact else contextlib.nullcontext() as params:
            params = params or (field.density_table, field.feature_table)
            opt = torch.optim.Adam(list(params), lr=0.05, fused=True)
            for _ in range(5):
                opt.zero_grad(set_to_none=True)
                (_render(field, origins, directions, grad=True).rgb - target).pow(2).mean().backward()
                opt.step()
            rendered = _render(field, origins, directions).rgb
        if compact:
            assert len(params[0]) < len(field.density_table)  # fewer rows than the grid
        tables[compact] = (field.density_table.detach().clone(), field.feature_table.detach().clone(), rendered,
                           _render(field, origins, directions).rgb)
        assert not torch.equal(field.density_table.detach(), initial)  # it trained
    for dense, compact in zip(tables[False], tables[True]):
        assert torch.allclose(dense, compact, rtol=1e-5, atol=1e-7)


def test_gradient_descent_on_the_grid_changes_opacity_as_asked():
    field = _field(0.1)
    origin, direction, _ = _axis_ray(2)
    before = _render(field, origin, direction).opacity.item()
    out = _render(field, origin, direction, grad=True)
    (-out.opacity.sum()).backward()  # ask for more opacity
    grad = field.density_table.grad
    assert (grad <= 0).all() and (grad < 0).sum() > 0  # more density anywhere on the ray = more opacity
    torch.optim.SGD([field.density_table], lr=10.0).step()
    after = _render(field, origin, direction).opacity.item()
    assert after > before + 0.01  # measured 0.632 -> 0.663


def test_upsampled_field_renders_the_same():
    """"The same field on a finer grid": a ray renders the same opacity and colour before and after."""
    field = _field(0.1)
    finer_grid = VoxelGrid(GRID.origin_m - 0.25 * VOXEL, 0.5 * VOXEL, tuple(2 * n for n in SHAPE))
    finer = field.upsampled(finer_grid, np.ones(finer_grid.shape, bool))
    origin, direction, _ = _axis_ray(0)
    a = _render(field, origin, direction)
    b = _render(finer, origin, direction)
    assert float(b.opacity[0]) == pytest.approx(float(a.opacity[0]), rel=1e-4)
    np.testing.assert_allclose(b.rgb.detach().numpy(), a.rgb.detach().numpy(), atol=1e-4)


def test_a_step_and_voxel_budget_halves_for_the_coarse_grid():
    """``reconstruct`` and ``run`` both build their field settings from --steps and --voxels this way."""
    from real2sim.plumbing.errors import UserInputError
    from real2sim.reconstruct.field.train import FieldConfig

    base = FieldConfig()
    assert base.with_budget() == base
    config = base.with_budget(steps=21, voxels=64)
    assert (config.fine_steps, config.coarse_steps, config.fine_voxels, config.coarse_voxels) == (21, 10, 64, 32)
    one = base.with_budget(steps=1, voxels=6)
    assert (one.coarse_steps, one.coarse_voxels) == (0, 4)  # one step skips the coarse grid, which stays valid
    one.validate()
    with pytest.raises(UserInputError):
        base.with_budget(voxels=3).validate()


def test_deep_photo_carved_space_is_left_out_at_every_resolution():
    """What carving opened, farther than the margin from what it kept, is not part of the field."""
    from real2sim.reconstruct.field.train import _deep_carved

    coarse = VoxelGrid.covering(np.zeros(3), np.full(3, 0.16), 16, 0.0)  # 1 cm voxels
    fine = VoxelGrid.covering(np.zeros(3), np.full(3, 0.16), 32, 0.0)
    carved = np.zeros(coarse.shape, bool)
    carved[3:13, 3:13, 3:13] = True  # a 10 cm cube
    deep = _deep_carved(carved, coarse, coarse, 2)
    assert deep.sum() == 6 ** 3 and deep[5:11, 5:11, 5:11].all()  # two voxels of margin kept on every side
    assert _deep_carved(carved, coarse, fine, 2).sum() == 8 * 6 ** 3  # the same 6 cm cube on the fine grid
    assert _deep_carved(carved, coarse, coarse, 0).sum() == carved.sum()
    assert not _deep_carved(carved, coarse, coarse, -1).any()  # a negative margin: the field keeps it all


def _render_and_gradients(device: str) -> list[np.ndarray]:
    """Colour, opacity, depth and the grid tables' gradients of 256 rays through a random, partly
    empty field (the same field and rays for every device)."""
    rng = np.random.default_rng(3)
    occupancy = rng.random(SHAPE) > 0.3
    density = rng.uniform(0.0, 0.8, SHAPE)
    features = rng.normal(0.0, 0.5, (int(np.prod(SHAPE)), 6)).astype(np.float32)
    origins = CENTRE + rng.normal(0.0, 0.02, (256, 3)) - np.array([0.0, 0.0, 0.2])
    directions = rng.normal(0.0, 0.15, (256, 3)) + np.array([0.0, 0.0, 1.0])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    field = VoxelRadianceField(GRID, occupancy, feature_channels=6, hidden=16, init_density=density,
                               device=device, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        field.feature_table.copy_(torch.from_numpy(features))
    out = field.render(torch.tensor(origins, dtype=torch.float32, device=device),
                       torch.tensor(directions, dtype=torch.float32, device=device))
    (out.rgb.sum() + out.opacity.sum() + out.depth_m.sum()).backward()
    assert out.rgb.device.type == device
    return [t.detach().cpu().numpy() for t in (out.rgb, out.opacity, out.depth_m,
                                               field.density_table.grad, field.feature_table.grad)]


@pytest.mark.cuda
def test_cuda_renders_and_differentiates_as_the_cpu():
    """The same field on CUDA gives the CPU's colour, opacity, depth and gradients (float32 sums in
    another order: 1e-4)."""
    if not torch.cuda.is_available():
        pytest.skip("needs a CUDA GPU")
    cpu, gpu = _render_and_gradients("cpu"), _render_and_gradients("cuda")
    assert cpu[1].max() > 0.5 and np.abs(cpu[3]).sum() > 0  # the rays cross the field, not only empty space
    for a, b in zip(cpu, gpu):
        np.testing.assert_allclose(b, a, atol=1e-4, rtol=1e-4)
