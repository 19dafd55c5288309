"""Score depth (`defocus evaluate`): a trained checkpoint on a dataset, or a method on a
focal-stack benchmark with the benchmark's own protocol."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any


def evaluate_checkpoint(checkpoint: Path, test_set: Sequence[Any], depth_cap: float | None = None,
                        crop: str | None = None, median_scaling: bool = False,
                        min_depth: float = 1e-3) -> tuple[dict[str, float], str | None]:
    """The depth metrics of a `defocus train` checkpoint on `test_set`, and a warning when the
    network collapsed to its depth limits, or when much of the ground truth lies outside the
    depth range the network can output (the metrics then mean little; both joined by "; ").

    Raises:
        ValueError: a sample the network cannot read: a key it needs is missing, or it holds
            another number of focused photos than the network was trained on.

    Example:
        >>> metrics, warning = evaluate_checkpoint(Path("run/checkpoints/last.pt"),
        ...                                        samples)  # doctest: +SKIP
    """
    from models.training import COLLAPSE_FRACTION, Trainer
    from models.training.sample_checks import TestSampleChecker

    trainer = Trainer.from_checkpoint(checkpoint)
    checker = TestSampleChecker(trainer.config, f"checkpoint {checkpoint}")
    metrics = trainer.evaluate(test_set, depth_cap=depth_cap, crop=crop,
                               median_scaling=median_scaling, min_depth=min_depth, checker=checker)
    warnings: list[str | None] = []
    if metrics["at_depth_limits"] >= COLLAPSE_FRACTION:
        config = trainer.config
        warnings.append(f"{metrics['at_depth_limits']:.0%} of the predicted pixels sit at "
                        f"depth_min ({config.depth_min} m) or depth_max ({config.depth_max} m): "
                        "the network collapsed to its depth limits; these metrics mean little")
    warnings.append(checker.range_message())  # None where the ground truth fits the range
    return metrics, "; ".join(w for w in warnings if w) or None


def evaluate_on_benchmark(dataset: Sequence[Any], protocol: str, method: str = "auto",
                          checkpoint: Path | None = None, max_samples: int | None = None,
                          max_pixels: int = 1_500_000,
                          report: Callable[[str], None] = lambda text: None
                          ) -> tuple[str, dict[str, float]]:
    """Score a label-free `method` (or the network of `checkpoint`) on `dataset` with
    `protocol` (`models.protocols.PROTOCOLS`); returns the method's name and the metrics.

    Example:
        >>> name, metrics = evaluate_on_benchmark(dataset, "ddff12")  # doctest: +SKIP
    """
    from defocus.app.experiment import score_benchmark
    from models.evaluation import label_free_method

    model = None
    if checkpoint is not None:
        from models import load_depth_model

        model = load_depth_model(checkpoint, "cpu")
    scorer = label_free_method(dataset.depth_range, method, model=model, max_pixels=max_pixels)
    count = len(dataset) if max_samples is None else min(max_samples, len(dataset))
    samples = (dataset[i] for i in range(count))
    metrics = score_benchmark(samples, scorer, protocol, count, report)
    return (checkpoint.name if checkpoint is not None else scorer.name), metrics
