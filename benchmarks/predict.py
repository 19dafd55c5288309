"""Speed and memory of `defocus predict` on 3, 12 and 24 megapixel photo sets, stage by stage.

Two photo sets per size, each run through `defocus predict` exactly as a user runs it (PNG files
in, depth.npy, the PNGs and figure.png out):

- **pair**: an all-in-focus photo and 2 focused ones (1.5 and 4 m): the sweep over depth at the
  working resolution (`estimate_depth`'s `"sweep"`);
- **stack**: 3 focused photos (1.5, 4 and 8 m), no all-in-focus one: the relative blur at the
  working resolution, then the all-in-focus image fused from the shots at full resolution.

The camera is the one of a phone-sized sensor: 18 mm f/8, 1.5 um pixels, depth range 0.8-10 m
(so at 12 megapixels the working resolution is bounded by its 1.5 megapixels, 0.35 of the
photos' side). **What the photos show**: a procedural scene of `datasets.synthetic.generate_scene`
(textured planes, a ground plane and occluding objects at 1-8 m) rendered by the library's
layered renderer through that camera at an eighth of the photos' side (pixel pitch 8x), then
resized to the full size, with a little sensor-like noise (sigma 0.004) and 8-bit sRGB: real
structure and real defocus at the working resolution, at a fraction of the rendering cost (the
fine detail of a real 12-megapixel photo is missing, which matters little: the depth is read at
the working resolution). The abs rel against that scene's depth is printed as a sanity check.

Stages (seconds, from wrappers around the functions `defocus predict` calls):
`decode` (`read_photos`), `downscale` (`to_working_resolution`), `align` (`optics.align_shots`
at the working resolution), `depth` (the method at the working resolution, with the bilinear
resizing of its depth to the photos' size: the rest of `run_at_working_resolution`), `fusion`
(`estimate._fused`, the stack's all-in-focus image), `write` (`write_outputs`) and `total` (the
whole command). **Peak memory** is read in a fresh subprocess per case (Linux `ru_maxrss` of the
whole command, decoding included); on CUDA it is `torch.cuda.max_memory_allocated`.

Goals: at 12 megapixels the pair and the stack each in <= 30 s and <= 3 GiB peak resident
memory on 2 CPU cores; on CUDA (where `torch.cuda.is_available()`) `estimate_depth` (the depth
stages, photos already decoded) in <= 2 s.

Usage:

    python benchmarks/predict.py                      # 3, 12 and 24 MP, pair and stack, CPU
    python benchmarks/predict.py --megapixels 3 12    # fewer sizes
    python benchmarks/predict.py --megapixels 12 --cases pair --no-memory
    python benchmarks/predict.py --device cuda        # the same on a GPU
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: Megapixels -> (height, width) of the photos (4:3, a 24 MP one 4:6).
SIZES = {3: (1500, 2000), 12: (3000, 4000), 24: (4000, 6000)}
#: The camera of every case (metres): focal length, f-number, pixel pitch, depth range.
FOCAL_LENGTH, F_NUMBER, PIXEL_PITCH, DEPTH_RANGE = 0.018, 8.0, 1.5e-6, (0.8, 10.0)
#: Focus distances (metres) of the focused photos of each case.
CASES = {"pair": [1.5, 4.0], "stack": [1.5, 4.0, 8.0]}
#: The photos are rendered at 1/RENDER_FACTOR of their side, then resized.
RENDER_FACTOR = 8
#: Goals at 12 megapixels on 2 CPU cores: seconds and GiB; on CUDA: seconds of estimate_depth.
GOAL_SECONDS, GOAL_GIB, GOAL_CUDA_SECONDS = 30.0, 3.0, 2.0
STAGES = ("decode", "downscale", "align", "depth", "fusion", "write")


def make_photos(megapixels: int, folder: Path) -> Path:
    """Write the all-in-focus photo `aif.png`, the focused ones `f1.5.png`, `f4.png`, `f8.png`
    and the scene's depth `truth.npy` (metres, at the rendering's resolution) for one size."""
    from kornia.color import linear_rgb_to_rgb
    from PIL import Image

    from datasets.capture import CaptureNoise, capture
    from datasets.synthetic import generate_scene
    from optics import CameraSettings

    folder = folder / f"{megapixels}mp"
    if (folder / "truth.npy").is_file():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    h, w = SIZES[megapixels]
    rng = np.random.default_rng(0)
    scene, depth = generate_scene((h // RENDER_FACTOR, w // RENDER_FACTOR), rng, (1.0, 8.0))
    distances = sorted({d for shots in CASES.values() for d in shots})
    camera = CameraSettings(FOCAL_LENGTH, F_NUMBER, distances, PIXEL_PITCH * RENDER_FACTOR,
                            "disk")
    aif, focused = capture(scene, depth, camera, rng, CaptureNoise())
    noise = torch.Generator().manual_seed(0)
    names = ["aif"] + [f"f{d:g}" for d in distances]
    for name, linear in zip(names, [aif, *focused], strict=True):
        big = torch.nn.functional.interpolate(linear[None], size=(h, w), mode="bilinear",
                                              align_corners=False)[0]
        big = big + 0.004 * torch.randn(big.shape, generator=noise)
        srgb = linear_rgb_to_rgb(big.clamp(0, 1)).permute(1, 2, 0).numpy()
        Image.fromarray((srgb * 255).round().astype(np.uint8)).save(folder / f"{name}.png",
                                                                     compress_level=1)
    np.save(folder / "truth.npy", depth[0].numpy())
    return folder


def command(folder: Path, case: str, out: Path, device: str) -> list[str]:
    """The `defocus predict` arguments of one case."""
    distances = CASES[case]
    shots = [str(folder / f"f{d:g}.png") for d in distances]
    image = ["--image", str(folder / "aif.png")] if case == "pair" else []
    return ["predict", *image, "--focused", *shots, "--focus-distance",
            *(f"{d:g}" for d in distances), "--f-number", f"{F_NUMBER:g}", "--focal-length",
            f"{FOCAL_LENGTH:g}", "--pixel-pitch", f"{PIXEL_PITCH:g}", "--depth-range",
            *(f"{d:g}" for d in DEPTH_RANGE), "--device", device, "--out", str(out),
            "--overwrite", "--quiet"]


@contextmanager
def stage_timers(device: str):
    """Seconds per stage (`STAGES`), from wrappers around the functions predict calls."""
    import defocus.app.predict as app
    import models.depth_from_photos.estimate as estimate
    import models.depth_from_photos.resolution as resolution

    seconds: dict[str, float] = defaultdict(float)
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)

    def timed(module, name, stage):
        original = getattr(module, name)

        def wrapper(*args, **kwargs):
            sync()
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                sync()
                seconds[stage] += time.perf_counter() - start
        setattr(module, name, wrapper)
        return module, name, original

    patched = [timed(app, "read_photos", "decode"), timed(app, "write_outputs", "write"),
               timed(estimate, "_fused", "fusion"),
               timed(estimate, "run_at_working_resolution", "working"),
               timed(resolution, "align_shots", "align"),
               timed(resolution, "to_working_resolution", "downscale")]
    try:
        yield seconds
    finally:
        for module, name, original in patched:
            setattr(module, name, original)
        seconds["depth"] = seconds.pop("working", 0.0) - seconds["align"] - seconds["downscale"]


def run_case(folder: Path, case: str, device: str, out: Path) -> dict[str, float]:
    """One `defocus predict` run: seconds per stage and in total, and the abs rel."""
    from defocus.cli import main

    with stage_timers(device) as seconds:
        start = time.perf_counter()
        code = main(command(folder, case, out, device))
        seconds["total"] = time.perf_counter() - start
    if code != 0:
        raise SystemExit(f"defocus predict failed on {case} at {folder.name} (exit {code})")
    depth = torch.from_numpy(np.load(out / "depth.npy"))[None, None]
    truth = torch.from_numpy(np.load(folder / "truth.npy"))
    depth = torch.nn.functional.interpolate(depth, size=truth.shape, mode="area")[0, 0]
    seconds["abs_rel"] = float(((depth - truth).abs() / truth).mean())
    return dict(seconds)


def cuda_depth_seconds(folder: Path, case: str, repeats: int = 3) -> tuple[float, float]:
    """Median seconds of `estimate_depth` on CUDA from decoded photos (the first run warms up),
    and its peak allocated GiB."""
    from datasets.photos import read_photo
    from models import estimate_depth
    from optics import CameraSettings

    distances = CASES[case]
    shots = torch.stack([read_photo(folder / f"f{d:g}.png")[0] for d in distances]).cuda()
    image = read_photo(folder / "aif.png")[0].cuda() if case == "pair" else None
    settings = CameraSettings(FOCAL_LENGTH, F_NUMBER, distances, PIXEL_PITCH, "disk")
    times = []
    for _ in range(repeats + 1):
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
        start = time.perf_counter()
        estimate_depth(shots, settings, DEPTH_RANGE, image=image)
        torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return float(np.median(times[1:])), torch.cuda.max_memory_allocated() / 2**30


def memory_probe(folder: Path, case: str, device: str, out: Path) -> float:
    """Peak resident memory (GiB) of `defocus predict` on one case, in a fresh process."""
    probe = subprocess.run([sys.executable, __file__, "--memory-probe", str(folder), case,
                            device, str(out)], capture_output=True, text=True, check=False)
    if probe.returncode != 0:
        raise SystemExit(f"memory probe failed: {probe.stderr[-2000:]}")
    return float(probe.stdout.split()[-1])


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--megapixels", type=int, nargs="+", default=sorted(SIZES),
                        choices=sorted(SIZES), help="photo sizes to run (megapixels)")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES),
                        help="photo sets: pair (sweep) and stack (relative blur)")
    parser.add_argument("--device", choices=("cpu", "cuda", "all"), default="all",
                        help="cpu, cuda, or all: cpu and cuda where available")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads (torch)")
    parser.add_argument("--no-memory", action="store_true",
                        help="skip the peak memory subprocesses")
    parser.add_argument("--photos", type=Path, default=None,
                        help="folder to keep the rendered photos in (default: a temporary one)")
    parser.add_argument("--memory-probe", nargs=4, metavar=("FOLDER", "CASE", "DEVICE", "OUT"),
                        help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.memory_probe:
        folder, case, device, out = args.memory_probe
        run_case(Path(folder), case, device, Path(out))
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB -> GiB
        print(f"peak_gib {peak:.3f}")
        return 0
    devices = ["cpu", "cuda"] if args.device == "all" else [args.device]
    if "cuda" in devices and not torch.cuda.is_available():
        if args.device == "cuda":
            raise SystemExit("--device cuda: no CUDA device here")
        devices.remove("cuda")
    with tempfile.TemporaryDirectory() as scratch:
        root = args.photos or Path(scratch)
        rows, goals = [], []
        for megapixels in args.megapixels:
            folder = make_photos(megapixels, root)
            for case in args.cases:
                for device in devices:
                    out = Path(scratch) / f"out_{megapixels}_{case}_{device}"
                    seconds = run_case(folder, case, device, out)
                    peak = math.nan if args.no_memory or device != "cpu" else \
                        memory_probe(folder, case, device, out)
                    if device == "cuda":
                        seconds["estimate_depth"], peak = cuda_depth_seconds(folder, case)
                    rows.append((megapixels, case, device, seconds, peak))
                    print(json.dumps({"megapixels": megapixels, "case": case, "device": device,
                                      "peak_gib": peak, **seconds}), flush=True)
                    if megapixels == 12 and device == "cpu":
                        goals.append((f"12 MP {case}, {args.threads} CPU threads: total <= "
                                      f"{GOAL_SECONDS:g} s", seconds["total"] <= GOAL_SECONDS))
                        if not args.no_memory:
                            goals.append((f"12 MP {case}: peak <= {GOAL_GIB:g} GiB",
                                          peak <= GOAL_GIB))
                    if megapixels == 12 and device == "cuda":
                        goals.append((f"12 MP {case}, CUDA: estimate_depth <= "
                                      f"{GOAL_CUDA_SECONDS:g} s",
                                      seconds["estimate_depth"] <= GOAL_CUDA_SECONDS))
    print(f"\ndefocus predict, {args.threads} threads; seconds per stage; peak memory GiB "
          "(resident on CPU, allocated on CUDA); abs rel against the rendered scene")
    header = ["MP", "case", "device", *STAGES, "total", "estimate_depth", "peak GiB", "abs rel"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for megapixels, case, device, seconds, peak in rows:
        cells = [str(megapixels), case, device,
                 *(f"{seconds.get(stage, 0.0):.2f}" for stage in STAGES),
                 f"{seconds['total']:.2f}",
                 f"{seconds['estimate_depth']:.2f}" if "estimate_depth" in seconds else "-",
                 "-" if math.isnan(peak) else f"{peak:.2f}", f"{seconds['abs_rel']:.3f}"]
        print("| " + " | ".join(cells) + " |")
    if goals:
        print("\ngoals:")
        for text, met in goals:
            print(f"  {'met  ' if met else 'UNMET'} {text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
