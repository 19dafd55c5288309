"""The README's main job (`defocus demo`).

1. Train the small depth-from-defocus network self-supervised (no depth labels in the loss) on the
   synthetic scenes of `datasets.synthetic` (camera `datasets.synthetic.SYNTHETIC_PRESET`:
   50 mm f/1.4 focused at 2 m and 6 m, effective pixel pitch 180 um).
2. Train the same network with supervised depth for the same number of steps.
3. Evaluate both on the real Middlebury motorcycle scene (never seen in training), downscaled by
   `scale`, whose focused images are rendered from its real depth through the same camera;
   add the direct optimisation baseline (`models.direct.fit_depth_direct`), the sweep over
   depth that `defocus predict` runs without a model file (`models.depth_from_photos.SweepDepth`,
   no network) and the best constant depth (an oracle: the abs-rel-optimal constant of the
   ground truth).
4. Write `metrics.json` and the figures under `out`, among them `focus_sweep.png`: the
   motorcycle rendered at four focus distances (`defocus render`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .outputs import plan_files

#: The rows of the demo's table, in order.
METHODS = ("self_supervised", "supervised", "direct_optimisation", "sweep", "constant")


@dataclass
class DemoResult:
    """What `run_demo` measured and wrote."""

    #: method -> metric -> value (the table)
    metrics: dict[str, dict[str, float]]
    #: the best constant depth, metres
    constant_depth: float
    #: the motorcycle scene's size, pixels (H, W)
    scene_size: tuple[int, int]
    #: files written
    metrics_path: Path
    focus_sweep_path: Path

    @property
    def ratio(self) -> float:
        """Self-supervised abs rel over the best constant's."""
        return self.metrics["self_supervised"]["abs_rel"] / self.metrics["constant"]["abs_rel"]


def run_demo(out: Path, steps: int = 500, batch_size: int = 8, lr: float = 2e-3, width: int = 24,
             scenes: int = 256, size: int = 48, scale: float = 0.25, direct_steps: int = 150,
             smoothness_weight: float = 0.01, seed: int = 0, progress: bool = True,
             overwrite: bool = False,
             report: Callable[[str], None] = lambda text: None) -> DemoResult:
    """Train, fit and evaluate every method of the demo (module docstring); returns the table.

    Example:
        >>> result = run_demo(Path("runs/demo"), steps=5)  # doctest: +SKIP
    """
    from datasets.middlebury import motorcycle_sample
    from datasets.synthetic import SYNTHETIC_PRESET, SyntheticScenes
    from defocus.app.render import write_focus_sweep
    from models.experiment import compare_on_scene
    from models.training import TrainConfig

    plan = plan_demo(out, overwrite)  # before any work: an earlier demo is kept
    out.mkdir(parents=True, exist_ok=True)
    preset = SYNTHETIC_PRESET
    depth_range = (preset.min_depth, preset.depth_cap)
    train_set = SyntheticScenes(scenes, (size, size), preset, seed=seed)
    val_set = SyntheticScenes(8, (size, size), preset, seed=seed + 1)
    sample = motorcycle_sample(scale, preset)
    report(f"motorcycle scene at {tuple(sample['image'].shape[-2:])} pixels; training on "
           f"{scenes} synthetic {size}x{size} scenes")
    config = TrainConfig(
        steps=steps, batch_size=batch_size, lr=lr, network="small",
        input_mode="aif+focused", out_dir=out, seed=seed, depth_min=depth_range[0],
        depth_max=depth_range[1], n_focus=len(preset.focus_distances), width=width,
        resume=False, log_every=10, smoothness_weight=smoothness_weight, progress=progress,
    )
    results, predictions = compare_on_scene(config, train_set, val_set, sample,
                                            direct_steps=direct_steps, report=report)
    metrics_path = out / "metrics.json"
    with plan.writing() as write:
        _write_figures(write, out, sample, predictions, depth_range)
        write(metrics_path, lambda tmp: tmp.write_text(json.dumps(results, indent=2)))
    sweep_path = write_focus_sweep(out, overwrite=overwrite)
    report(f"wrote {sweep_path} (the real scene through a thin lens at four focus distances)")
    return DemoResult(results, float(predictions["constant"].flatten()[0]),
                      tuple(sample["image"].shape[-2:]), metrics_path, sweep_path)


def plan_demo(out: Path, overwrite: bool = False):
    """The checked plan of the demo's files under `out` (`defocus.app.outputs`): an earlier
    demo's results and training runs are replaced only with `overwrite`.

    Example:
        >>> import tempfile
        >>> sorted(plan_demo(Path(tempfile.mkdtemp())).outputs)[0].name
        'focus_sweep.png'
    """
    from models.training import run_files

    names = {"metrics.json": "demo table", "focus_sweep.png": "focus sweep figure",
             "motorcycle_comparison.png": "demo figure",
             **{f"motorcycle_{method}.png": "demo figure" for method in METHODS}}
    plan = plan_files(Path(out), names, overwrite)[0]
    for method in ("self_supervised", "supervised"):
        earlier = run_files(Path(out) / method)
        if earlier and not overwrite:
            raise FileExistsError(f"{Path(out) / method} holds an earlier training run "
                                  f"({earlier[0].name}, ...); give --overwrite to replace it, "
                                  "or choose another --out")
    return plan


def _write_figures(write, out: Path, sample: dict[str, Any], predictions: dict[str, Any],
                   depth_range: tuple[float, float]) -> None:
    from models.plotting import plot_comparison, plot_prediction

    for method, depth in predictions.items():
        write(out / f"motorcycle_{method}.png", lambda tmp, depth=depth, method=method:
              plot_prediction(tmp, sample["image"], depth, sample["focused"], sample["depth"],
                              sample["mask"], title=f"motorcycle: {method}",
                              depth_range=depth_range))
    write(out / "motorcycle_comparison.png",
          lambda tmp: plot_comparison(tmp, sample, predictions, depth_range))
