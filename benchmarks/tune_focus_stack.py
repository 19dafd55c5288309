"""Choose the settings of the methods without an all-in-focus photo on procedural scenes.

The relative blur (`RelativeBlurDepth`) and depth from focus (`DepthFromFocus`) were tuned here,
never on the cameras of `benchmarks/cameras.py` (the motorcycle is held out): 16 procedural scenes
(`datasets.synthetic.generate_scene`, 128x192) under random cameras (`datasets.capture.
random_camera`: 18-200 mm, f/1.2-f/8, disk and polygon PSFs, 2 or 3 shots), photographed with a
real sensor's imperfections (`CaptureNoise()`). For each variant it prints the median and mean
over scenes of the abs rel ratio to the best constant depth (lower is better).

Usage:

    python benchmarks/tune_focus_stack.py                       # the shipped settings
    python benchmarks/tune_focus_stack.py --variant '{"aggregation": "windows"}'
    python benchmarks/tune_focus_stack.py --size 256 384 --blur 20 60 --shots 3   # long lenses
    python benchmarks/tune_focus_stack.py --shots 3 --per-scene   # every scene's ratio
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from datasets.capture import capture, random_camera  # noqa: E402
from datasets.synthetic import generate_scene  # noqa: E402
from models import evaluate  # noqa: E402
from models.depth_from_photos import estimate_depth  # noqa: E402
from models.metrics import best_constant_depth, depth_metrics  # noqa: E402


def scenes(n: int, shots: int | None, seed: int = 1234, size: tuple[int, int] = (128, 192),
           blur_px: tuple[float, float] = (3.0, 20.0)):
    """`n` procedural tuning scenes (photos, settings, depth, range) of `size` pixels, `shots`
    per scene (2 or 3 alternately when None), the largest blur over each scene log-uniform in
    `blur_px` pixels."""
    rng = np.random.default_rng(seed)
    for k in range(n):
        near = float(rng.uniform(1.0, 3.0))
        far = near * float(rng.uniform(2.0, 5.0))
        image, depth = generate_scene(size, rng, (near, far))
        count = shots or 2 + k % 2
        settings = random_camera(rng, near, far, count, blur_px)
        aif, focused = capture(image, depth, settings, rng)
        yield aif, focused, settings, depth, (near * 0.8, far * 1.25)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="relative-blur", help="a method of estimate_depth")
    parser.add_argument("--variant", default="{}", help="JSON options of the method's class")
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--shots", type=int, default=None, help="shots per scene (default 2/3)")
    parser.add_argument("--size", type=int, nargs=2, default=(128, 192), metavar=("H", "W"),
                        help="scene size in pixels")
    parser.add_argument("--blur", type=float, nargs=2, default=(3.0, 20.0), metavar=("LO", "HI"),
                        help="range of each scene's largest blur in pixels (log-uniform); e.g. "
                             "20 60 for long lenses whose photos are read at a coarser scale")
    parser.add_argument("--max-coc-px", type=float, default=None,
                        help="largest blur (pixels) at the working resolution (default: the "
                             "method's)")
    parser.add_argument("--per-scene", action="store_true", help="print every scene's ratio")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    options = json.loads(args.variant)
    samples = [{"image": aif, "focused": focused, "camera": settings, "depth": depth,
                "mask": torch.ones_like(depth, dtype=torch.bool), "depth_range": depth_range}
               for aif, focused, settings, depth, depth_range in scenes(
                   args.scenes, args.shots, size=tuple(args.size), blur_px=tuple(args.blur))]

    def method(sample):
        return estimate_depth(sample["focused"], sample["camera"], sample["depth_range"],
                              method=args.method, options=options, all_in_focus=False,
                              max_coc_px=args.max_coc_px,
                              image=sample["image"] if args.method == "sweep" else None)["depth"]

    def ratio(depth, sample):
        """abs rel over the best constant depth's (of the scene's own ground truth)"""
        target, mask = sample["depth"], sample["mask"]
        constant = best_constant_depth(target=target, mask=mask)
        floor = depth_metrics(pred=torch.full_like(target, constant), target=target,
                              mask=mask)["abs_rel"]
        return {"ratio": depth_metrics(pred=depth, target=target, mask=mask)["abs_rel"] / floor}

    ratios = []

    def report(index, _, values):
        ratios.append(values["ratio"])
        if args.per_scene:
            settings = samples[index]["camera"]
            near, far = samples[index]["depth_range"]
            print(f"scene {index}: {samples[index]['focused'].shape[0]} shots, focus "
                  f"{', '.join(f'{d:.2f}' for d in settings.focus_distance.tolist())} m, "
                  f"f/{float(settings.f_number.reshape(-1)[0]):.1f}, depth {near:.2f}-"
                  f"{far:.2f} m: ratio {ratios[-1]:.3f}")

    evaluate(method, samples, ratio, report=report)
    print(f"{args.method} {options} max_coc_px={args.max_coc_px}: median "
          f"{statistics.median(ratios):.3f} mean {statistics.fmean(ratios):.3f} over "
          f"{len(ratios)} scenes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
