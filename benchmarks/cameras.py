"""Depth from your own photos, measured: the shipped model on a real scene through many cameras.

The real Middlebury motorcycle scene (scikit-image; real depth 2.1-5.0 m from its disparity) is
photographed by `datasets.capture.capture` through each camera below: a disk or iris-polygon PSF,
the occlusion-aware layered renderer, shot and read noise, 8-bit sRGB, small exposure and
white-balance differences and up to a pixel of misalignment between shots. None of these cameras
was used to choose the model's settings. For each camera it prints abs rel and delta1 of

- `sweep`: `models.depth_from_photos.SweepDepth`, the default of `defocus predict` (no
  network), through `estimate_depth` (the working resolution chosen from the camera and the
  depth range, the shots aligned first),
- `pretrained`: the experimental camera-general network's weights (`--weights`, written by
  `examples/blur_net.py`), the same way, and
- with `--stacks`, the all-in-focus photo withheld: `pair`, the relative blur of the two shots
  (`estimate_depth(method="relative-blur")`), `stack3`, the same with a third shot (`--third`:
  focused midway between the two in inverse depth, or one step of their spacing nearer), and
  `focus3`, depth from focus of those three (`method="focus"`),
- `direct`: `models.direct.fit_depth_direct` through the renderer at the sweep's resolution, told
  the camera and the PSF, the shots aligned first (no network; slow),

next to the best constant depth (an oracle chosen on the ground truth), the ratio to it, and the
seconds each took (one thread). `--oracle` adds the bound of the blur-reading network's design:
the thin-lens solve (`models.depth_from_photos.solve_depth`) fed the true blur of every shot at the working
resolution, i.e. what a perfect blur reader would reach. For the methods with a confidence map
it also prints how well that ranks the errors: the mean error of the more confident half of the
pixels over the mean error (1 is no better than chance). Goal: abs rel <= 0.3x the constant's for
every camera, <= 0.06 at the demo camera, inference under 1 s at 185x125 on one thread.

Usage:

    python benchmarks/cameras.py --no-direct   # the sweep only (a minute)
    python benchmarks/cameras.py --weights runs/blur_net/dfd_general.pt   # everything
    python benchmarks/cameras.py --weights W.pt --no-direct --oracle   # and a perfect reader
    python benchmarks/cameras.py --cameras demo --photos perfect   # what imperfections cost
    python benchmarks/cameras.py --no-direct --jpeg 90   # photos saved as JPEGs of quality 90
    python benchmarks/cameras.py --no-direct --stacks    # and without the all-in-focus photo
    python benchmarks/cameras.py --no-direct --stacks --third nearer   # the third shot nearer
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from datasets.capture import CaptureNoise, capture  # noqa: E402
from datasets.middlebury import motorcycle_scene  # noqa: E402
from models.depth_from_photos import (  # noqa: E402
    DepthFromDefocus,
    SweepDepth,
    estimate_depth,
    solve_depth,
    texture_weight,
    working_scale,
)
from models.depth_from_photos.resolution import to_working_resolution  # noqa: E402
from models.metrics import (  # noqa: E402
    best_constant_depth,
    confident_half_error,
    depth_metrics,
)
from optics import CameraSettings, align_shots  # noqa: E402

#: name -> (focal length m, f-number, focus distances m, sensor width m (full 741 px), PSF)
CAMERAS = {
    "demo 50mm f/1.4 (2, 6 m)": (0.050, 1.4, (2.0, 6.0), 180e-6 * 185, "disk"),
    "35mm f/2 (1.2, 3 m) FF": (0.035, 2.0, (1.2, 3.0), 0.036, "polygon:6"),
    "85mm f/2.8 (3, 8 m) FF": (0.085, 2.8, (3.0, 8.0), 0.036, "disk"),
    "24mm f/1.4 (1.5, 4 m) APS-C": (0.024, 1.4, (1.5, 4.0), 0.0235, "polygon:9"),
    "135mm f/4 (4, 12 m) FF": (0.135, 4.0, (4.0, 12.0), 0.036, "polygon:7"),
    "18mm f/1.2 (1, 2.5 m) M43": (0.018, 1.2, (1.0, 2.5), 0.0173, "disk"),
    "200mm f/8 (5, 15 m) FF": (0.200, 8.0, (5.0, 15.0), 0.036, "polygon:5"),
}
#: The depth range a user would state for the scene (metres).
DEPTH_RANGE = (1.0, 15.0)
#: `--photos`: how perfect the camera is (what each imperfection costs each method).
PHOTOS = {
    "real": CaptureNoise(),
    "noise-only": CaptureNoise(exposure=0.0, white_balance=0.0, shift_px=0.0),
    "perfect": CaptureNoise.none(),
}


#: `--third`: where the third shot of `stack3` and `focus3` is focused, in inverse depth.
THIRD_SHOT = {"midway": "midway between the two shots (inside the pair's span)",
              "nearer": "one step of the pair's spacing nearer than the near shot (extending "
                        "the bracket towards the camera, as focus bracketing does)",
              "range": "midway through the stated depth range `DEPTH_RANGE` (a shot inside "
                       "the range whatever the pair)"}


def third_focus(focus: tuple[float, float], placement: str = "midway") -> float:
    """The focus distance (metres) a third shot adds to the pair `focus` (near, far), by
    `placement` (`THIRD_SHOT`).

    Example:
        >>> tuple(round(third_focus((5.0, 15.0), p), 2) for p in ("midway", "nearer", "range"))
        (7.5, 3.0, 1.88)
    """
    if placement not in THIRD_SHOT:
        raise ValueError(f"placement must be one of {sorted(THIRD_SHOT)}, got {placement!r}")
    near, far = (1 / d for d in (DEPTH_RANGE if placement == "range" else focus))
    return 1 / (2 * near - far) if placement == "nearer" else 2 / (near + far)


def photograph(name: str, seed: int = 0, scale: float = 1.0,
               noise: CaptureNoise = PHOTOS["real"], shots: int = 2,
               third: str = "midway") -> dict:
    """The motorcycle through camera `name`: photos, settings and ground truth; with
    `shots=3` a third shot focused at `third_focus(..., third)`, second in the stack."""
    f, n, focus, sensor_width, psf = CAMERAS[name]
    if shots == 3:
        focus = (focus[0], third_focus(focus, third), focus[1])
    if name.startswith("demo"):  # the demo's own resolution: 185x125 at 180 um
        scale = 0.25
    image, depth, mask = (t[0] for t in motorcycle_scene(scale))
    settings = CameraSettings(f, n, list(focus), sensor_width / image.shape[-1], aperture=psf)
    aif, focused = capture(image, depth, settings, np.random.default_rng(seed), noise)
    return {"image": aif, "focused": focused, "settings": settings.to(torch.float32),
            "depth": depth, "mask": mask}


def run_model(model, shot: dict) -> tuple[torch.Tensor, float, torch.Tensor]:
    """`(depth, seconds, confidence)` of `estimate_depth` with `model`."""
    started = time.perf_counter()
    out = estimate_depth(shot["focused"], shot["settings"], DEPTH_RANGE, image=shot["image"],
                         model=model, all_in_focus=False)
    return out["depth"], time.perf_counter() - started, out["confidence"]


def ranking_of(depth: torch.Tensor, confidence: torch.Tensor, shot: dict) -> float:
    """`models.metrics.confident_half_error` of the abs rel errors over the valid pixels."""
    valid = shot["mask"].bool()
    error = ((depth - shot["depth"]).abs() / shot["depth"])[valid]
    return confident_half_error(error, confidence[valid])


def working_resolution(shot: dict, max_coc_px: float) -> tuple[torch.Tensor, CameraSettings,
                                                              tuple[int, int]]:
    """The all-in-focus and focused photos `(1+F,3,h,w)` at `estimate_depth`'s working resolution
    for a model reading blurs up to `max_coc_px`, the settings there and that size."""
    scale = working_scale(shot["settings"], *DEPTH_RANGE, tuple(shot["image"].shape[-2:]),
                          max_coc_px)
    stack, settings = to_working_resolution(shot["image"], shot["focused"], shot["settings"],
                                            scale)
    return stack, settings, tuple(stack.shape[-2:])


def run_without_image(method: str, shot: dict) -> tuple[torch.Tensor, float, torch.Tensor]:
    """`(depth, seconds, confidence)` of `estimate_depth(method=...)` with the all-in-focus
    photo withheld."""
    started = time.perf_counter()
    out = estimate_depth(shot["focused"], shot["settings"], DEPTH_RANGE, method=method,
                         all_in_focus=False)
    return out["depth"], time.perf_counter() - started, out["confidence"]


#: The methods without an all-in-focus photo (`--stacks`): name -> (method, shots).
STACK_METHODS = {"pair": ("relative-blur", 2), "stack3": ("relative-blur", 3),
                 "focus3": ("focus", 3)}


def run_oracle(shot: dict) -> torch.Tensor:
    """Depth from `solve_depth` given the true blur of every shot (a perfect blur reader)."""
    stack, small, size = working_resolution(shot, DepthFromDefocus.max_coc_px)
    depth = torch.nn.functional.interpolate(shot["depth"][None], size=size, mode="area")
    blur = small.camera().signed_coc_px(depth.expand(small.n_shots, 1, *size)).abs()
    solved, _ = solve_depth(blur.transpose(0, 1), texture_weight(stack[:1]), small, *DEPTH_RANGE)
    return torch.nn.functional.interpolate(solved, size=shot["image"].shape[-2:],
                                           mode="bilinear")[0]


def run_direct(shot: dict, steps: int) -> tuple[torch.Tensor, float, None]:
    from models.direct import fit_depth_direct

    stack, small, _ = working_resolution(shot, SweepDepth.max_coc_px)
    h, w = shot["image"].shape[-2:]
    started = time.perf_counter()
    focused = align_shots(stack[:1], stack[1:][None])[0]
    depth = fit_depth_direct(stack[:1], focused, small, *DEPTH_RANGE, steps=steps)
    elapsed = time.perf_counter() - started
    depth = torch.nn.functional.interpolate(depth, size=(h, w), mode="bilinear")[0]
    return depth, elapsed, None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", type=Path, default=None,
                        help="camera-general weights written by `examples/blur_net.py` (adds the "
                             "`pretrained` columns)")
    parser.add_argument("--no-direct", action="store_true", help="skip the direct fits")
    parser.add_argument("--direct-steps", type=int, default=150, help="Adam steps of a direct fit")
    parser.add_argument("--oracle", action="store_true",
                        help="add the solve fed the true blur (the bound of a perfect reader)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the photo imperfections")
    parser.add_argument("--photos", choices=sorted(PHOTOS), default="real",
                        help="real: every imperfection (the evaluation); noise-only: shot and "
                             "read noise and 8-bit sRGB, the shots otherwise identical; "
                             "perfect: none")
    parser.add_argument("--jpeg", type=int, default=0, metavar="QUALITY",
                        help="save every photo as a JPEG of this quality (1-95, 4:2:0 chroma, "
                             "as cameras and phones do) and read it back; 0: lossless")
    parser.add_argument("--stacks", action="store_true",
                        help="add the methods without the all-in-focus photo: the relative blur "
                             "of the two shots (pair), of three (stack3: a third shot focused "
                             "where --third says) and depth from focus of the three (focus3)")
    parser.add_argument("--third", choices=sorted(THIRD_SHOT), default="midway",
                        help="with --stacks, where the third shot is focused: "
                             + "; ".join(f"{k}: {v}" for k, v in THIRD_SHOT.items()))
    parser.add_argument("--cameras", nargs="+", default=None, metavar="PREFIX",
                        help="only the cameras whose names start with these (e.g. demo 200mm)")
    args = parser.parse_args(argv)
    try:
        photos = dataclasses.replace(PHOTOS[args.photos], jpeg_quality=args.jpeg)
    except ValueError as error:
        parser.error(f"--jpeg: {error}")
    torch.set_num_threads(1)
    from models.loading import load_weights

    methods = {"sweep": lambda shot: run_model(SweepDepth(), shot)}
    if args.weights is not None:
        network = load_weights(args.weights)
        methods["pretrained"] = lambda shot: run_model(network, shot)
    if not args.no_direct:
        methods["direct"] = lambda shot: run_direct(shot, args.direct_steps)
    if args.oracle:
        methods["oracle"] = lambda shot: (run_oracle(shot), float("nan"), None)
    if args.stacks:
        for name, (method, _) in STACK_METHODS.items():
            methods[name] = lambda shot, method=method: run_without_image(method, shot)
    header = "| camera | PSF | constant abs rel |"
    for name in methods:
        header += f" {name} abs rel | ratio | d1 | s |"
    print(header)
    print("|---|---|---|" + "---|---|---|---|" * len(methods))
    ratios: dict[str, list[float]] = {name: [] for name in methods}
    ranking: dict[str, list[float]] = {name: [] for name in methods}
    demo: dict[str, float] = {}
    demo_seconds: dict[str, float] = {}
    cameras = {name: spec for name, spec in CAMERAS.items()
               if args.cameras is None or name.startswith(tuple(args.cameras))}
    if not cameras:
        parser.error(f"--cameras {' '.join(args.cameras)}: no camera's name starts with these; "
                     f"the cameras are: {', '.join(CAMERAS)}")
    for camera, spec in cameras.items():
        shot = photograph(camera, args.seed, noise=photos)
        stack = photograph(camera, args.seed, noise=photos, shots=3, third=args.third) \
            if args.stacks else None
        target, mask = shot["depth"][None], shot["mask"][None]
        constant = best_constant_depth(target=target, mask=mask)
        base = depth_metrics(pred=torch.full_like(target, constant), target=target, mask=mask)
        row = f"| {camera} | {spec[4]} | {base['abs_rel']:.3f} |"
        for name, method in methods.items():
            three = name in STACK_METHODS and STACK_METHODS[name][1] == 3
            depth, seconds, confidence = method(stack if three else shot)
            if confidence is not None:
                ranking[name].append(ranking_of(depth, confidence, shot))
            m = depth_metrics(pred=depth[None], target=target, mask=mask)
            ratios[name].append(m["abs_rel"] / base["abs_rel"])
            demo.setdefault(name, m["abs_rel"])
            demo_seconds.setdefault(name, seconds)
            row += (f" {m['abs_rel']:.3f} | {m['abs_rel'] / base['abs_rel']:.2f} | "
                    f"{m['delta1']:.3f} | {seconds:.2f} |")
        print(row, flush=True)
    print()
    for name, values in ranking.items():
        if values:
            print(f"{name} confidence: the more confident half of the pixels has "
                  f"{statistics.median(values):.2f} of the mean error (median over the cameras, "
                  f"{min(values):.2f}-{max(values):.2f}; 1 is no better than chance)")
    if args.stacks:
        relative = [p / s for p, s in zip(ratios["pair"], ratios["sweep"], strict=True)]
        print(f"pair: ratio within 1.3x the sweep's (with the all-in-focus photo) at every "
              f"camera: {'met' if max(relative) <= 1.3 else 'unmet'} ({min(relative):.2f}-"
              f"{max(relative):.2f}x)")
        for name in ("stack3", "focus3"):
            others = [r for camera, r in zip(cameras, ratios[name], strict=True)
                      if not camera.startswith("demo")]
            if others:
                print(f"{name} (third shot {args.third}): ratio <= 0.30 at every camera but "
                      f"the demo one: {'met' if max(others) <= 0.3 else 'unmet'} "
                      f"(worst {max(others):.2f})")
    for name in methods:
        worst = max(ratios[name])
        print(f"{name}: ratio <= 0.30 for every camera: {'met' if worst <= 0.3 else 'unmet'} "
              f"(worst {worst:.2f}); demo camera abs rel <= 0.06: "
              f"{'met' if demo[name] <= 0.06 else 'unmet'} ({demo[name]:.3f})"
              + ("" if math.isnan(demo_seconds[name]) else
                 f"; under 1 s at the demo camera's 185x125: "
                 f"{'met' if demo_seconds[name] < 1 else 'unmet'} ({demo_seconds[name]:.2f} s)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
