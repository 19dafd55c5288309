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
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def train(config: dict, out: Path, twin: bool = False) -> list[Path]:
    """Train the blur network (and its twin) as `config` says; returns the weights written."""
    import torch

    from datasets.capture import CaptureNoise, RandomCameraScenes
    from models.depth_from_photos import BlurNet, DepthFromDefocus, train_blur_net
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
