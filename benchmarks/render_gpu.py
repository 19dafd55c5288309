"""Speed of the per-pixel PSF renderer on a CUDA GPU (the Triton kernels): scatter mode against
`kornia.filters.gaussian_blur2d` and against a memory-bandwidth floor; then the gather and
layered modes (Triton spreads, the layers composited in PyTorch) against the same two.

For each shape (`1x3x512x512`, `8x3x512x512`), window `K` (15, 31) and aperture (Gaussian,
disk), `render_defocus(..., mode="scatter")` and `gaussian_blur2d` with the same `K` run
forward+backward, round-robin in this process (one run of each per round, timed with CUDA events
after a warm-up), on the inputs of `benchmarks/render.py` (a CoC map whose largest CoC needs
exactly the `K` window). Ratios are medians of the per-round ratios. The second table runs, at
`1x3x512x512` and `K = 15`, the gather and layered modes (8 layers; the motorcycle,
plane-and-discs and random depths as in `benchmarks/render.py`): their unnormalised spreads run
the Triton kernels `CHANNEL_GROUP` channels per program, the rest (layer weights, normalisation,
compositing) is PyTorch.

The floor is the time to move, once, the bytes that a forward+backward must read and write:
forward reads the image and the CoC and writes the output, backward reads the output's
gradient, the image and the CoC and writes both gradients, `(4 C + 3) B H W` values, at the
device-to-device copy bandwidth measured here (`copy_` of a 1 GiB buffer, read+write).

Usage:

    python benchmarks/render_gpu.py             # goals, then the table
    python benchmarks/render_gpu.py --rounds 21
    python benchmarks/render_gpu.py --block-h 8 --warps 2   # another tile of the Triton kernels
    python benchmarks/render_gpu.py --no-other   # only the fused scatter table
    python benchmarks/render_gpu.py --channel-group 8   # channels per program of the spreads
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from render import Job, paired_ratio  # noqa: E402  (benchmarks/render.py: inputs, pairing)

from optics.render import triton_kernels as _render_triton  # noqa: E402

SHAPES = [(1, 3, 512, 512), (8, 3, 512, 512)]
KERNELS = [15, 31]
METHODS = ["kornia", "gaussian/scatter", "disk/scatter"]
#: The other modes, timed beside the two baselines.
OTHER_METHODS = ["gaussian/gather", "disk/gather", "gaussian/layered-motorcycle",
                 "disk/layered-motorcycle", "gaussian/layered-plane-discs",
                 "disk/layered-plane-discs", "gaussian/layered-random", "disk/layered-random"]
#: The goals' configuration (as in benchmarks/render.py) and their targets.
GOAL_SHAPE, GOAL_K = (1, 3, 512, 512), 15
#: goal: occlusion-aware (layered) rendering of the motorcycle depth against the same aperture's
#: fused scatter
LAYERED_GOAL = 2.5


def copy_bandwidth(n_bytes: int = 2**30, repeats: int = 10) -> float:
    """Device-to-device copy bandwidth in bytes per second, counting the read and the write."""
    src = torch.empty(n_bytes, dtype=torch.uint8, device="cuda")
    dst = torch.empty_like(src)
    dst.copy_(src)
    seconds = statistics.median(_timed(lambda: dst.copy_(src)) for _ in range(repeats))
    return 2 * n_bytes / seconds


def floor_bytes(shape, element_size: int = 4) -> int:
    """Bytes a forward+backward must read or write at least once (see the module docstring)."""
    b, c, h, w = shape
    return (4 * c + 3) * b * h * w * element_size


def _timed(fn) -> float:
    """Seconds of one call of `fn` on the current stream, by CUDA events."""
    start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    start.record()
    fn()
    end.record()
    end.synchronize()
    return start.elapsed_time(end) / 1e3


def measure(shape, k: int, rounds: int, warmup: int = 3,
            methods: list[str] = METHODS) -> dict[str, list[float]]:
    """Forward+backward seconds per method, interleaved over `rounds` after `warmup` runs."""
    jobs = {name: Job(name, k, torch.device("cuda"), shape=shape) for name in methods}
    for job in jobs.values():
        for _ in range(warmup):
            job.run(True)
    torch.cuda.synchronize()
    times: dict[str, list[float]] = {name: [] for name in jobs}
    for _ in range(rounds):
        for name, job in jobs.items():
            times[name].append(_timed(lambda job=job: job.run(True)))
    return times


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15, help="round-robin rounds (medians)")
    parser.add_argument("--block-h", type=int, help="tile rows of the Triton kernels (tuning)")
    parser.add_argument("--warps", type=int, help="warps per program; tile width is 32 per warp")
    parser.add_argument("--no-other", action="store_true",
                        help="skip the table of the gather and layered modes")
    parser.add_argument("--channel-group", type=int,
                        help="channels per program of the unnormalised spreads (a power of two)")
    parser.add_argument("--no-main", action="store_true",
                        help="skip the table of the fused scatter against gaussian_blur2d")
    parser.add_argument("--profile", action="store_true",
                        help="add the kernels the layered mode spends its time in")
    args = parser.parse_args(argv)
    if args.block_h:
        _render_triton.BLOCK_H = args.block_h
    if args.channel_group:
        _render_triton.CHANNEL_GROUP = args.channel_group
    if args.warps:
        _render_triton.NUM_WARPS, _render_triton.BLOCK_W = args.warps, 32 * args.warps
    if not torch.cuda.is_available():
        print("benchmarks/render_gpu.py needs a CUDA GPU; none is available, nothing measured.")
        return 0
    bandwidth = copy_bandwidth()
    tiles = f"{_render_triton.BLOCK_H}x{_render_triton.BLOCK_W}, {_render_triton.NUM_WARPS} warps"
    print(f"torch {torch.__version__}, {torch.cuda.get_device_name()}, Triton kernels: "
          f"{_render_triton.available()} (tiles {tiles}), copy bandwidth "
          f"{bandwidth / 1e9:.0f} GB/s (read+write)\n")
    if not args.no_main:
        main_table(args, bandwidth)
    if not args.no_other:
        other_table(args, bandwidth)
    if args.profile:
        for name in ("gaussian/layered-motorcycle", "disk/layered-motorcycle"):
            print(f"\nKernels of {name} ({where_goal()}), by CUDA time:\n")
            print(kernel_profile(name))
    return 0


def where_goal() -> str:
    return f"{'x'.join(map(str, GOAL_SHAPE))}, K={GOAL_K}, fwd+bwd"


def kernel_profile(name: str, runs: int = 5) -> str:
    """The profiler's table of the CUDA kernels of `runs` forward+backward passes."""
    from torch.profiler import ProfilerActivity, profile

    job = Job(name, GOAL_K, torch.device("cuda"), shape=GOAL_SHAPE)
    for _ in range(3):
        job.run(True)
    torch.cuda.synchronize()
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        for _ in range(runs):
            job.run(True)
        torch.cuda.synchronize()
    return prof.key_averages().table(sort_by="cuda_time_total", row_limit=15)


def main_table(args, bandwidth: float) -> None:
    print("| shape | K | method | fwd+bwd ms | / gaussian_blur2d | / Gaussian scatter | floor ms | "
          "/ floor |\n|---|---|---|---|---|---|---|---|", flush=True)
    results = {}
    for shape in SHAPES:
        floor = floor_bytes(shape) / bandwidth
        for k in KERNELS:
            times = measure(shape, k, args.rounds)
            results[shape, k] = times
            for name in METHODS:
                median = statistics.median(times[name])
                print(f"| {'x'.join(map(str, shape))} | {k} | "
                      f"{'gaussian_blur2d' if name == 'kornia' else name} | {median * 1e3:.3f} | "
                      f"{paired_ratio(times, name, 'kornia'):.2f} | "
                      f"{paired_ratio(times, name, 'gaussian/scatter'):.2f} | "
                      f"{floor * 1e3:.3f} | {median / floor:.1f} |", flush=True)
    goal = results[GOAL_SHAPE, GOAL_K]
    where = where_goal()
    print()
    for name, value, target in (
        ("Gaussian scatter <= 1.5x gaussian_blur2d on GPU",
         paired_ratio(goal, "gaussian/scatter", "kornia"), 1.5),
        ("disk scatter <= 1.5x Gaussian scatter on GPU",
         paired_ratio(goal, "disk/scatter", "gaussian/scatter"), 1.5),
    ):
        print(f"{name} ({where}): {value:.2f}x, {'met' if value <= target else 'unmet'}")


def other_table(args, bandwidth: float) -> None:
    where = where_goal()
    print(f"\nGather and layered modes ({_render_triton.CHANNEL_GROUP} channels per "
          f"program of the spreads), {where}; each against its aperture's fused scatter:\n")
    print("| method | fwd+bwd ms | / gaussian_blur2d | / its aperture's scatter | / floor |\n"
          "|---|---|---|---|---|")
    times = measure(GOAL_SHAPE, GOAL_K, args.rounds,
                    methods=["kornia", "gaussian/scatter", "disk/scatter", *OTHER_METHODS])
    floor = floor_bytes(GOAL_SHAPE) / bandwidth
    ratios = {}
    for name in OTHER_METHODS:
        median = statistics.median(times[name])
        ratios[name] = paired_ratio(times, name, f"{name.split('/')[0]}/scatter")
        print(f"| {name} | {median * 1e3:.3f} | {paired_ratio(times, name, 'kornia'):.2f} | "
              f"{ratios[name]:.2f} | {median / floor:.0f} |", flush=True)
    print()
    for name in ("gaussian/layered-motorcycle", "disk/layered-motorcycle"):
        met = "met" if ratios[name] <= LAYERED_GOAL else "unmet"
        print(f"{name} <= {LAYERED_GOAL}x its aperture's scatter on GPU ({where}): "
              f"{ratios[name]:.2f}x, {met}")


if __name__ == "__main__":
    sys.exit(main())
