"""The self-supervised loss's SSIM, measured: `models.losses.ssim_map` against Kornia's SSIM.

Each training step computes the SSIM of every rendered shot against the real one, forward and
backward. Kornia filters its five local moments one after another; `ssim_map` filters them as
one stack. This prints, for batch 8 RGB images:

- the operations each dispatches for a forward and a backward (views and other metadata-only
  operations left out), which on a GPU are kernel launches the host must issue one by one;
- the median time of a forward and backward, paired back to back with Kornia's in one process,
  at 16 px (so small that the time is the cost of issuing the operations: what a GPU training
  step, bound by its host, pays) and at 256 px (the training crop);
- the largest difference of the two SSIM maps and of their gradients.

Goals: at most half Kornia's forward operations, at most 0.7x its time at 16 px and at most its
time at 256 px, maps and gradients within 1e-4.

Usage:

    python benchmarks/loss.py                 # CPU, one thread
    python benchmarks/loss.py --device cuda --json ssim.json
"""

from __future__ import annotations

import argparse
import collections
import json
import statistics
import sys
import time
from pathlib import Path

import kornia
import torch
from torch.utils._python_dispatch import TorchDispatchMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from models.losses import ssim_map  # noqa: E402

#: operations that move no data: not kernel launches
METADATA_OPS = {"view", "_unsafe_view", "expand", "unsqueeze", "squeeze", "detach", "alias",
                "slice", "select", "t", "transpose", "permute", "as_strided", "split",
                "split_with_sizes", "chunk", "unbind", "lift_fresh", "promote_types",
                "result_type"}


class _CountOps(TorchDispatchMode):
    def __init__(self):
        super().__init__()
        self.counts: collections.Counter[str] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.counts[func.overloadpacket.__name__] += 1
        return func(*args, **(kwargs or {}))

    def kernels(self) -> int:
        return sum(n for name, n in self.counts.items() if name not in METADATA_OPS)


def kornia_ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return kornia.metrics.ssim(x, y, 7)


def fused_ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return ssim_map(x, y, 7)


def _loss(ssim: torch.Tensor) -> torch.Tensor:
    return ((1 - ssim) / 2).clamp(0, 1).mean()


def count_ops(fn, x: torch.Tensor, y: torch.Tensor) -> tuple[int, int]:
    """Kernel-launching operations of a forward and of its backward."""
    fn(x, y)  # the first call may build and cache constants
    with _CountOps() as forward:
        loss = _loss(fn(x, y))
    with _CountOps() as backward:
        loss.backward()
    return forward.kernels(), backward.kernels()


def _step_seconds(fn, x: torch.Tensor, y: torch.Tensor) -> float:
    _sync(x.device)
    start = time.perf_counter()
    _loss(fn(x, y)).backward()
    _sync(x.device)
    return time.perf_counter() - start


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def paired_times(x: torch.Tensor, y: torch.Tensor, repeats: int) -> tuple[float, float]:
    """Median seconds of a forward and backward, Kornia's and ours, paired back to back."""
    for _ in range(3):
        _step_seconds(kornia_ssim, x, y), _step_seconds(fused_ssim, x, y)
    theirs, ours = [], []
    for _ in range(repeats):
        theirs.append(_step_seconds(kornia_ssim, x, y))
        ours.append(_step_seconds(fused_ssim, x, y))
    return statistics.median(theirs), statistics.median(ours)


def differences(x: torch.Tensor, y: torch.Tensor) -> float:
    """Largest absolute difference of the two maps and of their gradients."""
    out = []
    for fn in (kornia_ssim, fused_ssim):
        a = x.detach().clone().requires_grad_()
        ssim = fn(a, y)
        _loss(ssim).backward()
        out.append((ssim.detach(), a.grad))
    return max(float((p - q).abs().max()) for p, q in zip(*out, strict=True))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--sizes", default="16,256", help="image sizes, pixels, comma-separated")
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, help="write the rows to this JSON file")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    gen = torch.Generator().manual_seed(0)
    rows = []
    print(f"SSIM of {args.batch} RGB images, forward and backward, {device}, "
          f"{args.threads} thread(s), median of {args.repeats}")
    print(f"{'size':>5} {'ops fwd K/ours':>15} {'ops bwd K/ours':>15} {'Kornia ms':>10} "
          f"{'ours ms':>8} {'ratio':>6} {'max diff':>9}")
    for size in (int(s) for s in args.sizes.split(",")):
        x = torch.rand(args.batch, 3, size, size, generator=gen).to(device).requires_grad_()
        y = torch.rand(args.batch, 3, size, size, generator=gen).to(device)
        ops_k, ops_o = count_ops(kornia_ssim, x, y), count_ops(fused_ssim, x, y)
        theirs, ours = paired_times(x, y, args.repeats)
        diff = differences(x, y)
        rows.append({"size": size, "kornia_ops": ops_k, "ops": ops_o, "kornia_s": theirs,
                     "s": ours, "ratio": ours / theirs, "max_difference": diff})
        print(f"{size:>5} {ops_k[0]:>7}/{ops_o[0]:<7} {ops_k[1]:>7}/{ops_o[1]:<7} "
              f"{theirs * 1e3:>10.3f} {ours * 1e3:>8.3f} {ours / theirs:>6.2f} {diff:>9.1e}")
    small, large = rows[0], rows[-1]
    goals = [
        ("forward operations <= half Kornia's", small["ops"][0] <= small["kornia_ops"][0] / 2),
        (f"time <= 0.7x Kornia's at {small['size']} px", small["ratio"] <= 0.7),
        (f"time <= Kornia's at {large['size']} px", large["ratio"] <= 1.0),
        ("maps and gradients within 1e-4", all(r["max_difference"] <= 1e-4 for r in rows)),
    ]
    for goal, met in goals:
        print(f"goal: {goal}: {'met' if met else 'UNMET'}")
    if args.json:
        args.json.write_text(json.dumps({"device": str(device), "rows": rows,
                                         "goals": dict(goals)}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
