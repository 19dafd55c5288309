"""`defocus pretrain`: train the shipped camera-general depth-from-defocus model from scratch.

Reads a YAML config (`models/weights/dfd_general.yaml` is the shipped model's), trains the blur
network self-supervised and, with `--twin`, its depth-supervised twin on the same budget, and
writes the weights (with their sha256), the training logs and the camera benchmark's table.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path,
                        default=Path(__file__).resolve().parents[2] / "models" / "weights"
                        / "dfd_general.yaml", help="YAML training config")
    parser.add_argument("--out", type=Path, default=Path("runs/pretrain"),
                        help="output folder: weights, logs")
    parser.add_argument("--twin", action="store_true",
                        help="also train the depth-supervised twin on the same budget")
    parser.add_argument("--steps", type=int, default=None, help="override the config's steps")


def run(args: argparse.Namespace) -> int:
    import json
    import time

    import torch
    import yaml

    from datasets.capture import CaptureNoise, RandomCameraScenes
    from models.blur import BlurNet, DepthFromDefocus, train_blur_net
    from models.pretrained import save_weights

    config = yaml.safe_load(args.config.read_text())
    if args.steps is not None:
        config["steps"] = args.steps
    torch.set_num_threads(int(config.get("threads", 1)))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "config.json").write_text(json.dumps(config, indent=2))
    for supervision in ("self", "depth") if args.twin else ("self",):
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
        digest = save_weights(DepthFromDefocus(net), args.out / f"{name}.pt",
                              supervision=supervision, steps=int(config["steps"]),
                              minutes=round(minutes, 1), seed=int(config["seed"]))
        (args.out / f"{name}_log.json").write_text(json.dumps(log))
        print(f"{supervision}-supervised: {minutes:.1f} min; wrote {args.out / (name + '.pt')} "
              f"sha256 {digest}")
    return 0
