"""Seconds per training step of `examples/middlebury.py --root builtin`, with user and system time.

Each step's wall, user and system CPU time come from `time.perf_counter` and
`resource.getrusage(RUSAGE_SELF)` read around the step (the first `--warmup` steps, which load
and synthesise, are reported apart). Two configurations:

- `before`: what the example did before issue 15: the whole 741x500 scene in every sample, its
  focal stack synthesised again for every sample of every step, no cache.
- `after`: the example's defaults now: a random crop (`--crop`) of the full-resolution sample,
  its focal stack synthesised once (kept in memory and in a cache folder), freed large blocks
  kept in the process (`models.experiment.keep_freed_memory`).

Usage:

    python benchmarks/train_step.py                         # both, batch 8, 3 timed steps
    python benchmarks/train_step.py --config after --steps 20 --crop 128
    python benchmarks/train_step.py --threads 2 --json out.json

Run `uptime` next to it: on a shared machine the numbers move with the load.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from datasets import JointAugment, Middlebury  # noqa: E402
from models.training import TrainConfig, Trainer  # noqa: E402


def _usage() -> tuple[float, float, float]:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return time.perf_counter(), usage.ru_utime, usage.ru_stime


def measure(config: str, steps: int, warmup: int, batch_size: int, crop: int,
            width: int) -> dict:
    """Per-step wall, user and system seconds of one configuration (median and totals)."""
    folder = Path(tempfile.mkdtemp(prefix="defocus-bench-"))
    if config == "before":
        dataset = Middlebury(None, augment=JointAugment(hflip=0.5, gain=0.1))
    else:
        from models.experiment import keep_freed_memory

        keep_freed_memory()
        kwargs = {"cache_dir": folder / "cache"}
        if _has_memory_cache():
            kwargs["memory_cache_mb"] = 1024
        dataset = Middlebury(None, augment=JointAugment(crop_size=(crop, crop), hflip=0.5,
                                                         gain=0.1), **kwargs)
    cfg = TrainConfig(steps=warmup + steps, batch_size=batch_size, width=width,
                      out_dir=folder / "run", progress=False, depth_min=0.5, depth_max=10.0,
                      device="cpu")
    trainer = Trainer(cfg, dataset)
    marks = [_usage()]
    trainer.step_callback = lambda *_: marks.append(_usage())
    trainer.fit()
    deltas = [tuple(b - a for a, b in zip(x, y, strict=True))
              for x, y in zip(marks, marks[1:], strict=False)]
    timed = deltas[warmup:]
    wall, user, system = (statistics.median(d[i] for d in timed) for i in range(3))
    return {"config": config, "batch_size": batch_size,
            "pixels": "741x500" if config == "before" else f"{crop}x{crop}",
            "warmup_s": sum(d[0] for d in deltas[:warmup]), "steps": steps,
            "s_per_step": wall, "user_s_per_step": user, "sys_s_per_step": system,
            "sys_over_user": system / max(user, 1e-9), "threads": torch.get_num_threads()}


def _has_memory_cache() -> bool:
    import inspect

    from datasets import DepthDataset

    return "memory_cache_mb" in inspect.signature(DepthDataset.__init__).parameters


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", choices=["before", "after", "both"], default="both")
    parser.add_argument("--steps", type=int, default=3, help="timed steps per configuration")
    parser.add_argument("--warmup", type=int, default=1, help="untimed first steps")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--crop", type=int, default=128, help="crop side of `after`, pixels")
    parser.add_argument("--width", type=int, default=32, help="small network width")
    parser.add_argument("--threads", type=int, default=None, help="torch.set_num_threads")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    configs = ["before", "after"] if args.config == "both" else [args.config]
    rows = []
    print("| config | pixels | batch | s/step | user s/step | sys s/step | sys/user | warm-up s |")
    print("|---|---|---|---|---|---|---|---|")
    for config in configs:
        row = measure(config, args.steps, args.warmup, args.batch_size, args.crop, args.width)
        rows.append(row)
        print(f"| {config} | {row['pixels']} | {row['batch_size']} | {row['s_per_step']:.2f} | "
              f"{row['user_s_per_step']:.2f} | {row['sys_s_per_step']:.2f} | "
              f"{row['sys_over_user']:.2f} | {row['warmup_s']:.1f} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
