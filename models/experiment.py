"""Experiments built from the pieces: train then evaluate, and compare methods on one scene.

The `defocus demo` command and the per-dataset example scripts call these; they take datasets
(any sequence of samples in the sample format) as arguments, so `models` never imports `datasets`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import torch
from torch.utils.data import default_collate

from .direct import fit_depth_direct
from .metrics import best_constant_depth, depth_metrics
from .training import TrainConfig, Trainer


def constant_depth_metrics(
    train_set: Sequence[Mapping[str, Any]], test_set: Sequence[Mapping[str, Any]], **metric_kwargs: Any
) -> tuple[float, dict[str, float]] | None:
    """The best constant depth of the training depths (`best_constant_depth`, abs-rel-optimal)
    and its mean metrics on `test_set`; None when the training data holds no valid depth.

    Args:
        train_set: samples with `depth` and `mask`, where the constant is chosen.
        test_set: samples with `depth` and `mask`, where it is evaluated.
        **metric_kwargs: passed to `depth_metrics` (`max_depth`, `crop`, ...).
    """
    depths = [s["depth"][s["mask"].bool()] for s in train_set if bool(s["mask"].any())]
    if not depths:
        return None
    constant = best_constant_depth(target=torch.cat(depths))
    totals: dict[str, float] = {}
    for sample in test_set:
        row = depth_metrics(pred=torch.full_like(sample["depth"], constant),
                            target=sample["depth"], mask=sample["mask"], **metric_kwargs)
        for key, value in row.items():
            totals[key] = totals.get(key, 0.0) + value / len(test_set)
    return constant, totals


def reconstruction_metrics(trainer: Trainer, test_set: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Mean self-supervised loss terms on `test_set` (for data without ground-truth depth)."""
    totals: dict[str, float] = {}
    for sample in test_set:
        batch = default_collate([sample])
        depth = trainer.predict(batch["image"], batch["focused"], batch["camera"])
        with torch.no_grad():
            terms = trainer.loss_fn(depth, batch["image"].to(depth), batch["focused"].to(depth),
                                    batch["camera"].to(depth.device))
        for key, value in terms.items():
            totals[key] = totals.get(key, 0.0) + float(value) / len(test_set)
    return totals


def train_and_evaluate(
    config: TrainConfig,
    train_set: Sequence[Mapping[str, Any]],
    test_set: Sequence[Mapping[str, Any]],
    crop: str | Sequence[float] | None = None,
    has_depth: bool = True,
) -> dict[str, dict[str, float]]:
    """Train a network with `config` on `train_set`, then evaluate it on `test_set`.

    Args:
        config: the training run (its `depth_max` is also the evaluation cap).
        train_set: training samples in the sample format.
        test_set: test samples in the sample format.
        crop: evaluation crop (`"eigen"`, `"garg"` or fractions), see `Trainer.evaluate`.
        has_depth: False for data without ground truth: the rows then hold the self-supervised
            reconstruction losses instead of depth metrics.

    Returns:
        table rows: the trained network's, and (with depth) the best constant depth's.
    """
    trainer = Trainer(config, train_set)
    trainer.fit()
    method = f"ours ({config.network}, {config.input_mode}, {config.steps} steps)"
    if not has_depth:
        return {method: reconstruction_metrics(trainer, test_set)}
    rows = {method: trainer.evaluate(test_set, depth_cap=config.depth_max, crop=crop)}
    baseline = constant_depth_metrics(train_set, test_set, max_depth=config.depth_max, crop=crop)
    if baseline is not None:
        rows[f"best constant depth ({baseline[0]:.2f} m, from training depths)"] = baseline[1]
    return rows


def compare_on_scene(
    config: TrainConfig,
    train_set: Sequence[Mapping[str, Any]],
    val_set: Sequence[Mapping[str, Any]] | None,
    sample: Mapping[str, Any],
    direct_steps: int = 150,
) -> tuple[dict[str, dict[str, float]], dict[str, torch.Tensor]]:
    """Four ways to get one scene's depth, with their metrics on its ground truth.

    `self_supervised` and `supervised`: the network of `config` trained without and with depth
    labels (same budget); `direct_optimisation`: `fit_depth_direct` through the renderer, no
    network; `constant`: the best constant depth of the scene's own ground truth (an oracle).

    Args:
        config: the training run; `out_dir` gets one subfolder per trained method.
        train_set: training samples.
        val_set: validation samples (or None).
        sample: the test scene (unbatched sample with `depth` and `mask`).
        direct_steps: Adam steps of the direct fit.

    Returns:
        (metrics per method, depth `(1,H,W)` per method).
    """
    batch = default_collate([sample])
    target, mask = batch["depth"], batch["mask"]
    results: dict[str, dict[str, float]] = {}
    predictions: dict[str, torch.Tensor] = {}
    for method, supervision in (("self_supervised", "self"), ("supervised", "depth")):
        run = replace(config, supervision=supervision, out_dir=config.out_dir / method)
        labels = "no depth labels" if supervision == "self" else "depth labels"
        print(f"\n[{method}] training {run.steps} steps ({labels})")
        trainer = Trainer(run, train_set, val_set)
        trainer.fit()
        results[method] = trainer.evaluate([sample])
        predictions[method] = trainer.predict(batch["image"], batch["focused"], batch["camera"])[0]
    print(f"\n[direct_optimisation] fitting the scene's depth, {direct_steps} steps")
    direct = fit_depth_direct(batch["image"], batch["focused"], batch["camera"], config.depth_min,
                              config.depth_max, steps=direct_steps, progress=config.progress)
    results["direct_optimisation"] = depth_metrics(pred=direct, target=target, mask=mask)
    predictions["direct_optimisation"] = direct[0]
    constant = best_constant_depth(target=target, mask=mask)
    predictions["constant"] = torch.full_like(target[0], constant)
    results["constant"] = depth_metrics(pred=predictions["constant"][None], target=target,
                                        mask=mask)
    return results, predictions
