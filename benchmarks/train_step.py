"""Training steps per second, the share of each step spent waiting for data, and peak memory.

Trains the small (or the paper's) network on a real dataset with the examples' defaults (random
crops, flips and gains; loaded samples kept in memory, loaded once before timing as the examples
do) and times each step, split into waiting for the batch (`data_s`) and computing it
(`compute_s`). `--network`, `--precision`, `--compile` and `--workers` take comma-separated
lists; every combination is a setting, measured `--repeats` times, the settings interleaved in
one process so that they share the machine's load and the samples are loaded once. The table
gives the medians and each setting's steps/s against the first setting's. Peak memory is the
CUDA allocator's peak (read in this process, which leaves the allocator as it is) or, on the CPU,
the largest resident set of a separate process per setting. `--profile` adds where a step's
time goes for each network: each phase's host time (and, on a GPU, its kernels' time), its
count of elementary operations (on a GPU, about one kernel launch each), and the host time
those operations take to issue, measured on this machine.
`--learn-optics` learns the camera as well (data with synthesised focus: middlebury), and
`--optics-objective loss,contrast` compares the camera's two self-supervised objectives (the
contrast one's goal: at most `CONTRAST_COST_GOAL` times the first setting's step).

Usage:

    python benchmarks/train_step.py --dataset dslr --root ../shared/data/real/dfd_indoor
    python benchmarks/train_step.py --dataset middlebury --root builtin --profile
    python benchmarks/train_step.py --dataset dslr --root DIR --device cuda --network small,paper \\
        --precision float32,bfloat16 --compile off,on --workers -1 --json out.json
    python benchmarks/train_step.py --dataset middlebury --root builtin --workers 0 \\
        --learn-optics focus,f-number --optics-objective loss,contrast

Run `uptime` next to it: on a shared machine the numbers move with the load.
"""

from __future__ import annotations

import argparse
import itertools
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
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
#: goal: a self-supervised learned-optics step under `optics_objective=contrast` (two more
#: renders and losses, no network) at most this many times the step under "loss"
CONTRAST_COST_GOAL = 1.4
#: the phases of a step (compiled: the network and the loss are one phase)
PHASES = ("data", "network", "loss", "network and loss", "backward", "optimizer")


@dataclass(frozen=True)
class Setting:
    """One measured combination of the options."""

    network: str
    precision: str
    #: "off", "on" (`torch.compile` of the network and the loss) or "graphs" (and CUDA graphs)
    compile: str
    workers: int
    #: `TrainConfig.optics_objective` (used where `--learn-optics` is given)
    objective: str = "contrast"

    def label(self, learned: bool = False) -> str:
        compiled = {"off": "", "on": ", compiled", "graphs": ", compiled with CUDA graphs"}
        objective = f", optics objective {self.objective}" if learned else ""
        return f"{self.network}, {self.precision}{compiled[self.compile]}, " \
            f"workers={self.workers}{objective}"


def training_set(args: argparse.Namespace) -> tuple[torch.utils.data.Dataset, dict]:
    """The augmented training set and the config fields it needs, its samples loaded once."""
    augment = JointAugment(crop_size=(args.crop, args.crop), hflip=0.5, gain=0.1)
    if args.dataset == "dslr":
        scenes = None if args.scenes is None else slice(0, args.scenes)
        data = DSLR(args.root, "train", relative=True, camera=args.camera,
                    memory_cache_mb=2048, scenes=scenes)
        fields = {"n_focus": 1, "depth_min": 0.5, "depth_max": 10.0, "depth_spacing": "inverse"}
    else:
        root = None if args.root in (None, "builtin") else args.root
        data = Middlebury(root, memory_cache_mb=2048)
        fields = {"n_focus": data[0]["focused"].shape[0], "depth_min": 0.5, "depth_max": 10.0}
    for index in range(len(data)):  # the examples load every sample once before training
        data[index]
    return data.with_augment(augment), fields


def config(args: argparse.Namespace, fields: dict, setting: Setting, steps: int) -> TrainConfig:
    """A run of `steps` steps of `setting`, its folder a new one under `args.scratch` (removed
    when the benchmark ends)."""
    return TrainConfig(steps=steps, batch_size=args.batch_size, network=setting.network,
                       out_dir=Path(tempfile.mkdtemp(dir=args.scratch)), progress=False,
                       device=args.device, workers=setting.workers,
                       checkpoint_minutes=0, precision=setting.precision,
                       compile=setting.compile != "off", resume="overwrite",
                       compile_mode="reduce-overhead" if setting.compile == "graphs" else "default",
                       learn_optics=args.learn_optics or "", optics_objective=setting.objective,
                       **fields)


def _is_cuda(args: argparse.Namespace) -> bool:
    return torch.device(args.device).type == "cuda"


def measure(args: argparse.Namespace, data, fields: dict, setting: Setting) -> dict:
    """Median step seconds, the data-wait share and (CUDA) the allocator's peak of one run of
    `--steps` timed steps."""
    cfg = config(args, fields, setting, args.warmup + args.steps)
    if _is_cuda(args):
        torch.cuda.reset_peak_memory_stats(args.device)
    trainer = Trainer(cfg, data)
    if args.channels_last:  # the same Parameter objects, their memory in NHWC order
        trainer.model.to(memory_format=torch.channels_last)
    rows = trainer.fit()[args.warmup:]
    walls = [b["seconds"] - a["seconds"] for a, b in zip(rows, rows[1:], strict=False)]
    data_s = sum(r["data_s"] for r in rows)
    peak = torch.cuda.max_memory_allocated(args.device) / 2**20 if _is_cuda(args) else None
    return {"s_per_step": statistics.median(walls),
            "data_share": data_s / sum(r["data_s"] + r["compute_s"] for r in rows),
            "workers": trainer.workers, "peak_mb": peak, "split": trainer.step_timer.split()}


def peak_memory_mb(args: argparse.Namespace, setting: Setting) -> float:
    """CPU: the largest resident set of a separate process (or of its workers) running a few
    steps of this setting, MiB."""
    command = [sys.executable, __file__, *args.argv, "--network", setting.network,
               "--precision", setting.precision, "--compile", setting.compile,
               "--optics-objective", setting.objective, "--memory-of", str(setting.workers)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return float(done.stdout.strip().splitlines()[-1])


def memory_of(args: argparse.Namespace) -> None:
    data, fields = training_set(args)
    setting = Setting(args.network[-1], args.precision[-1], args.compile[-1], args.memory_of,
                      args.optics_objective[-1])
    cfg = config(args, fields, setting, args.warmup + 3)
    Trainer(cfg, data).fit()
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


def _kernel_us(event) -> float:
    """Microseconds of device kernels launched under a profiled range."""
    own = sum(k.duration for k in getattr(event, "kernels", []))
    return own + sum(_kernel_us(c) for c in event.cpu_children)


def profile(args: argparse.Namespace, data, fields: dict, setting: Setting) -> dict[str, dict]:
    """Per phase of a step: host and kernel milliseconds (means over the profiled steps) and
    elementary ops."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    steps = 3
    cfg = config(args, fields, setting, args.warmup + steps)
    activities = [ProfilerActivity.CPU]
    if _is_cuda(args):
        activities.append(ProfilerActivity.CUDA)
    prof = torch_profile(activities=activities)

    def profile_steps(trainer: Trainer, step: int, losses: dict) -> None:
        # one run: the workers and the device thread keep going between warm-up and profile
        if step == args.warmup:
            prof.start()
        elif step == args.warmup + steps:
            if _is_cuda(args):
                torch.cuda.synchronize(args.device)
            prof.stop()

    Trainer(cfg, data, step_callback=profile_steps).fit()
    phases = {name: {"ms": 0.0, "kernel_ms": 0.0, "ops": 0} for name in PHASES}
    # every kernel of the steps, those the backward pass launches from autograd's thread too
    busy = sum(getattr(e, "self_device_time_total", 0.0) for e in prof.key_averages())
    phases["device busy"] = {"ms": 0.0, "kernel_ms": busy / 1e3 / steps, "ops": 0}
    for event in prof.events():
        if event.name in phases and event.cpu_parent is None:
            phases[event.name]["ms"] += event.cpu_time_total / 1e3 / steps
            phases[event.name]["kernel_ms"] += _kernel_us(event) / 1e3 / steps
            phases[event.name]["ops"] += _leaf_ops(event) // steps
    return phases


def print_profile(setting: Setting, phases: dict[str, dict], per_op_s: float,
                  cuda: bool) -> None:
    total = sum(p["ms"] for p in phases.values())
    ops = sum(p["ops"] for p in phases.values())
    kernel = " kernels, ms/step |" if cuda else ""
    print(f"\nWhere a step's time goes ({setting.label()}; host time to issue one op here: "
          f"{per_op_s * 1e6:.1f} us)")
    print(f"| phase | host ms/step | share |{kernel} elementary ops | issue time, ms |")
    print("|---|---|---|---|---|" + ("---|" if cuda else ""))
    busy = phases.pop("device busy", None)
    for name, p in phases.items():
        if not (p["ms"] or p["ops"]):
            continue
        k = f" {p['kernel_ms']:.1f} |" if cuda else ""
        print(f"| {name} | {p['ms']:.1f} | {p['ms'] / max(total, 1e-9):.0%} |{k} {p['ops']} | "
              f"{p['ops'] * per_op_s * 1e3:.1f} |")
    floor = ops * per_op_s
    k = f" {sum(p['kernel_ms'] for p in phases.values()):.1f} |" if cuda else ""
    print(f"| all | {total:.1f} | 100% |{k} {ops} | {floor * 1e3:.1f} |")
    if cuda and busy is not None:
        print(f"The GPU runs kernels {busy['kernel_ms']:.1f} ms per step, every phase's (the "
              "backward's kernels too, which the table's backward row cannot see).")
    print(f"Issuing the ops alone caps a step at {1 / floor:.0f} steps/s on any device; on a GPU "
          "the step takes at least that long unless the ops are fused (torch.compile) or "
          "captured (CUDA graphs).")


def goals(kind: str, rows: list[dict], args: argparse.Namespace) -> list[tuple[str, bool]]:
    """(goal, met) for the table's rows."""
    best = max(rows, key=lambda r: r["steps_per_s"])
    out = [(f"data wait <= {DATA_WAIT_GOAL[kind]:.0%} of the step ({best['setting']})",
            best["data_share"] <= DATA_WAIT_GOAL[kind])]
    if kind == "cpu":
        for r in rows[1:]:
            if r["objective"] != rows[0]["objective"]:  # a cost the objective is allowed
                out.append((f"{r['setting']}: s/step <= {CONTRAST_COST_GOAL:.1f}x the first "
                            "setting's", 1 / r["ratio"] <= CONTRAST_COST_GOAL))
            else:
                out.append((f"{r['setting']}: steps/s >= {CPU_SPEED_RATIO_GOAL:.2f}x the "
                            "first setting", r["ratio"] >= CPU_SPEED_RATIO_GOAL))
        return out
    small = [r for r in rows if r["network"] == "small"]
    if small and args.batch_size == 8 and args.crop == 256:
        fastest = max(small, key=lambda r: r["steps_per_s"])
        out.append((f"small network >= {GPU_STEPS_PER_S_GOAL:.0f} steps/s ({fastest['setting']})",
                    fastest["steps_per_s"] >= GPU_STEPS_PER_S_GOAL))
    return out


def _choices(name: str, allowed: tuple[str, ...]):
    def parse_list(text: str) -> list[str]:
        values = [v.strip() for v in text.split(",")]
        bad = [v for v in values if v not in allowed]
        if bad:
            raise argparse.ArgumentTypeError(
                f"{name} takes a comma-separated list of {', '.join(allowed)}; got {text!r}")
        return values
    return parse_list


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--dataset", choices=["dslr", "middlebury"], default="dslr")
    parser.add_argument("--root", default=None, help="the dataset folder (middlebury: "
                        "'builtin' for the scene embedded in scikit-image)")
    parser.add_argument("--camera", type=Path, default=None, help="dslr: a fitted camera JSON")
    parser.add_argument("--scenes", type=int, default=None,
                        help="dslr: train on the first N scenes only (loads faster; a step's "
                             "time does not depend on how many scenes there are)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda, cuda:1, ...")
    parser.add_argument("--network", type=_choices("--network", ("small", "paper")),
                        default=["small"], help="small, paper, or both: small,paper")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--crop", type=int, default=None,
                        help="crop side, pixels (default: 128 on the CPU, 256 on a GPU)")
    parser.add_argument("--workers", default="0,-1",
                        help="comma-separated worker counts to compare (-1: automatic)")
    parser.add_argument("--precision",
                        type=_choices("--precision", ("auto", "float32", "bfloat16")),
                        default=["float32"], help="float32, bfloat16, auto (the training "
                        "default: bfloat16 on a CPU with native bfloat16), or a list")
    parser.add_argument("--compile", nargs="?", const=["on"], default=["off"],
                        type=_choices("--compile", ("off", "on", "graphs")),
                        help="torch.compile the network and the loss: off, on (the flag alone), "
                             "graphs (and CUDA graphs: compile_mode=reduce-overhead), or a list")
    parser.add_argument("--learn-optics", default=None, metavar="WHAT",
                        help="learn the camera too (TrainConfig.learn_optics, e.g. "
                             "focus,f-number): data with synthesised focus (middlebury)")
    parser.add_argument("--optics-objective", default=["contrast"],
                        type=_choices("--optics-objective", ("loss", "contrast")),
                        help="with --learn-optics: loss, contrast, or both: loss,contrast")
    parser.add_argument("--steps", type=int, default=10, help="timed steps per repetition")
    parser.add_argument("--warmup", type=int, default=3, help="untimed first steps")
    parser.add_argument("--repeats", type=int, default=3, help="repetitions per setting")
    parser.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    parser.add_argument("--profile", action="store_true", help="add where a step's time goes")
    parser.add_argument("--channels-last", action="store_true",
                        help="the network's weights in channels-last order (NHWC convolutions)")
    parser.add_argument("--cudnn-benchmark", action="store_true",
                        help="let cuDNN time its convolution algorithms (fixed crop sizes)")
    parser.add_argument("--no-memory", action="store_true", help="skip the peak-memory runs")
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    parser.add_argument("--memory-of", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.dataset == "dslr" and args.root is None:
        parser.error("--dataset dslr needs --root (the DSLR release's folder)")
    if args.steps < 2:
        parser.error(f"--steps must be at least 2 (a step's time is the interval between two), "
                     f"got {args.steps}")
    if args.crop is None:
        args.crop = 256 if torch.device(args.device).type == "cuda" else 128
    args.workers = [int(w) for w in str(args.workers).split(",")]
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    with tempfile.TemporaryDirectory(prefix="defocus-bench-") as args.scratch:
        return run(args)


def run(args: argparse.Namespace) -> int:
    torch.set_num_threads(args.threads)
    torch.backends.cudnn.benchmark = args.cudnn_benchmark
    if args.memory_of is not None:
        memory_of(args)
        return 0
    kind = torch.device(args.device).type
    data, fields = training_set(args)
    settings = [Setting(*s) for s in itertools.product(
        args.network, args.precision, args.compile, args.workers, args.optics_objective)]
    runs: dict[Setting, list[dict]] = {s: [] for s in settings}
    for _ in range(args.repeats):  # settings interleaved: they share the machine's load
        for setting in settings:
            runs[setting].append(measure(args, data, fields, setting))
    rows = []
    for setting, measured in runs.items():
        s = statistics.median(m["s_per_step"] for m in measured)
        if kind == "cuda":
            peak = max(m["peak_mb"] for m in measured)
        else:
            peak = None if args.no_memory else peak_memory_mb(args, setting)
        rows.append({"setting": setting.label(bool(args.learn_optics)),
                     "network": setting.network, "objective": setting.objective,
                     "precision": setting.precision, "compile": setting.compile,
                     "workers": measured[0]["workers"], "steps_per_s": 1 / s, "s_per_step": s,
                     "data_share": statistics.median(m["data_share"] for m in measured),
                     "protocol_minutes": PROTOCOL_STEPS * s / 60, "peak_mb": peak,
                     "split_ms": {name: 1000 * statistics.median(m["split"].get(name, 0.0)
                                                                 for m in measured)
                                  for name in measured[0]["split"]}})
    for row in rows:
        row["ratio"] = row["steps_per_s"] / rows[0]["steps_per_s"]
    print(f"{args.dataset}, batch {args.batch_size}, {args.crop}x{args.crop} crops, "
          f"{args.device}, {args.threads} thread(s)"
          f"{', channels-last weights' if args.channels_last else ''}"
          f"{', cuDNN benchmark mode' if args.cudnn_benchmark else ''}; medians of "
          f"{args.repeats} runs of {args.steps} steps")
    print("| network | precision | compiled | workers | optics objective | steps/s | vs first | "
          "data wait | peak MiB | 20000 steps, min |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        peak = "-" if r["peak_mb"] is None else f"{r['peak_mb']:.0f}"
        objective = r["objective"] if args.learn_optics else "-"
        print(f"| {r['network']} | {r['precision']} | {r['compile']} | "
              f"{r['workers']} | {objective} | {r['steps_per_s']:.2f} | {r['ratio']:.2f}x | "
              f"{r['data_share']:.1%} | {peak} | {r['protocol_minutes']:.0f} |")
    print("\nA step's time, ms (the trainer's host timers; medians of the runs' means):")
    for r in rows:
        print(f"  {r['setting']}: " + ", ".join(f"{name} {ms:.0f}"
                                               for name, ms in r["split_ms"].items()))
    results = {"args": {k: str(v) for k, v in vars(args).items()
                        if k not in ("argv", "scratch")}, "rows": rows,
               "goals": [{"goal": g, "met": met} for g, met in goals(kind, rows, args)]}
    print("\n| goal | met |\n|---|---|")
    for goal in results["goals"]:
        print(f"| {goal['goal']} | {'met' if goal['met'] else 'unmet'} |")
    if kind != "cuda":
        print("No GPU in this run: the GPU goals (>= 40 steps/s for the small network, data "
              "wait <= 5 %) are not measured.")
    if args.profile:
        per_op = issue_seconds_per_op()
        results["issue_seconds_per_op"] = per_op
        results["profile"] = {}
        for network in args.network:
            setting = Setting(network, args.precision[0], args.compile[0], args.workers[-1])
            phases = profile(args, data, fields, setting)
            results["profile"][setting.label()] = phases
            print_profile(setting, phases, per_op, kind == "cuda")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
