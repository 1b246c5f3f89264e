"""Import torchvision's Mask R-CNN builder, also where torchvision's compiled ops cannot load.

Why this exists: on these machines torch is a CPU build (``torch==2.13.0+cpu``) and
the only torchvision wheel for it (0.28.0) is a CUDA build. Its compiled extension
``torchvision/_C.so`` needs ``libc10_cuda.so`` and fails to load; torchvision then
treats its custom ops as missing, and ``import torchvision`` itself fails
(``RuntimeError: operator torchvision::nms does not exist``), because
``torchvision/_meta_registrations.py`` registers fake kernels for ``torchvision::nms``
and ``torchvision::qnms`` whether or not the ops exist.

Mask R-CNN inference needs only two of torchvision's compiled ops:

- ``roi_align``: torchvision falls back to its own pure-PyTorch version when the ops
  are missing, but wraps it in ``torch.compile`` on its first call: seconds of
  compilation in every process and, on CPU, a C++ compiler the user may not have;
  uncompiled, its gather of every sample of every channel is slow
  (docs/design-notes/capture.md#mask-r-cnn-roi-align). Where the sampling grid is fixed
  (Mask R-CNN's poolers: 2 x 2 samples per bin) :func:`roi_align_by_grid_sample` computes
  the same bilinear samples with ``torch.nn.functional.grid_sample`` (one call per image;
  equal to torchvision's to float rounding, ``tests/capture/test_masking_maskrcnn.py``);
  adaptive sampling goes to torchvision's function, uncompiled.
- ``nms``: has no fallback. :func:`torchvision.ops.boxes.nms` calls
  ``_assert_has_ops()`` and then ``torch.ops.torchvision.nms``.

So, only when the plain import fails for exactly that reason (or imports with the ops
missing), :func:`import_maskrcnn_builder`:

1. defines ``torchvision::nms`` and ``torchvision::qnms`` with ``torch.library``
   (torchvision's schemas) and registers our own greedy NMS (:func:`greedy_nms`) for
   every backend (``CompositeExplicitAutograd``: CPU, and CUDA tensors where a CUDA
   torch meets a broken torchvision); torchvision's own fake kernels then register
   on top of them at import, as designed;
2. re-imports torchvision from scratch;
3. replaces the name ``_assert_has_ops`` inside ``torchvision.ops.boxes`` only (the
   least invasive change we found: one module attribute, no torchvision function
   replaced) with a check that lets the call through when it comes from
   ``torchvision.ops.boxes.nms`` -- whose ops now exist -- and otherwise defers to
   torchvision's original check, so every other compiled op (rotated-box IoU,
   deform_conv2d, ...) still fails with torchvision's own clear message.
   ``torchvision.extension._has_ops()`` stays False, which keeps roi_align on its
   pure-PyTorch path.

Where torchvision's ops load normally (a GPU machine with matching builds), the plain
import succeeds and nothing here touches torchvision. Calling it again is a no-op; a
lock serialises the set-up within a process.
"""

from __future__ import annotations

import sys
import threading
from typing import Callable

import numpy as np

from real2sim.plumbing.errors import UserInputError

_INSTALL_HINT = "pip install -e '.[maskrcnn]'"
_lock = threading.Lock()
# torch.library.Library objects unregister their ops when garbage-collected: keep them.
_libraries: list = []
_shim_installed = False
# The IoU block is at most this many elements (rows x candidate columns) at a time.
_MAX_BLOCK_ELEMENTS = 1 << 22


def greedy_nms(boxes, scores, iou_threshold: float):
    """Greedy non-maximum suppression with torchvision's semantics.

    ``boxes``: (N, 4) tensor (x1, y1, x2, y2), any units; ``scores``: (N,). Boxes are
    visited by decreasing score (equal scores: lower index first); a box is kept unless
    a kept box of higher rank overlaps it with IoU > ``iou_threshold``. Returns the
    kept indices (int64, on the boxes' device), by decreasing score. IoU is computed
    in the boxes' dtype as inter / (area_a + area_b - inter) with unclamped areas,
    so zero-area boxes (0 / 0 = NaN) suppress nothing and are never suppressed.

    The IoU of each block of rows against the not-yet-suppressed later boxes is one
    tensor operation; only the resolution of suppressions inside a block is a loop
    (over kept boxes), on a boolean array.
    """
    import torch

    if boxes.dim() != 2 or boxes.shape[1] != 4:
        raise RuntimeError(f"boxes should be a (N, 4) tensor, got shape {tuple(boxes.shape)}")
    if scores.dim() != 1 or scores.shape[0] != boxes.shape[0]:
        raise RuntimeError(f"scores should be a (N,) tensor matching {boxes.shape[0]} boxes, got {tuple(scores.shape)}")
    n = boxes.shape[0]
    if n == 0:
        return torch.empty(0, dtype=torch.long, device=boxes.device)
    order = torch.argsort(scores, descending=True, stable=True)
    b = boxes[order]
    if not b.is_floating_point():
        b = b.double()
    x1, y1, x2, y2 = b.unbind(1)
    area = (x2 - x1) * (y2 - y1)
    removed = np.zeros(n, dtype=bool)
    keep: list[int] = []
    start = 0
    while start < n:
        # Rows per block so that rows x remaining candidates stays bounded.
        candidates = np.flatnonzero(~removed[start:]) + start
        if candidates.size == 0:
            break
        rows_per_block = max(1, min(n - start, _MAX_BLOCK_ELEMENTS // candidates.size))
        stop = start + rows_per_block
        rows = candidates[candidates < stop]
        cols = candidates
        r = torch.from_numpy(rows).to(b.device)
        c = torch.from_numpy(cols).to(b.device)
        w = (torch.minimum(x2[r, None], x2[None, c]) - torch.maximum(x1[r, None], x1[None, c])).clamp(min=0)
        h = (torch.minimum(y2[r, None], y2[None, c]) - torch.maximum(y1[r, None], y1[None, c])).clamp(min=0)
        inter = w * h
        over = ((inter / ((area[r, None] + area[None, c]) - inter)) > iou_threshold).cpu().numpy()
        for k, i in enumerate(rows):
            if removed[i]:
                continue  # suppressed by an earlier row of this block
            keep.append(int(i))
            hit = cols[over[k]]
            removed[hit[hit > i]] = True
        start = stop
    return order[torch.as_tensor(keep, dtype=torch.long, device=b.device)]


def _greedy_qnms(dets, scores, iou_threshold: float):
    """qnms on the integer representations torchvision passes (boxes and scores as ints)."""
    return greedy_nms(dets.double(), scores.double(), iou_threshold)


def _op_exists(name: str) -> bool:
    import torch

    try:
        getattr(torch.ops.torchvision, name)
    except (AttributeError, RuntimeError):
        return False
    return True


def _define_nms_ops() -> None:
    """Define torchvision::nms and torchvision::qnms with our kernels, unless they exist."""
    import torch

    missing = [name for name in ("nms", "qnms") if not _op_exists(name)]
    if not missing:
        return
    lib = torch.library.Library("torchvision", "FRAGMENT")
    kernels = {"nms": greedy_nms, "qnms": _greedy_qnms}
    for name in missing:
        lib.define(f"{name}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
        # CompositeExplicitAutograd covers every backend (CPU, CUDA) but not Meta, where
        # torchvision registers its own fake kernel at import.
        lib.impl(name, kernels[name], "CompositeExplicitAutograd")
    _libraries.append(lib)


def _install_nms_check_shim() -> None:
    """Let torchvision.ops.boxes.nms past ``_assert_has_ops``; every other caller keeps the original check."""
    global _shim_installed
    import torchvision.ops.boxes as boxes_module

    if _shim_installed or getattr(boxes_module._assert_has_ops, "_real2sim_nms_shim", False):
        _shim_installed = True
        return
    original = boxes_module._assert_has_ops
    nms_code = boxes_module.nms.__code__

    def _assert_has_ops() -> None:
        if sys._getframe(1).f_code is nms_code:
            return  # torchvision::nms is ours (defined by real2sim.capture.masks.torchvision_compat)
        original()

    _assert_has_ops._real2sim_nms_shim = True
    boxes_module._assert_has_ops = _assert_has_ops
    _shim_installed = True


def roi_align_by_grid_sample(input, rois, spatial_scale: float, pooled_height: int, pooled_width: int,
                             sampling_ratio: int, aligned: bool, *, adaptive=None):
    """torchvision's pure-PyTorch ``_roi_align`` (same arguments, same result) for ``sampling_ratio > 0``.

    Each bin's ``sampling_ratio`` x ``sampling_ratio`` sample points are placed as torchvision places
    them; its bilinear lookup clamps a point to the feature map's edge pixels, which is
    ``grid_sample``'s border padding with ``align_corners=True`` (pixel centres at integer
    coordinates). ``adaptive``: the function used for ``sampling_ratio <= 0``.
    """
    import torch
    import torch.nn.functional as F

    if sampling_ratio <= 0:
        return adaptive(input, rois, spatial_scale, pooled_height, pooled_width, sampling_ratio, aligned)
    batch, channels, height, width = input.shape
    rois = rois.to(input.dtype)
    offset = 0.5 if aligned else 0.0
    start = rois[:, 1:3] * spatial_scale - offset  # (K, 2): x, y
    size = rois[:, 3:5] * spatial_scale - offset - start
    if not aligned:
        size = size.clamp(min=1.0)
    bins = torch.tensor([pooled_width, pooled_height], dtype=input.dtype, device=input.device)
    bin_size = size / bins  # (K, 2)
    # sample positions along x (K, PW * S) and y (K, PH * S): bin p, sample i at start + (p + (i + 0.5) / S) bin
    steps_x = (torch.arange(pooled_width * sampling_ratio, device=input.device, dtype=input.dtype) + 0.5) / sampling_ratio
    steps_y = (torch.arange(pooled_height * sampling_ratio, device=input.device, dtype=input.dtype) + 0.5) / sampling_ratio
    xs = start[:, 0:1] + steps_x[None] * bin_size[:, 0:1]
    ys = start[:, 1:2] + steps_y[None] * bin_size[:, 1:2]
    gx = 2.0 * xs / (width - 1) - 1.0 if width > 1 else torch.zeros_like(xs)
    gy = 2.0 * ys / (height - 1) - 1.0 if height > 1 else torch.zeros_like(ys)
    k = len(rois)
    grid = torch.stack((gx[:, None, :].expand(k, gy.shape[1], gx.shape[1]),
                        gy[:, :, None].expand(k, gy.shape[1], gx.shape[1])), dim=-1)  # (K, PH S, PW S, 2)
    out = input.new_zeros((k, channels, pooled_height, pooled_width))
    image_of_roi = rois[:, 0].long()
    for b in range(batch):
        index = torch.nonzero(image_of_roi == b).flatten()
        if not len(index):
            continue
        g = grid[index].reshape(1, -1, grid.shape[2], 2)  # the image's rois stacked along the grid's height
        samples = F.grid_sample(input[b:b + 1], g, mode="bilinear", padding_mode="border", align_corners=True)
        samples = samples.reshape(channels, len(index), pooled_height, sampling_ratio, pooled_width, sampling_ratio)
        out[index] = samples.mean(dim=(3, 5)).permute(1, 0, 2, 3)
    return out


def _use_fast_roi_align() -> None:
    """torchvision's pure-PyTorch roi_align replaced by :func:`roi_align_by_grid_sample` (module docstring)."""
    import functools

    # the module, not the function torchvision.ops exports under the same name
    roi_module = sys.modules["torchvision.ops.roi_align"]
    fallback = roi_module._roi_align
    if getattr(fallback, "_real2sim_grid_sample", False):
        return
    # torchvision's function, without its lazy torch.compile wrapper (functools.wraps keeps it as __wrapped__)
    adaptive = getattr(fallback, "__wrapped__", fallback)

    @functools.wraps(adaptive)
    def wrapper(*args):
        return roi_align_by_grid_sample(*args, adaptive=adaptive)

    wrapper._real2sim_grid_sample = True
    roi_module._roi_align = wrapper


def _forget_torchvision() -> None:
    """Drop a half-imported torchvision so that the next import starts clean."""
    for name in [m for m in sys.modules if m == "torchvision" or m.startswith("torchvision.")]:
        del sys.modules[name]


def _ops_missing_error(exc: BaseException) -> bool:
    """True when ``exc`` is torchvision's import failing because its compiled ops did not load."""
    ext = sys.modules.get("torchvision.extension")
    return (isinstance(exc, RuntimeError) and "operator torchvision::" in str(exc)
            and "does not exist" in str(exc) and ext is not None and not ext._has_ops())


def ensure_torchvision():
    """Import torchvision (patched as in the module docstring only when its compiled ops are missing).

    Returns the ``torchvision`` module. Raises :class:`UserInputError` when torchvision is
    not installed or cannot be imported for another reason.
    """
    with _lock:
        try:
            import torchvision
        except ImportError as exc:
            raise UserInputError(
                f"--method maskrcnn needs torchvision, which is not installed ({_INSTALL_HINT}; "
                f"or use --method background / provided): {exc}") from None
        except RuntimeError as exc:
            if not _ops_missing_error(exc):
                raise UserInputError(f"torchvision is installed but cannot be imported: {str(exc).splitlines()[0]}"
                                     ) from None
            _forget_torchvision()
            _define_nms_ops()
            try:
                import torchvision
            except (ImportError, RuntimeError) as exc2:
                raise UserInputError("torchvision's compiled ops are missing and importing it without them failed "
                                     f"too: {str(exc2).splitlines()[0]}") from None
        if not torchvision.extension._has_ops():
            _define_nms_ops()  # no-op when the failed-import path above defined them
            _install_nms_check_shim()
            _use_fast_roi_align()
        return torchvision


def compiled_ops_loaded() -> bool:
    """True when torchvision's own compiled ops loaded (our NMS is not in use)."""
    return bool(ensure_torchvision().extension._has_ops())


def import_maskrcnn_builder() -> Callable:
    """torchvision's ``maskrcnn_resnet50_fpn``, importable on a CPU-only torch (see module docstring)."""
    ensure_torchvision()
    from torchvision.models.detection import maskrcnn_resnet50_fpn

    return maskrcnn_resnet50_fpn
