"""Train the experimental camera-general blur network (`models.depth_from_photos.blur_net`).

`DepthFromDefocus(BlurNet)` reads the blur of each focused photo in pixels (it never sees the
camera) and solves the thin lens of any camera for depth. It is trained without depth labels on
procedural scenes under random cameras (`datasets.capture.RandomCameraScenes`); `--twin` also
trains its depth-supervised twin on the same budget. It is an experiment, not a product: on the
cameras benchmark it measures worse than the label-free sweep that `defocus predict` runs at
every camera (docs/tutorials/own_photos.md), so no weights ship and the command line does not
offer it. To compare it yourself:

    python examples/blur_net.py --config examples/blur_net.yaml --out runs/blur_net --twin
    python benchmarks/cameras.py --weights runs/blur_net/dfd_general.pt --no-direct

and in Python `estimate_depth(focused, settings, depth_range, image=image,
model=models.load_depth_model("runs/blur_net/dfd_general.pt"))`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _per_shot(samples: list[Mapping[str, Any]], key: str) -> torch.Tensor:
    """`sample[key]` `(3,H,W)` once per shot of each sample, stacked: `(sum F, 3, H, W)`."""
    return torch.cat([p[key][None].expand(len(p["focused"]), -1, -1, -1) for p in samples])


def train_blur_net(
    net, samples: Iterable[Mapping[str, Any]], steps: int, batch_size: int = 8,
    lr: float = 1e-3, supervision: str = "self", progress: bool = True,
    log: list[dict[str, float]] | None = None,
) -> torch.nn.Module:
    """Train `net` on samples with `image`, `focused` `(F,3,H,W)` and, for `"depth"`
    supervision, `coc_px` `(F,1,H,W)`; every shot is one training pair. Samples that also hold
    `clean_image` and `clean_focused` give the self-supervised loss its clean targets (see
    `blur_loss`). Adam, cosine schedule, gradient clipping; stops with an error at the first
    non-finite loss. The library's one training loop is `models.training.Trainer.fit`; this
    experiment's pairs of photos and blurs fit it less well than this short loop of its own."""
    from models.depth_from_photos.blur_net import blur_loss
    from optics.progress import progress_bar

    optimizer = torch.optim.Adam(net.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda s: 0.5 * (1 + math.cos(math.pi * min(s, steps) / steps)))
    stream = iter(samples)
    net.train()
    bar = progress_bar(range(int(steps)), desc=f"blur net ({supervision})", disable=not progress)
    for step in bar:
        pairs = [next(stream) for _ in range(batch_size)]
        image = _per_shot(pairs, "image")
        focused = torch.cat([p["focused"] for p in pairs])
        target = torch.cat([p["coc_px"] for p in pairs]) if supervision == "depth" else None
        clean = None
        if all("clean_image" in p for p in pairs):
            clean = (_per_shot(pairs, "clean_image"),
                     torch.cat([p["clean_focused"] for p in pairs]))
        loss = blur_loss(net, image, focused, supervision, target, clean=clean)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite blur-net loss at step {step}")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        optimizer.step()
        schedule.step()
        if log is not None:
            log.append({"step": step + 1, "loss": float(loss.detach()),
                        "lr": schedule.get_last_lr()[0]})
        bar.set_postfix(loss=f"{float(loss.detach()):.4f}", refresh=False)
    net.eval()
    return net


def train(config: dict, out: Path, twin: bool = False) -> list[Path]:
    """Train the blur network (and its twin) as `config` says; returns the weights written."""
    from datasets.capture import CaptureNoise, RandomCameraScenes
    from models.depth_from_photos import BlurNet, DepthFromDefocus
    from models.loading import save_weights

    torch.set_num_threads(int(config.get("threads", 1)))
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(config, indent=2))
    written = []
    for supervision in ("self", "depth") if twin else ("self",):
        torch.manual_seed(int(config["seed"]))
        data = RandomCameraScenes(int(config["pool_size"]), tuple(config["scene_size"]),
                                  tuple(config["crop"]), 2, tuple(config["max_coc_px"]),
                                  noise=CaptureNoise(**config.get("noise", {})),
                                  seed=int(config["seed"]))
        log: list[dict[str, float]] = []
        started = time.perf_counter()
        net = train_blur_net(BlurNet(int(config["width"])), data, int(config["steps"]),
                             int(config["batch_size"]), float(config["lr"]), supervision,
                             log=log)
        minutes = (time.perf_counter() - started) / 60
        name = "dfd_general" if supervision == "self" else "dfd_general_supervised"
        digest = save_weights(DepthFromDefocus(net), out / f"{name}.pt",
                              supervision=supervision, steps=int(config["steps"]),
                              minutes=round(minutes, 1), seed=int(config["seed"]))
        (out / f"{name}_log.json").write_text(json.dumps(log))
        print(f"{supervision}-supervised: {minutes:.1f} min; wrote {out / (name + '.pt')} "
              f"sha256 {digest}")
        written.append(out / f"{name}.pt")
    return written


def main(argv: list[str] | None = None) -> int:
    import yaml

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--config", type=Path, default=ROOT / "examples" / "blur_net.yaml",
                        help="YAML training config")
    parser.add_argument("--out", type=Path, default=Path("runs/blur_net"),
                        help="output folder: weights, logs")
    parser.add_argument("--twin", action="store_true",
                        help="also train the depth-supervised twin on the same budget")
    parser.add_argument("--steps", type=int, help="override the config's steps")
    args = parser.parse_args(argv)
    config = yaml.safe_load(args.config.read_text())
    if args.steps is not None:
        config["steps"] = args.steps
    try:
        train(config, args.out, args.twin)
    except (KeyError, TypeError, ValueError) as error:
        print(f"blur_net.py: error: {args.config}: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
