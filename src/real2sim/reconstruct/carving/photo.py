"""Photo-consistent carving: open the concavities that silhouettes cannot see (a mug's cavity).

The visual hull fills every concavity a silhouette cannot reveal: seen from any
side, a mug's cavity is hidden by its rim. The views that look down into it see
its floor and inner wall, and those disagree about the colour of any point of
the lid the hull puts across it: each view sees a different point behind it.
A point on the real surface looks nearly the same from every view that sees it.

So, as in space carving (Kutulakos and Seitz, 2000), voxels on the surface of
the current solid are tested against the views that see them (a ray from the
camera reaches the voxel before the current surface stops it) and removed when
those views disagree; removing them exposes the voxels behind, which are tested
in the next round, until no surface voxel is removed. The radiance field then
starts from the carved solid, because its gradients cannot open a cavity by
themselves (a filled cavity renders nearly like a lid with a painted top).

The test, per surface voxel: the colours at its projection in the views that
see it (images blurred over half a voxel's footprint), their per-channel
median, and each view's distance from it (RGB in [0, 1]); the *spread* is the
``spread_quantile`` of those distances, and the voxel disagrees when it exceeds
``max_spread`` and at least ``min_views`` views see it. These guards keep true
surfaces:

* brightness alone differs between views of a shiny or curved surface (the
  can's lid): a carve *starts* only where the hues disagree too (colour over
  brightness), and then grows through voxels next to what it removed, but not
  into a wall: a voxel that some views reach through the carved space and others
  from outside has two true faces whose colours differ (why:
  docs/design-notes/reconstruct.md#carving-guards);
* texture edges make isolated disagreeing voxels: a voxel goes only when most
  of the surface voxels around it disagree too;
* what is carved in the end is kept only in connected parts of at least
  ``min_component_fraction`` of the hull's volume;
* the silhouettes have the last word: a ray through a mask pixel that met the hull
  must still meet the carved solid, so carving that emptied such a ray gets put back
  (``mask_recheck``): where the views disagree for another reason than a concavity --
  poses a few millimetres off, which make every textured surface disagree -- carving
  would otherwise eat the object from the top down.

It stops early where the views inside a concavity agree for want of texture (a
deep cup's floor and lower wall, one flat colour, seen only from steep views):
there any depth looks the same from every view. So, once a concavity is open,
a second pass (*the hollow prior*, ``hollow_prior``) chooses the hollow shape where
the images cannot place a surface: a voxel of the concavity's surface goes when at least
``min_views`` views see it through the carved space, fewer than ``min_views``
from outside, it is more than ``min_wall_voxels`` from the visual hull's outside
and the table, and its views either look at featureless image (RGB contrast
below ``featureless_contrast`` over ``contrast_window_voxels`` footprints) or
disagree at least ``min_spread_to_contrast`` times as much as the image varies
there (a true textured surface is seen alike from every view), or would agree as well
(within ``depth_test_margin``) about a surface ``depth_test_voxels`` deeper along their
mean line of sight: views that cannot tell this depth from a deeper one do not place a
surface here, however much the image varies around (the *depth test*: a cup's plain
lower wall seen through its mouth, where the rim and a printed band make the contrast
high). Walls keep what
the silhouettes vouch for; the masks then judge the second pass on its own (a ray it
emptied gets back what it took). What each pass leaves, and how the ratio and the depth
test were chosen: docs/design-notes/reconstruct.md#hollow-prior. A concavity
the first pass never opens (no colour disagreement anywhere) stays filled.
World frame, metres; the lowest layer of voxels (standing on the table) is never carved.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import distance_transform_edt, gaussian_filter

from real2sim.plumbing.progress import ProgressFn
from real2sim.multiview.views import bilinear
from real2sim.reconstruct.carving.config import CarvingConfig
from real2sim.reconstruct.carving.verdict import CarvingScene, Verdict, voxel_verdicts
from real2sim.reconstruct.carving.views import cameras_on, occluder, sightings
from real2sim.multiview.voxel_grid import VoxelGrid, voxel_footprint_px, voxel_parts
from real2sim.reconstruct.carving.mask_recheck import put_back_for_masks
from real2sim.multiview.views import PosedViews


@dataclass(frozen=True)
class CarvingResult:
    """``solid``: bool (``grid.shape``), the carved solid; ``carved_voxels``; ``rounds`` run;
    ``restored_voxels``: carved voxels put back because the masks' rays needed them."""

    solid: np.ndarray
    carved_voxels: int
    rounds: int
    restored_voxels: int = 0
    opened_voxels: int = 0  # of ``carved_voxels``, those the second pass (the hollow prior) removed
    # each view's exposure and white balance (view_exposure.py): whether they were taken out, and how large
    exposure: dict | None = None


#: Parts of the carved solid smaller than this fraction of it, cut off from the rest, are dropped.
FLOATER_FRACTION = 0.01

def photo_carve(views: PosedViews, grid: VoxelGrid, solid: np.ndarray, config: CarvingConfig = CarvingConfig(),
                progress: ProgressFn | None = None, device: str = "cpu") -> CarvingResult:
    """Carve the photo-inconsistent surface voxels of ``solid`` (bool, ``grid.shape``) round by round.
    ``device``: where the rounds run (torch: the colour tests, the lines of sight and the grids' morphology;
    why: docs/design-notes/reconstruct.md#carving-speed)."""
    footprint_px = voxel_footprint_px(views, grid)
    images = _blurred(views.rgb, config.blur_voxels * footprint_px)
    cameras = cameras_on(views, device)
    origin = torch.as_tensor(grid.origin_m, dtype=torch.float64, device=device)
    original = torch.as_tensor(solid, device=device)
    now = original.clone()
    floor = torch.zeros_like(original)
    floor[:, :, 0] = True
    candidates = _surface(now) & ~floor
    exposure = None
    scene = CarvingScene(cameras, torch.as_tensor(images, device=device), grid, origin)
    if config.exposure_correction:
        images, exposure = _exposure_corrected(scene, images, candidates, now, config)
        if exposure["applied"]:  # the corrected images replace the uploaded ones
            scene = scene._replace(images=torch.as_tensor(images, device=device))
    rounds = 0
    for rounds in range(1, config.max_rounds + 1):
        if not bool(candidates.any()):
            break
        idx, verdict = _tested(scene, candidates, original, now, config)
        # a carve starts only where the views disagree in hue, and grows wherever they disagree
        # at all: brightness alone differs between views of a shiny or curved true surface
        inconsistent = (verdict.seen >= config.min_views) & (verdict.spread > config.max_spread)
        bad = _marked(original.shape, idx[inconsistent])
        hue_bad = _marked(original.shape, idx[inconsistent & (verdict.hue_spread > config.max_hue_spread)])
        grows = _face_dilated(original & ~now)
        # a voxel some views reach through the carved space and others from outside is a wall
        wall = idx[(verdict.through >= config.min_views) & (verdict.outside >= config.min_views)]
        grows[wall[:, 0], wall[:, 1], wall[:, 2]] = False
        carve = bad & (grows | hue_bad) & _mostly_bad_neighbourhood(bad, _surface(now), config.neighbour_fraction)
        if progress:
            progress("photo-consistent carving", rounds, config.max_rounds)
        if not bool(carve.any()):
            break
        now &= ~carve
        candidates = _surface(now) & _near(carve) & ~floor
    recheck = dict(band_voxels=config.restore_band_voxels, max_rounds=config.max_restore_rounds,
                   void_gap_voxels=config.void_gap_voxels, device=device)
    carved_solid = now.cpu().numpy()
    put_back = put_back_for_masks(views, grid, solid, carved_solid, **recheck)
    carved_solid |= put_back
    carved_solid |= _small_components(solid & ~carved_solid, config.min_component_fraction * solid.sum())
    restored, opened_count = int(put_back.sum()), 0
    if config.hollow_prior and (solid & ~carved_solid).any():
        contrast = torch.as_tensor(_local_contrast(images, config.contrast_window_voxels * footprint_px),
                                   device=device)
        opened = _open_concavity(scene, contrast, solid, carved_solid, floor, config, progress)
        # the masks judge the second pass on its own: a ray it emptied gets back what that pass took
        # from it (the concavity the first pass opened stays open)
        again = put_back_for_masks(views, grid, carved_solid, opened, **recheck)
        opened |= again
        opened_count, restored = int((carved_solid & ~opened).sum()), restored + int(again.sum())
        carved_solid = opened
    # A ray that lost a thin rim to carving gets back every carved voxel on it, specks in mid-air
    # included; what is left of them floating is no object.
    carved_solid &= ~_small_components(carved_solid, FLOATER_FRACTION * carved_solid.sum())
    return CarvingResult(solid=carved_solid, carved_voxels=int((solid & ~carved_solid).sum()), rounds=rounds,
                         restored_voxels=restored, opened_voxels=opened_count, exposure=exposure)


#: The surface voxels the exposure is estimated on, at most (evenly spread over the surface).
EXPOSURE_SAMPLE_VOXELS = 20_000


def _exposure_corrected(scene: CarvingScene, images: np.ndarray, surface: torch.Tensor, solid: torch.Tensor,
                        config: CarvingConfig) -> tuple[np.ndarray, dict]:
    """``images`` (``scene.images`` as an array) with each view's exposure and white balance divided out, as
    the views see the ``surface`` voxels of ``solid`` (:mod:`view_exposure`), and a report of the gains."""
    from real2sim.reconstruct.carving.view_exposure import corrected_images, gains_summary, view_gains

    idx = torch.nonzero(surface)
    idx = idx[::max(1, -(-len(idx) // EXPOSURE_SAMPLE_VOXELS))]
    view_of, point_of, pixel_uv, _ = sightings(scene.cameras, scene.grid, scene.points(idx),
                                               occluder(scene.grid, solid, config.visibility, solid.device),
                                               config.visibility_tolerance_voxels)
    colours = bilinear(scene.images, view_of, pixel_uv)
    gains, evidence = view_gains(colours.cpu().numpy(), view_of.cpu().numpy(), point_of.cpu().numpy(),
                                 scene.cameras.count, min_views=config.min_views)
    if not evidence["applied"]:
        return images, evidence
    return corrected_images(images, gains), {**evidence, **gains_summary(gains)}


def _tested(scene: CarvingScene, candidates: torch.Tensor, original: torch.Tensor, solid: torch.Tensor,
            config: CarvingConfig, contrast: torch.Tensor | None = None,
            behind_m: float = 0.0) -> tuple[torch.Tensor, Verdict]:
    """The indices (P, 3) of the ``candidates`` voxels and the views' :class:`Verdict` on each, seen
    against the current ``solid`` (carved so far: ``original & ~solid``)."""
    idx = torch.nonzero(candidates)
    sight = occluder(scene.grid, solid, config.visibility, solid.device)
    return idx, voxel_verdicts(scene, idx, sight, original & ~solid, config, contrast, behind_m)


def _open_concavity(scene: CarvingScene, contrast: torch.Tensor, original: np.ndarray, solid: np.ndarray,
                    floor: torch.Tensor, config: CarvingConfig, progress: ProgressFn | None) -> np.ndarray:
    """``solid`` (a copy) with the space behind an opened concavity that the images cannot place a
    surface in removed, round by round (the hollow prior of the module docstring). ``contrast``:
    :func:`_local_contrast` of the images; ``floor``: voxels never carved."""
    device = floor.device
    # the wall the silhouettes vouch for: near the hull's outside, or near the table under it
    wall = distance_transform_edt(np.pad(original, 1))[1:-1, 1:-1, 1:-1] <= config.min_wall_voxels
    keep = floor | torch.as_tensor(wall, device=device)
    original_t, now = torch.as_tensor(original, device=device), torch.as_tensor(solid, device=device).clone()
    candidates = _surface(now) & _face_dilated(original_t & ~now) & ~keep
    for rounds in range(1, config.max_rounds + 1):
        if not bool(candidates.any()):
            break
        idx, verdict = _tested(scene, candidates, original_t, now, config, contrast,
                               behind_m=config.depth_test_voxels * scene.grid.voxel_m)
        unplaced = (verdict.contrast < config.featureless_contrast) | \
            (verdict.spread >= config.min_spread_to_contrast * verdict.contrast)
        if verdict.behind is not None:
            unplaced |= verdict.behind <= verdict.spread + config.depth_test_margin
        open_ = (verdict.through >= config.min_views) & (verdict.outside < config.min_views) & unplaced
        if progress:
            progress("hollow prior", rounds, config.max_rounds)
        if not bool(open_.any()):
            break
        carve = _marked(now.shape, idx[open_])
        now &= ~carve
        candidates = _surface(now) & _near(carve) & ~keep
    return now.cpu().numpy()


def _small_components(carved: np.ndarray, min_voxels: float) -> np.ndarray:
    """The connected parts (26-neighbours) of ``carved`` smaller than ``min_voxels`` (carved parts to
    put back; applied to the solid, floaters to drop).

    Shading and highlights that differ between views (a can's shiny lid) make small
    inconsistent patches that carving deepens into pits; a concavity that changes how
    an object moves is a large share of its volume.
    """
    labels, sizes = voxel_parts(carved)
    small = sizes < min_voxels
    small[0] = False
    return small[labels]


def _blurred(rgb: np.ndarray, sigma_px: float) -> np.ndarray:
    if sigma_px <= 0:
        return rgb
    return gaussian_filter(rgb, sigma=(0, sigma_px, sigma_px, 0)).astype(np.float32)


def _marked(shape: tuple, idx: torch.Tensor) -> torch.Tensor:
    """A bool grid of ``shape`` set at the voxels ``idx`` (P, 3)."""
    grid = torch.zeros(shape, dtype=torch.bool, device=idx.device)
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    return grid


def _shifted_along(grid: torch.Tensor, axis: int, radius: int, combine, outside: int = 0) -> torch.Tensor:
    """``combine`` (an elementwise reduction) of ``grid`` shifted by -radius..radius along ``axis``; beyond
    the grid the values are ``outside``."""
    pad = [0] * 6
    pad[2 * (2 - axis)] = pad[2 * (2 - axis) + 1] = radius
    padded = torch.nn.functional.pad(grid, pad, value=outside)
    n = grid.shape[axis]
    out = padded.narrow(axis, 0, n)
    for k in range(1, 2 * radius + 1):
        out = combine(out, padded.narrow(axis, k, n))
    return out


def _face_neighbour(grid: torch.Tensor, outside: bool = False) -> torch.Tensor:
    """Whether any of each voxel's six face neighbours is set in ``grid`` (bool); beyond it counts as ``outside``."""
    padded = torch.nn.functional.pad(grid.to(torch.uint8), (1, 1, 1, 1, 1, 1), value=int(outside))
    return (padded[:-2, 1:-1, 1:-1] | padded[2:, 1:-1, 1:-1] | padded[1:-1, :-2, 1:-1] | padded[1:-1, 2:, 1:-1]
            | padded[1:-1, 1:-1, :-2] | padded[1:-1, 1:-1, 2:]) > 0


def _face_dilated(grid: torch.Tensor) -> torch.Tensor:
    """``grid`` (bool) grown by its face neighbours (scipy's ``binary_dilation`` with the 6-neighbour cross)."""
    return grid | _face_neighbour(grid)


def _surface(solid: torch.Tensor) -> torch.Tensor:
    """Voxels of ``solid`` (bool) with an empty face neighbour (outside the grid counts as empty)."""
    return solid & _face_neighbour(~solid, outside=True)


def _near(removed: torch.Tensor) -> torch.Tensor:
    """Voxels within two (26-neighbour steps) of ``removed``: only those can change verdict after a
    round: the newly exposed ones and those that now see more views. Both passes use it, rather than
    the face neighbours alone (why: docs/design-notes/reconstruct.md#retesting)."""
    grown = removed.to(torch.uint8)
    for axis in range(3):  # the 5x5x5 box, one axis at a time
        grown = _shifted_along(grown, axis, 2, torch.maximum)
    return grown > 0


def _mostly_bad_neighbourhood(bad: torch.Tensor, surface: torch.Tensor, fraction: float) -> torch.Tensor:
    """Where at least ``fraction`` of the surface voxels in the 3x3x3 neighbourhood are ``bad``."""
    def count(grid):
        total = grid.to(torch.int16)
        for axis in range(3):
            total = _shifted_along(total, axis, 1, torch.add)
        return total.to(torch.float32)

    return count(bad) >= fraction * torch.clamp(count(surface), min=1.0)


def _local_contrast(images: np.ndarray, window_px: float) -> np.ndarray:
    """Per pixel (V, H, W): the RGB standard deviation (norm over channels) over a square window
    ``window_px`` wide: how well a view can tell one depth of a surface from another there."""
    from scipy.ndimage import uniform_filter

    width = max(3, int(round(window_px)) | 1)
    contrast = np.empty(images.shape[:3], np.float32)
    for i, image in enumerate(images):  # a view at a time: whole-stack temporaries were 1 GB at 640x480
        mean = uniform_filter(image, size=(width, width, 1))
        mean_sq = uniform_filter(image * image, size=(width, width, 1))
        contrast[i] = np.sqrt(np.clip(mean_sq - mean * mean, 0.0, None).sum(axis=-1))
    return contrast


