"""Speed and memory of the per-pixel PSF renderer: every aperture x mode against two baselines.

Timings and memory are taken apart:

- **Time** is measured in this process, never under an allocator setting: the methods of one
  configuration run round-robin (one run of each per round) and every ratio is the median over
  rounds of the per-round ratio, so a machine whose load changes during the run still gives fair
  ratios. The baselines are `kornia.filters.gaussian_blur2d` with the same `K` (the spatially
  invariant floor) and the renderer's Gaussian scatter at the same window.
- **Memory** is read in a fresh subprocess per entry (`--memory-probe`), which sets glibc's
  `M_MMAP_THRESHOLD` to 128 KiB so that large blocks go back to the system on free and the peak
  resident set size (Linux `VmHWM`, reset through `/proc/self/clear_refs`) above the level
  before the call is the call's own peak. That setting slows large allocations a lot, which is
  why no timing ever runs under it. On CUDA the memory is `torch.cuda.max_memory_allocated`.

Each aperture gets a spatially varying CoC map (uniform in `[0, c_max]`, one pixel at `c_max`)
whose largest CoC needs exactly the `K`-pixel window: `c_max = 2 (K // 2) / 3` for the Gaussian
(`sigma = CoC / 2`, half-width `ceil(3 sigma)`), `K - 0.01` for the disk and hexagon, `K - 2.01`
for the mask. The layered mode (8 layers) runs on three depth maps, each mode named for it:
`layered-motorcycle` (the headline: the real Middlebury motorcycle's depth from scikit-image's
sample, disparity to metres, resized to 512x512, the photo itself as the image, focused at 3 m),
`layered-random` (depth `1 + CoC` per pixel: every layer is present everywhere, the worst case)
and `layered-plane-discs` (a synthetic smooth scene: a tilted
plane with two discs in front, the CoC following the depth as a camera would make it).

Usage:

    python benchmarks/render.py                 # goals, then the table (1 thread, 1x3x512x512)
    python benchmarks/render.py --quick         # only the goals
    python benchmarks/render.py --kernels 7 15 31 --threads 1 2 --no-memory
    python benchmarks/render.py --device cuda   # the same on a GPU (pure PyTorch path)
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import kornia  # noqa: E402

from datasets.middlebury import motorcycle_scene  # noqa: E402
from optics import Disk, Gaussian, Mask, Polygon, render_defocus  # noqa: E402
from optics.render import cpp as _render_cpp  # noqa: E402
from optics.render import layer_weights  # noqa: E402

APERTURES = ["gaussian", "disk", "hexagon", "mask"]
MODES = ["scatter", "gather", "layered-motorcycle", "layered-plane-discs", "layered-random"]
#: The depth map each layered mode renders (see the module docstring).
DEPTHS = {"layered-motorcycle": "motorcycle", "layered-plane-discs": "plane-discs",
          "layered-random": "random"}
SHAPE = (1, 3, 512, 512)
#: Skip the unfold baseline when its K^2 copies would need more than this many bytes.
UNFOLD_LIMIT_BYTES = 2.5e9
#: A scatter of `2 (C + 1) - 1` channels: the multiply-adds of the layered mode if each source
#: touched its two layers' sums at no cost of indexing (the layered mode's arithmetic floor).
FLOOR = "two-layer-floor"
#: A method whose first run takes longer than this is timed once per configuration.
SLOW_RUN_S = 3.0


def _mask() -> Mask:
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, 33), torch.linspace(-1, 1, 33), indexing="ij")
    r = (xx**2 + yy**2).sqrt()
    return Mask(((r < 1) & (r > 0.4)).float() + 0.3 * (r <= 0.4).float())


def make_psf(name: str):
    return {"gaussian": Gaussian, "disk": Disk, "hexagon": lambda: Polygon(6), "mask": _mask}[
        name
    ]()


def coc_max_for(name: str, k: int) -> float:
    """Largest CoC whose window is exactly `k` pixels for aperture `name`."""
    half = k // 2
    return {"gaussian": 2 * half / 3, "mask": k - 2.01}.get(name, k - 0.01)


def make_inputs(name: str, shape, k: int, device, depth_kind: str = "random", seed: int = 0):
    """Image, CoC map (its largest CoC needs exactly a `k`-pixel window) and depth map;
    `depth_kind` is "random", "plane-discs" or "motorcycle" (module docstring)."""
    gen = torch.Generator().manual_seed(seed)
    b, c, h, w = shape
    image = torch.rand(shape, generator=gen)
    c_max = coc_max_for(name, k)
    if depth_kind == "random":
        coc = torch.rand(b, 1, h, w, generator=gen) * c_max
        coc[:, :, 0, 0] = c_max
        depth = 1.0 + coc  # any positive depth map: per pixel, every layer is present everywhere
        return image.to(device), coc.to(device), depth.to(device)
    if depth_kind == "plane-discs":  # a tilted plane (far) with two discs in front
        yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
        depth, focus = 2.0 + 6.0 * yy, 2.5
        for cy, cx, radius, d in ((0.35, 0.3, 0.18, 1.0), (0.6, 0.7, 0.22, 1.4)):
            depth = torch.where((yy - cy) ** 2 + (xx - cx) ** 2 < radius**2, torch.tensor(d), depth)
        depth = depth[None, None]
    elif depth_kind == "motorcycle":  # the real scene: its photo and its depth, focused at 3 m
        photo, depth, _ = motorcycle_scene()
        photo = torch.nn.functional.interpolate(photo, size=(h, w), mode="area")
        depth = torch.nn.functional.interpolate(depth, size=(h, w), mode="nearest")
        image, focus = photo.expand(b, c, h, w).clone(), 3.0
    else:
        raise ValueError(f"depth_kind must be random, plane-discs or motorcycle, got {depth_kind!r}")
    blur = (1 / depth - 1 / focus).abs()  # the CoC of a thin lens, up to a factor
    coc = (blur / blur.max() * c_max).expand(b, 1, h, w).clone()
    return image.to(device), coc.to(device), depth.expand(b, 1, h, w).clone().to(device)


def layers_per_window(depth: torch.Tensor, n_layers: int, k: int, block: int = 8
                      ) -> tuple[float, float]:
    """How many layers the exact layered mode must sum, on average: `(per source, per source
    row of a block's window)`. A source adds to its one or two layers; a block of `block` output
    pixels (one vector of the compiled kernel) sums, for each of the `k` source rows of its
    window, every layer present among that row's `k + block - 1` sources."""
    present = (layer_weights(depth, n_layers) > 0).to(torch.float32)
    half = k // 2
    padded = torch.nn.functional.pad(present, (half, half + block, 0, 0))
    rows = torch.nn.functional.max_pool2d(padded, (1, k + block - 1), stride=(1, block))
    rows = rows[..., : math.ceil(depth.shape[-1] / block)]
    return float(present.sum(1).mean()), float(rows.sum(1).mean())


def unfold_scatter(image: torch.Tensor, coc: torch.Tensor, k: int) -> torch.Tensor:
    """Naive Gaussian scatter: `unfold` the image and the per-source sigma into K*K copies."""
    b, c, h, w = image.shape
    half = k // 2
    sigma = (0.5 * coc).clamp_min(1e-2)
    d = torch.arange(-half, half + 1, dtype=image.dtype, device=image.device)
    line = torch.exp(-(d.view(-1, 1, 1, 1) ** 2) / (2 * sigma.view(1, b, h, w) ** 2)).sum(0)
    norm = 1.0 / (line * line)  # each source spreads unit energy over its K x K window
    patches = torch.nn.functional.unfold(image, k, padding=half).view(b, c, k * k, h * w)
    src_sigma = torch.nn.functional.unfold(sigma, k, padding=half).view(b, 1, k * k, h * w)
    src_norm = torch.nn.functional.unfold(norm, k, padding=half).view(b, 1, k * k, h * w)
    valid = torch.nn.functional.unfold(torch.ones_like(sigma), k, padding=half)
    dy, dx = torch.meshgrid(-d, -d, indexing="ij")
    r2 = (dy * dy + dx * dx).reshape(1, 1, k * k, 1)
    weight = src_norm * torch.exp(-r2 / (2 * src_sigma**2)) * valid.view(b, 1, k * k, h * w)
    out = (weight * patches).sum(2) / weight.sum(2)
    return out.view(b, c, h, w)


class Job:
    """One method on one configuration: `run(backward)` renders once."""

    def __init__(self, method: str, k: int, device, shape=SHAPE):
        self.method, self.k = method, k
        if method in ("kornia", "unfold"):
            self.psf, mode = None, method
            self.inputs = make_inputs("gaussian", shape, k, device)
        else:
            name, mode = method.split("/")
            self.psf = make_psf(name).to(device)
            if mode == FLOOR:  # the values a source adds per tap in two layers: 2 (C + 1)
                shape = (shape[0], 2 * (shape[1] + 1) - 1, *shape[2:])
            self.inputs = make_inputs(name, shape, k, device, DEPTHS.get(mode, "random"))
        self.mode = mode

    def run(self, backward: bool) -> None:
        image, coc, depth = self.inputs
        image = image.detach().requires_grad_(backward)
        coc = coc.detach().requires_grad_(backward and self.mode != "kornia")
        if self.mode == "kornia":
            sigma = coc_max_for("gaussian", self.k) / 2
            out = kornia.filters.gaussian_blur2d(image, (self.k, self.k), (sigma, sigma))
        elif self.mode == "unfold":
            out = unfold_scatter(image, coc, self.k)
        else:
            mode = "layered" if self.mode in DEPTHS else {FLOOR: "scatter"}.get(self.mode,
                                                                                 self.mode)
            out = render_defocus(image, coc, self.psf, mode, depth=depth, n_layers=8)
        if backward:
            out.backward(torch.ones_like(out))


def _once(fn, device) -> float:
    if device.type == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    fn()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - start


def round_robin(jobs: dict[str, Job], backward: bool, rounds: int, device) -> dict[str, list]:
    """Times per method, interleaved: round `r` runs every method once (slow ones only in round 0)."""
    times: dict[str, list[float]] = {name: [] for name in jobs}
    for job in jobs.values():  # warm-up (thread pools, kernel build, first allocations)
        Job(job.method, 7, device, shape=(1, 3, 32, 32)).run(backward)
        if job.method != "unfold" and not job.method.startswith("mask"):  # slow: warm enough
            job.run(backward)
    slow: set[str] = set()
    for r in range(rounds):
        for name, job in jobs.items():
            if name in slow:
                continue
            times[name].append(_once(lambda job=job: job.run(backward), device))
            if r == 0 and times[name][0] > SLOW_RUN_S:
                slow.add(name)
    return times


def paired_ratio(times: dict[str, list], name: str, reference: str) -> float:
    pairs = list(zip(times[name], times[reference], strict=False))
    return statistics.median(a / b for a, b in pairs)


# ------------------------------------------------------------------ memory, in a subprocess


def _probe(spec: dict) -> float:
    """Peak extra bytes of one forward(+backward) run (run inside a fresh process)."""
    device = torch.device(spec["device"])
    torch.set_num_threads(spec["threads"])
    job = Job(spec["method"], spec["k"], device)
    small = Job(spec["method"], 7, device, shape=(1, 3, 32, 32))
    small.run(spec["backward"])  # warm-up: one-time allocations are not the op's
    gc.collect()
    if device.type == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
        base = torch.cuda.memory_allocated()
        job.run(spec["backward"])
        torch.cuda.synchronize()
        return torch.cuda.max_memory_allocated() - base
    try:  # return large blocks to the system on free (M_MMAP_THRESHOLD = -3): memory only
        ctypes.CDLL("libc.so.6").mallopt(-3, 128 * 1024)
    except OSError:
        return float("nan")

    def status(key: str) -> int:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1]) * 1024
        raise OSError(key)

    try:
        Path("/proc/self/clear_refs").write_text("5")
        base = status("VmRSS")
        job.run(spec["backward"])
        return status("VmHWM") - base
    except OSError:
        return float("nan")


def peak_memory(method: str, k: int, device, backward: bool = True, threads: int = 1) -> float:
    """Peak extra bytes of `method`, read in a fresh Python process."""
    spec = {"method": method, "k": k, "device": str(device), "backward": backward,
            "threads": threads}
    result = subprocess.run([sys.executable, __file__, "--memory-probe", json.dumps(spec)],
                            capture_output=True, text=True, check=False)
    try:
        return float(result.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return float("nan")


# ------------------------------------------------------------------ goals and table


def goals(device, rounds: int, memory: bool) -> list[tuple[str, float | str, str, bool]]:
    """The issue's goals: one thread, 1x3x512x512, K = 15, forward+backward, paired ratios."""
    torch.set_num_threads(1)
    k = 15
    names = ["kornia", "gaussian/scatter", "disk/scatter", "hexagon/scatter",
             *(f"{aperture}/{mode}" for mode in DEPTHS for aperture in ("gaussian", "disk")),
             f"gaussian/{FLOOR}", f"disk/{FLOOR}"]
    jobs = {name: Job(name, k, device) for name in names}
    times = round_robin(jobs, True, rounds, device)
    gauss = "gaussian/scatter"
    rows = [
        ("Gaussian scatter / gaussian_blur2d", paired_ratio(times, gauss, "kornia"), "<= 1.5"),
        ("disk scatter / Gaussian scatter", paired_ratio(times, "disk/scatter", gauss), "<= 1.5"),
        ("hexagon scatter / Gaussian scatter", paired_ratio(times, "hexagon/scatter", gauss),
         "<= 1.5"),
        ("Gaussian layered (8, real motorcycle depth) / Gaussian scatter",
         paired_ratio(times, "gaussian/layered-motorcycle", gauss), "<= 2.0"),
        ("disk layered (8, real motorcycle depth) / disk scatter",
         paired_ratio(times, "disk/layered-motorcycle", "disk/scatter"), "<= 2.0"),
        ("Gaussian layered (8, synthetic plane and discs) / Gaussian scatter",
         paired_ratio(times, "gaussian/layered-plane-discs", gauss), "<= 2.5"),
        ("disk layered (8, synthetic plane and discs) / disk scatter",
         paired_ratio(times, "disk/layered-plane-discs", "disk/scatter"), "<= 2.5"),
        ("Gaussian layered (8, random depth per pixel) / Gaussian scatter",
         paired_ratio(times, "gaussian/layered-random", gauss), "no goal"),
        ("disk layered (8, random depth per pixel) / disk scatter",
         paired_ratio(times, "disk/layered-random", "disk/scatter"), "no goal"),
    ]
    result = [(name, value, target, target == "no goal" or value <= float(target.split()[-1]))
              for name, value, target in rows]
    ok, detail = compile_check(device)
    result.append(("torch.compile(fullgraph=True), Disk, fwd+bwd matches eager", detail, "yes", ok))
    if memory:
        peaks = {kk: peak_memory("gaussian/scatter", kk, device) for kk in (7, 15, 31)}
        spread = max(peaks.values()) / min(peaks.values())
        result.append((
            "scatter peak memory K=31 / K=7 (" + ", ".join(
                f"K={kk}: {v / 2**20:.1f} MiB" for kk, v in peaks.items()) + ")",
            spread, "<= 1.25", spread <= 1.25))
    for aperture in ("Gaussian", "disk"):
        floor = paired_ratio(times, f"{aperture.lower()}/{FLOOR}", f"{aperture.lower()}/scatter")
        channels = jobs[f"{aperture.lower()}/{FLOOR}"].inputs[0].shape[1]
        print(f"reference: {aperture} scatter of {channels} channels (the layered "
              f"mode's two layers a source, no indexing: its arithmetic floor) / {aperture} "
              f"scatter: {floor:.2f}")
    for mode, kind in DEPTHS.items():
        per_source, per_row = layers_per_window(jobs[f"gaussian/{mode}"].inputs[2], 8, k)
        print(f"layers on the {kind} depth: {per_source:.2f} a source adds to, {per_row:.2f} an "
              f"8-pixel block sums per source row of its window (the exact kernel's work "
              f"follows the second)")
    medians = {name: statistics.median(t) * 1e3 for name, t in times.items()}
    print("goal configuration (1 thread, 1x3x512x512, K=15, fwd+bwd, medians, ms): " + ", ".join(
        f"{name} {value:.1f}" for name, value in medians.items()))
    return result


def compile_check(device) -> tuple[bool, str]:
    """`torch.compile(render_defocus, fullgraph=True)` with a Disk against eager, forward+backward."""
    image, coc, depth = make_inputs("disk", (1, 3, 64, 64), 15, device)
    psf = Disk().to(device)

    def render(i, c):
        return render_defocus(i, c, psf, "scatter")

    try:
        compiled = torch.compile(render, fullgraph=True)
        results = []
        for fn in (compiled, render):
            i, c = image.clone().requires_grad_(), coc.clone().requires_grad_()
            out = fn(i, c)
            results.append((out, *torch.autograd.grad(out.square().sum(), (i, c))))
        error = max(float((a - b).detach().abs().max()) for a, b in zip(*results, strict=True))
    except Exception as exc:  # report, do not crash the benchmark
        return False, f"failed: {type(exc).__name__}"
    return error < 1e-4, f"max |compiled - eager| = {error:.1e}"


def table(kernels, threads, rounds, device, memory: bool, methods) -> list[str]:
    lines = [
        "| threads | K | aperture | mode | fwd ms | fwd+bwd ms | / Gaussian scatter | "
        "/ gaussian_blur2d | fwd+bwd peak MiB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    print("\n".join(lines), flush=True)
    for n_threads in threads:
        torch.set_num_threads(n_threads)
        for k in kernels:
            names = ["kornia", "gaussian/scatter"]
            names += [m for m in methods if m not in names]
            unfold_bytes = SHAPE[0] * (SHAPE[1] + 2) * k * k * SHAPE[2] * SHAPE[3] * 4
            if "unfold" in names and unfold_bytes > UNFOLD_LIMIT_BYTES:
                names.remove("unfold")
            jobs = {name: Job(name, k, device) for name in names}
            forward = round_robin(jobs, False, rounds, device)
            both = round_robin(jobs, True, rounds, device)
            for name in names:
                peak = peak_memory(name, k, device, True, n_threads) if memory else math.nan
                aperture, _, mode = name.partition("/")
                if name in ("kornia", "unfold"):
                    aperture, mode = ("gaussian_blur2d", "-") if name == "kornia" else (
                        "unfold", "scatter")
                lines.append(
                    f"| {n_threads} | {k} | {aperture} | {mode} | "
                    f"{statistics.median(forward[name]) * 1e3:.1f} | "
                    f"{statistics.median(both[name]) * 1e3:.1f} | "
                    f"{paired_ratio(both, name, 'gaussian/scatter'):.2f} | "
                    f"{paired_ratio(both, name, 'kornia'):.2f} | {peak / 2**20:.1f} |"
                )
                print(lines[-1], flush=True)
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--rounds", type=int, default=9, help="round-robin rounds (medians)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--kernels", type=int, nargs="+", default=[15])
    parser.add_argument("--quick", action="store_true", help="only the goals, not the table")
    parser.add_argument("--no-memory", action="store_true", help="skip the memory subprocesses")
    parser.add_argument("--methods", nargs="+", default=None,
                        help="aperture/mode entries of the table (default: all, plus unfold)")
    parser.add_argument("--memory-probe", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_probe:
        print(_probe(json.loads(args.memory_probe)))
        return 0
    device = torch.device(args.device)
    compiled = device.type == "cpu" and _render_cpp.library() is not None
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    print(f"torch {torch.__version__}, device {device}, compiled CPU kernels: {compiled}, "
          f"{os.cpu_count()} CPUs, load average {load:.2f}")
    measured = goals(device, args.rounds, not args.no_memory)
    print("\n| goal (1 thread, 1x3x512x512, K=15, fwd+bwd, median of paired ratios) | measured "
          "| target | met |\n|---|---|---|---|")
    for name, value, target, ok in measured:
        shown = f"{value:.2f}" if isinstance(value, float) else value
        print(f"| {name} | {shown} | {target} | {'met' if ok else 'unmet'} |")
    if not args.quick:
        methods = args.methods or [f"{a}/{m}" for a in APERTURES for m in MODES] + ["unfold"]
        print()
        table(args.kernels, args.threads, max(3, args.rounds // 2), device, not args.no_memory,
              methods)
    return 0


if __name__ == "__main__":
    sys.exit(main())
