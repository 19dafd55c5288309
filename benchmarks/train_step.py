"""Training steps per second, the share of each step spent waiting for data, and peak memory.

Trains the small (or the paper's) network on a real dataset with the examples' defaults (random
crops, flips and gains; loaded samples kept in memory, loaded once before timing as the examples
do) and times each step, split into waiting for the batch (`data_s`) and computing it
(`compute_s`). Each `--workers` setting is measured `--repeats` times, the settings interleaved
in one process so that they share the machine's load; the table gives the medians and each
setting's steps/s against the first setting's. Peak memory comes from a separate process per
setting. `--profile` adds where a step's time goes: each phase's time and its count of
elementary operations (on a GPU, about one kernel launch each), and the host time those
operations take to issue, measured on this machine.

Usage:

    python benchmarks/train_step.py --dataset dslr --root ../shared/data/real/dfd_indoor
    python benchmarks/train_step.py --dataset middlebury --root builtin --profile
    python benchmarks/train_step.py --dataset dslr --root DIR --device cuda --network paper \\
        --json out.json

Run `uptime` next to it: on a shared machine the numbers move with the load.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from datasets import DSLR, JointAugment, Middlebury  # noqa: E402
from models.training import TrainConfig, Trainer  # noqa: E402

#: the paper's protocol, for the wall-time estimate
PROTOCOL_STEPS = 20000
#: goals: the share of the step spent waiting for data, per device kind
DATA_WAIT_GOAL = {"cpu": 0.10, "cuda": 0.05}
#: goal: the small network's steps/s on a GPU at batch 8 and 256-pixel crops
GPU_STEPS_PER_S_GOAL = 40.0
#: goal on the CPU: steps/s of every setting at least this share of the first setting's
CPU_SPEED_RATIO_GOAL = 0.95
PHASES = ("data", "network", "loss", "backward", "optimizer")


def training_set(args: argparse.Namespace) -> tuple[torch.utils.data.Dataset, dict]:
    """The augmented training set and the config fields it needs, its samples loaded once."""
    augment = JointAugment(crop_size=(args.crop, args.crop), hflip=0.5, gain=0.1)
    if args.dataset == "dslr":
        data = DSLR(args.root, "train", relative=True, camera=args.camera,
                    memory_cache_mb=2048)
        fields = {"n_focus": 1, "depth_min": 0.5, "depth_max": 10.0, "depth_spacing": "inverse"}
    else:
        root = None if args.root in (None, "builtin") else args.root
        data = Middlebury(root, memory_cache_mb=2048)
        fields = {"n_focus": data[0]["focused"].shape[0], "depth_min": 0.5, "depth_max": 10.0}
    for index in range(len(data)):  # the examples load every sample once before training
        data[index]
    return data.with_augment(augment), fields


def config(args: argparse.Namespace, fields: dict, workers: int, steps: int,
           out: Path) -> TrainConfig:
    return TrainConfig(steps=steps, batch_size=args.batch_size, network=args.network,
                       out_dir=out, progress=False, device=args.device, workers=workers,
                       checkpoint_minutes=0, precision=args.precision, compile=args.compile,
                       resume="overwrite", **fields)


def measure(args: argparse.Namespace, data, fields: dict, workers: int) -> dict:
    """Median step seconds and the data-wait share of one run of `--steps` timed steps."""
    cfg = config(args, fields, workers, args.warmup + args.steps,
                 Path(tempfile.mkdtemp(prefix="defocus-bench-")))
    trainer = Trainer(cfg, data)
    rows = trainer.fit()[args.warmup:]
    walls = [b["seconds"] - a["seconds"] for a, b in zip(rows, rows[1:], strict=False)]
    data_s = sum(r["data_s"] for r in rows)
    return {"s_per_step": statistics.median(walls),
            "data_share": data_s / sum(r["data_s"] + r["compute_s"] for r in rows),
            "workers": trainer.workers}


def peak_memory_mb(args: argparse.Namespace, workers: int) -> float:
    """Peak memory of a separate process running a few steps of this setting, MiB (GPU: the
    allocator's peak; CPU: the largest resident set of the process or a worker)."""
    command = [sys.executable, __file__, *args.argv, "--memory-of", str(workers)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return float(done.stdout.strip().splitlines()[-1])


def memory_of(args: argparse.Namespace) -> None:
    data, fields = training_set(args)
    cfg = config(args, fields, args.memory_of, args.warmup + 3,
                 Path(tempfile.mkdtemp(prefix="defocus-bench-")))
    Trainer(cfg, data).fit()
    if torch.device(cfg.device).type == "cuda":
        print(torch.cuda.max_memory_allocated() / 2**20)
        return
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    print(max(own, workers) / 1024)  # Linux: KiB


def issue_seconds_per_op(repeats: int = 20000) -> float:
    """Host seconds to issue one small PyTorch operation, measured here (median of 5)."""
    x = torch.zeros(1)
    times = []
    for _ in range(5):
        started = time.perf_counter()
        for _ in range(repeats):
            x = x.add(1.0)
        times.append((time.perf_counter() - started) / repeats)
    return statistics.median(times)


def _leaf_ops(event) -> int:
    """Elementary operations under a profiled range: aten ops that call no other aten op."""
    children = [c for c in event.cpu_children if c.name.startswith("aten::")]
    if event.name.startswith("aten::") and not children:
        return 1
    return sum(_leaf_ops(c) for c in event.cpu_children)


def profile(args: argparse.Namespace, data, fields: dict, workers: int) -> dict[str, dict]:
    """Per phase of a step: milliseconds (mean over the profiled steps) and elementary ops."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    steps = 3
    cfg = config(args, fields, workers, args.warmup + steps,
                 Path(tempfile.mkdtemp(prefix="defocus-bench-")))
    trainer = Trainer(cfg, data)
    trainer.fit(until=args.warmup)
    activities = [ProfilerActivity.CPU]
    if torch.device(cfg.device).type == "cuda":
        activities.append(ProfilerActivity.CUDA)
    with torch_profile(activities=activities) as prof:
        trainer.fit()
    phases = {name: {"ms": 0.0, "ops": 0} for name in PHASES}
    for event in prof.events():
        if event.name in phases and event.cpu_parent is None:
            phases[event.name]["ms"] += event.cpu_time_total / 1e3 / steps
            phases[event.name]["ops"] += _leaf_ops(event) // steps
    return phases


def print_profile(phases: dict[str, dict], per_op_s: float) -> None:
    total = sum(p["ms"] for p in phases.values())
    ops = sum(p["ops"] for p in phases.values())
    print(f"\nWhere a step's time goes (host time to issue one op here: {per_op_s * 1e6:.1f} us)")
    print("| phase | ms/step | share | elementary ops | issue time, ms |")
    print("|---|---|---|---|---|")
    for name, p in phases.items():
        print(f"| {name} | {p['ms']:.1f} | {p['ms'] / max(total, 1e-9):.0%} | {p['ops']} | "
              f"{p['ops'] * per_op_s * 1e3:.1f} |")
    floor = ops * per_op_s
    print(f"| all | {total:.1f} | 100% | {ops} | {floor * 1e3:.1f} |")
    print(f"Issuing the ops alone caps a step at {1 / floor:.0f} steps/s on any device; on a GPU "
          "the step takes at least that long unless the ops are fused (torch.compile) or "
          "captured (CUDA graphs).")


def goals(kind: str, rows: list[dict], args: argparse.Namespace) -> list[tuple[str, bool]]:
    """(goal, met) for the table's rows."""
    best = max(rows, key=lambda r: r["steps_per_s"])
    out = [(f"data wait <= {DATA_WAIT_GOAL[kind]:.0%} of the step (workers={best['workers']})",
            best["data_share"] <= DATA_WAIT_GOAL[kind])]
    if kind == "cpu":
        out += [(f"workers={r['workers']}: steps/s >= {CPU_SPEED_RATIO_GOAL:.2f}x the first "
                 "setting", r["ratio"] >= CPU_SPEED_RATIO_GOAL) for r in rows[1:]]
    elif args.network == "small" and args.batch_size == 8 and args.crop == 256:
        out.append((f"small network >= {GPU_STEPS_PER_S_GOAL:.0f} steps/s",
                    best["steps_per_s"] >= GPU_STEPS_PER_S_GOAL))
    return out


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--dataset", choices=["dslr", "middlebury"], default="dslr")
    parser.add_argument("--root", default=None, help="the dataset folder (middlebury: "
                        "'builtin' for the scene embedded in scikit-image)")
    parser.add_argument("--camera", type=Path, default=None, help="dslr: a fitted camera JSON")
    parser.add_argument("--device", default="cpu", help="cpu, cuda, cuda:1, ...")
    parser.add_argument("--network", choices=["small", "paper"], default="small")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--crop", type=int, default=None,
                        help="crop side, pixels (default: 128 on the CPU, 256 on a GPU)")
    parser.add_argument("--workers", default="0,-1",
                        help="comma-separated worker counts to compare (-1: automatic)")
    parser.add_argument("--precision", choices=["float32", "bfloat16"], default="float32")
    parser.add_argument("--compile", action="store_true", help="torch.compile the network")
    parser.add_argument("--steps", type=int, default=10, help="timed steps per repetition")
    parser.add_argument("--warmup", type=int, default=3, help="untimed first steps")
    parser.add_argument("--repeats", type=int, default=3, help="repetitions per setting")
    parser.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    parser.add_argument("--profile", action="store_true", help="add where a step's time goes")
    parser.add_argument("--no-memory", action="store_true", help="skip the peak-memory runs")
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    parser.add_argument("--memory-of", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.dataset == "dslr" and args.root is None:
        parser.error("--dataset dslr needs --root (the DSLR release's folder)")
    if args.crop is None:
        args.crop = 256 if torch.device(args.device).type == "cuda" else 128
    args.workers = [int(w) for w in str(args.workers).split(",")]
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    torch.set_num_threads(args.threads)
    if args.memory_of is not None:
        memory_of(args)
        return 0
    kind = torch.device(args.device).type
    data, fields = training_set(args)
    runs: dict[int, list[dict]] = {w: [] for w in args.workers}
    for _ in range(args.repeats):  # settings interleaved: they share the machine's load
        for workers in args.workers:
            runs[workers].append(measure(args, data, fields, workers))
    rows = []
    for workers, measured in runs.items():
        s = statistics.median(m["s_per_step"] for m in measured)
        rows.append({"workers": measured[0]["workers"], "setting": workers,
                     "steps_per_s": 1 / s, "s_per_step": s,
                     "data_share": statistics.median(m["data_share"] for m in measured),
                     "protocol_minutes": PROTOCOL_STEPS * s / 60,
                     "peak_mb": None if args.no_memory else peak_memory_mb(args, workers)})
    for row in rows:
        row["ratio"] = row["steps_per_s"] / rows[0]["steps_per_s"]
    print(f"{args.dataset}, {args.network} network, batch {args.batch_size}, "
          f"{args.crop}x{args.crop} crops, {args.device}, {args.threads} thread(s), "
          f"{args.precision}{', compiled' if args.compile else ''}; medians of {args.repeats} "
          f"runs of {args.steps} steps")
    print("| workers | steps/s | vs first | data wait | peak MiB | 20000 steps, min |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        peak = "-" if r["peak_mb"] is None else f"{r['peak_mb']:.0f}"
        print(f"| {r['workers']} | {r['steps_per_s']:.2f} | {r['ratio']:.2f}x | "
              f"{r['data_share']:.1%} | {peak} | {r['protocol_minutes']:.0f} |")
    results = {"args": {k: str(v) for k, v in vars(args).items() if k != "argv"}, "rows": rows,
               "goals": [{"goal": g, "met": met} for g, met in goals(kind, rows, args)]}
    print("\n| goal | met |\n|---|---|")
    for goal in results["goals"]:
        print(f"| {goal['goal']} | {'met' if goal['met'] else 'unmet'} |")
    if kind != "cuda":
        print("No GPU in this run: the GPU goals (>= 40 steps/s for the small network, data "
              "wait <= 5 %) are not measured.")
    if args.profile:
        per_op = issue_seconds_per_op()
        results["profile"] = profile(args, data, fields, rows[-1]["workers"])
        results["issue_seconds_per_op"] = per_op
        print_profile(results["profile"], per_op)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
