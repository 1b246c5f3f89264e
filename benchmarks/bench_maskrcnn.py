"""Mask R-CNN (torchvision ResNet-50 FPN) inference time per image on this machine.

Weights: seeded random ones (real2sim never downloads; the COCO file is the user's),
so this measures speed, not mask quality. Random weights give few confident
detections, so the box/mask heads run on few instances: a lower bound for COCO
weights on a cluttered image. Images: a capture of the bundled can at 640x480.

    python benchmarks/bench_maskrcnn.py [--images 3] [--sizes 800 480 240]

Writes benchmarks/results/maskrcnn.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_result  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--images", type=int, default=3, help="timed images per size (default 3)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[800, 480, 240], help="short-side resize, px")
    parser.add_argument("--full", action="store_true", help="accepted for run_all.py; same as the default")
    args = parser.parse_args()

    import numpy as np
    import torch
    from PIL import Image

    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.formats.dataset import read_dataset
    from real2sim.capture.masks.methods import MaskConfig, load_maskrcnn, maskrcnn_mask
    from real2sim.geometry.objects import make_textured_object
    from real2sim.capture.masks.torchvision_compat import compiled_ops_loaded, import_maskrcnn_builder

    work = Path(tempfile.mkdtemp(prefix="bench_maskrcnn-"))
    root = work / "can"
    capture(make_textured_object("can"), root, CaptureConfig(views=args.images + 1, width=640, height=480, seed=0))
    ds = read_dataset(root)
    images = [np.asarray(Image.open(root / f.file_path).convert("RGB")) for f in ds.frames]

    builder = import_maskrcnn_builder()
    torch.manual_seed(0)
    weights = work / "maskrcnn_random.pth"
    torch.save(builder(weights=None, weights_backbone=None, num_classes=91).state_dict(), weights)

    rows = []
    for size in args.sizes:
        cfg = MaskConfig(mask_weights=weights, maskrcnn_min_size_px=size, maskrcnn_max_size_px=max(size, 1333))
        model = load_maskrcnn(weights, "cpu", cfg.maskrcnn_min_size_px, cfg.maskrcnn_max_size_px,
                              cfg.score_threshold, cfg.maskrcnn_max_instances)
        start = time.perf_counter()
        maskrcnn_mask(model, images[0], cfg)  # the first call pays torch.compile of roi_align
        first_s = time.perf_counter() - start
        times = []
        for image in images[1:]:
            start = time.perf_counter()
            maskrcnn_mask(model, image, cfg)
            times.append(time.perf_counter() - start)
        rows.append([size, first_s, float(np.mean(times)), float(np.max(times))])
        print(rows[-1], flush=True)

    body = (
        f"Mask R-CNN ResNet-50 FPN, seeded random weights (91 classes), {len(images) - 1} timed 640x480 "
        f"images of the bundled can per resize, after one warm-up image (its time is the first column). "
        f"torch threads: {torch.get_num_threads()}. torchvision compiled ops loaded: "
        f"{compiled_ops_loaded()} (False: our NMS and roi_align by grid_sample, see "
        "real2sim.capture.masks.torchvision_compat). Random weights keep few detections, so the heads run on few "
        "instances: real COCO weights on a cluttered image cost more.\n\n"
        + markdown_table(["short side px", "first image s", "mean s / image", "max s / image"], rows)
    )
    path = write_result("maskrcnn", "Mask R-CNN inference (CPU)", body,
                         "python benchmarks/bench_maskrcnn.py " + " ".join(sys.argv[1:]))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
