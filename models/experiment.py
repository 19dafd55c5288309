"""Experiments built from the pieces: train then evaluate, and compare methods on one scene.

The `defocus demo` command and the per-dataset example scripts call these; they take datasets
(any sequence of samples in the sample format) as arguments, so `models` never imports `datasets`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import torch
from torch import Tensor
from torch.utils.data import Subset

from optics import collate

from .depth_from_photos import estimate_depth
from .direct import fit_depth_direct
from .evaluation import TILE_PIXELS, evaluate, network_method
from .metrics import best_constant_depth, depth_metrics, depth_order
from .training import TrainConfig, Trainer
from .training.learned_camera import rendered_samples


def keep_freed_memory() -> bool:
    """Keep freed large blocks in the process (glibc `mallopt`) instead of giving them back to
    the system on every free; returns whether the setting was applied (Linux with glibc).

    A training step allocates and frees the same large buffers every time; with glibc's
    defaults each of them is a fresh `mmap` and `munmap` and its pages are faulted in again,
    which shows up as system time. Here blocks up to 32 MiB (glibc's largest threshold) come
    from the heap and up to 1 GiB of free heap is kept.
    """
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(libc.mallopt(m_mmap_threshold, 32 << 20)) and bool(
        libc.mallopt(m_trim_threshold, 1 << 30))


def format_duration(seconds: float) -> str:
    """`"1 h 02 min"`, `"3 min 05 s"` or `"12.3 s"`.

    Example:
        >>> format_duration(185), format_duration(3720), format_duration(4.25)
        ('3 min 05 s', '1 h 02 min', '4.2 s')
    """
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    return f"{minutes // 60} h {minutes % 60:02d} min"


def evaluate_whole_images(
    trainer: Trainer, test_set: Sequence[Mapping[str, Any]], constant: float | None = None,
    depth_cap: float | None = None, crop: str | Sequence[float] | None = None,
    max_pixels: int = TILE_PIXELS,
) -> tuple[dict[str, float], dict[str, float] | None]:
    """Mean metrics of the network and of a constant depth over whole test images, one pass
    of `models.evaluate` (`"eigen"`).

    Each sample is read once (its focal stack synthesised or loaded once, or rendered through
    the camera the trainer learned, `learned_camera.rendered_samples`) and predicted whole,
    tiled above `max_pixels` (`models.evaluation.network_method`). The network's metrics
    include `depth_order` (`models.metrics.depth_order`: whether it orders each scene's depths,
    which abs rel alone does not show).

    Returns:
        (the network's metrics, the constant's metrics or None without `constant`).
    """
    def also(depth: Tensor, sample: Mapping[str, Any]) -> dict[str, float]:
        kwargs = {"target": sample["depth"], "mask": sample.get("mask"), "max_depth": depth_cap,
                  "crop": crop}
        values = {"depth_order": depth_order(pred=depth, **kwargs)}
        if constant is not None:
            values.update({f"constant {key}": value for key, value in depth_metrics(
                pred=torch.full_like(sample["depth"], constant), **kwargs).items()})
        return values

    method = network_method(trainer.model, trainer.device, max_pixels=max_pixels,
                            aperture=trainer.learned_aperture)
    test_set = rendered_samples(trainer.camera, test_set, trainer.config)  # a learned camera's
    metrics = evaluate(method, test_set, "eigen", also=also, max_depth=depth_cap, crop=crop)
    del metrics["images"], metrics["skipped"]
    ours = {key: value for key, value in metrics.items() if not key.startswith("constant ")}
    const = {key[len("constant "):]: value for key, value in metrics.items()
             if key.startswith("constant ")}
    return ours, const if constant is not None else None


def evenly_spaced(samples: Sequence[Mapping[str, Any]], count: int) -> Sequence[Mapping[str, Any]]:
    """`count` samples spread evenly over `samples` (all of them when there are no more).

    Example:
        >>> list(evenly_spaced(list(range(10)), 3))
        [0, 3, 6]
    """
    n = len(samples)
    if count >= n:
        return samples
    return Subset(samples, [i * n // count for i in range(count)])  # type: ignore[arg-type]


def constant_from_training(samples: Sequence[Mapping[str, Any]],
                           max_samples: int = 64) -> float | None:
    """`best_constant_depth` (abs-rel-optimal) of the valid depths of `samples` (at most
    `max_samples` of them, evenly spaced, so a large training set is not read whole), or None."""
    if hasattr(samples, "__len__"):
        samples = evenly_spaced(samples, max_samples)
    depths = [s["depth"][s["mask"].bool()] for s in samples if bool(s["mask"].any())]
    return None if not depths else best_constant_depth(target=torch.cat(depths))


def _silent(message: str) -> None:
    """A `report` that drops the message."""


def _progress_reporter(total: int, every: int, report: Callable[[str], None],
                       ) -> Callable[[Trainer, int, dict[str, float]], None]:
    """A `step_callback` that reports step, loss, s/step and ETA every `every` steps (and at
    the last); set `.start[0]` to the step training starts from."""
    started = time.perf_counter()

    def progress(trainer: Trainer, step: int, losses: dict[str, float]) -> None:
        if step % every and step != total:
            return
        elapsed = time.perf_counter() - started
        done = max(step - trainer_start[0], 1)
        rate = elapsed / done
        report(f"  step {step}/{total}  loss {losses['loss']:.4f}  {rate:.2f} s/step  "
               f"ETA {format_duration(rate * (total - step))}")

    trainer_start = [0]
    progress.start = trainer_start  # type: ignore[attr-defined]
    return progress


def reconstruction_metrics(trainer: Trainer, test_set: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Mean self-supervised loss terms on `test_set` (for data without ground-truth depth):
    `models.evaluate` with the trainer's loss as the score."""
    def losses(depth: Tensor, sample: Mapping[str, Any]) -> dict[str, float]:
        depth = depth[None].to(trainer.device)
        with torch.no_grad():
            terms = trainer.loss_fn(depth, sample["image"][None].to(depth),
                                    sample["focused"][None].to(depth),
                                    sample["camera"].batched(1).to(trainer.device))
        return {key: float(value) for key, value in terms.items()}

    method = network_method(trainer.model, trainer.device, max_pixels=None,
                            aperture=trainer.learned_aperture)
    metrics = evaluate(method, test_set, losses)
    del metrics["images"], metrics["skipped"]
    return metrics


def _result_rows(trainer: Trainer, train_set: Sequence[Mapping[str, Any]],
                 test_set: Sequence[Mapping[str, Any]], crop: str | Sequence[float] | None,
                 has_depth: bool, constant_set: Sequence[Mapping[str, Any]] | None,
                 ) -> dict[str, dict[str, float]]:
    """The table rows of a trained network: its metrics (or reconstruction losses without
    depth) and the best constant depth's."""
    config = trainer.config
    method = f"ours ({config.network}, {config.input_mode}, {trainer.step} steps)"
    if not has_depth:
        return {method: reconstruction_metrics(trainer, test_set)}
    constant = constant_from_training(train_set if constant_set is None else constant_set)
    ours, baseline = evaluate_whole_images(trainer, test_set, constant,
                                           depth_cap=config.depth_max, crop=crop)
    rows = {method: ours}
    if baseline is not None:
        rows[f"best constant depth ({constant:.2f} m, from training depths)"] = baseline
    return rows


def train_and_evaluate(
    config: TrainConfig,
    train_set: Sequence[Mapping[str, Any]],
    test_set: Sequence[Mapping[str, Any]],
    crop: str | Sequence[float] | None = None,
    has_depth: bool = True,
    constant_set: Sequence[Mapping[str, Any]] | None = None,
    report_every: int | None = None,
    report: Callable[[str], None] | None = None,
) -> dict[str, dict[str, float]]:
    """Train a network with `config` on `train_set`, then evaluate it on whole `test_set` images.

    Training runs `config.steps` steps or stops when its time budget `config.minutes` is spent
    (`Trainer.fit`, no probe run); the table names the steps actually run.

    Args:
        config: the training run (its `depth_max` is also the evaluation cap).
        train_set: training samples in the sample format (e.g. random crops).
        test_set: test samples in the sample format, evaluated whole (tiled above
            `TILE_PIXELS`).
        crop: evaluation crop (`"eigen"`, `"garg"` or fractions), see `Trainer.evaluate`.
        has_depth: False for data without ground truth: the rows then hold the self-supervised
            reconstruction losses instead of depth metrics.
        constant_set: samples whose depths choose the best constant depth (default
            `train_set`; pass the training samples without random crops).
        report_every: report a progress line every this many steps (default: about 10 lines;
            0: never).
        report: called with each message line (the plan, progress, the budget), e.g. `print`;
            None: silent.

    Returns:
        table rows: the trained network's, and (with depth) the best constant depth's.

    Example:
        >>> rows = train_and_evaluate(config, train, test, report=print)  # doctest: +SKIP
    """
    say = report if report is not None else _silent
    budget = f", ETA at most {format_duration(config.minutes * 60)} (budget " \
        f"{config.minutes:g} min)" if config.minutes else ""
    say(f"plan: {config.steps} steps at most, batch {config.batch_size}, device "
        f"{config.device}{budget}; then {len(test_set)} whole test images")
    every = report_every if report_every is not None else max(1, math.ceil(config.steps / 10))
    progress = _progress_reporter(config.steps, every, say) if every else None
    trainer = Trainer(config, train_set, step_callback=progress)
    if progress is not None:
        progress.start[0] = trainer.step  # type: ignore[attr-defined]
    started, first = time.perf_counter(), trainer.step
    trainer.fit()
    seconds = time.perf_counter() - started
    cut = f"; the time budget of {config.minutes:g} min was spent" if trainer.out_of_time else ""
    say(f"trained {trainer.step - first} steps in {format_duration(seconds)} "
        f"({seconds / max(trainer.step - first, 1):.3f} s/step){cut}; evaluating")
    if trainer.step_timer.split():
        say(f"a training step's time: {trainer.step_timer.summary()}")
    return _result_rows(trainer, train_set, test_set, crop, has_depth, constant_set)


def compare_on_scene(
    config: TrainConfig,
    train_set: Sequence[Mapping[str, Any]],
    val_set: Sequence[Mapping[str, Any]] | None,
    sample: Mapping[str, Any],
    direct_steps: int = 150,
    report: Callable[[str], None] | None = None,
) -> tuple[dict[str, dict[str, float]], dict[str, torch.Tensor]]:
    """Five ways to get one scene's depth, with their metrics on its ground truth.

    `self_supervised` and `supervised`: the network of `config` trained without and with depth
    labels (same budget); `direct_optimisation`: `fit_depth_direct` through the renderer, no
    network; `sweep`: `estimate_depth(method="sweep")` (no network, no training, any camera; the
    default of `defocus predict`); `constant`: the best constant depth of the scene's own ground truth (an
    oracle).

    Args:
        config: the training run; `out_dir` gets one subfolder per trained method.
        train_set: training samples.
        val_set: validation samples (or None).
        sample: the test scene (unbatched sample with `depth` and `mask`).
        direct_steps: Adam steps of the direct fit.
        report: called with a heading line before each method runs, e.g. `print`; None:
            silent.

    Returns:
        (metrics per method, depth `(1,H,W)` per method).

    Example:
        >>> results, depths = compare_on_scene(config, train, None, scene, report=print)  # doctest: +SKIP
    """
    say = report if report is not None else _silent
    batch = collate([sample])
    target, mask = batch["depth"], batch["mask"]
    results: dict[str, dict[str, float]] = {}
    predictions: dict[str, torch.Tensor] = {}
    for method, supervision in (("self_supervised", "self"), ("supervised", "depth")):
        run = replace(config, supervision=supervision, out_dir=config.out_dir / method)
        labels = "no depth labels" if supervision == "self" else "depth labels"
        say(f"\n[{method}] training {run.steps} steps ({labels})")
        trainer = Trainer(run, train_set, val_set)
        trainer.fit()
        results[method] = trainer.evaluate([sample])
        predictions[method] = trainer.predict(batch["image"], batch["focused"], batch["camera"])[0]
    say(f"\n[direct_optimisation] fitting the scene's depth, {direct_steps} steps")
    direct = fit_depth_direct(batch["image"], batch["focused"], batch["camera"], config.depth_min,
                              config.depth_max, steps=direct_steps, progress=config.progress)
    results["direct_optimisation"] = depth_metrics(pred=direct, target=target, mask=mask)
    predictions["direct_optimisation"] = direct[0]
    say("\n[sweep] sweeping over depth (no network)")
    swept = estimate_depth(sample["focused"], sample["camera"],
                           (config.depth_min, config.depth_max), image=sample["image"],
                           method="sweep", progress=config.progress)["depth"]
    results["sweep"] = depth_metrics(pred=swept[None], target=target, mask=mask)
    predictions["sweep"] = swept
    constant = best_constant_depth(target=target, mask=mask)
    predictions["constant"] = torch.full_like(target[0], constant)
    results["constant"] = depth_metrics(pred=predictions["constant"][None], target=target,
                                        mask=mask)
    return results, predictions
