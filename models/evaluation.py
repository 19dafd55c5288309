"""Scoring a depth method: one evaluation loop, the protocol's metrics averaged over images.

A *method* is any callable `predict(sample) -> depth` that takes a sample of `datasets.base`
(`image`, `focused`, `camera`, and `has_all_in_focus` for the focal-stack benchmarks) and
returns depth `(1,H,W)` in metres; `label_free_method` makes one of the methods of
`models.depth_from_photos.estimate_depth` (the sweep where the sample has a real all-in-focus
image, the relative blur between the shots where it has not), a trained model of
`models.loading.load_depth_model` runs through it too, and any other callable can be swapped
in. `evaluate` runs a method over samples and averages `models.protocols.protocol_metrics` over
the images with ground truth, as the benchmarks' own code does. `MeanMetrics` is the running
mean every evaluation loop of the package shares (`Trainer.evaluate`,
`models.experiment.evaluate_whole_images`).

Example:
    >>> import torch
    >>> from optics import CameraSettings
    >>> sample = {"image": torch.rand(3, 8, 8), "focused": torch.rand(2, 3, 8, 8),
    ...           "camera": CameraSettings(0.05, 2.0, [1.0, 3.0], 1e-5),
    ...           "depth": torch.full((1, 8, 8), 2.0), "mask": torch.ones(1, 8, 8, dtype=torch.bool)}
    >>> result = evaluate(lambda s: torch.full((1, 8, 8), 2.5), [sample], "zedd")
    >>> result["images"], round(result["abs_rel"], 3), result["delta1"]
    (1, 0.25, 0.0)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import torch
from torch import Tensor, nn

from .protocols import PROTOCOLS, Protocol, protocol_metrics

#: A depth method: a sample in, depth `(1,H,W)` metres out.
Method = Callable[[Mapping[str, Any]], Tensor]


class MeanMetrics:
    """The running mean of per-image metrics: each name's values summed in the order they come,
    divided by the number of images at the end.

    Example:
        >>> means = MeanMetrics()
        >>> means.add({"abs_rel": 0.5, "rmse": 1.0})
        >>> means.add({"abs_rel": 0.25, "rmse": 3.0})
        >>> means.count, means.mean()
        (2, {'abs_rel': 0.375, 'rmse': 2.0})
    """

    def __init__(self) -> None:
        self.totals: dict[str, float] = {}
        self.count = 0

    def add(self, values: Mapping[str, float]) -> None:
        """Count one image's metrics."""
        for key, value in values.items():
            self.totals[key] = self.totals.get(key, 0.0) + value
        self.count += 1

    def mean(self) -> dict[str, float]:
        """The mean of each metric over the images counted (at least one)."""
        return {key: value / self.count for key, value in self.totals.items()}


def label_free_method(depth_range: tuple[float, float], method: str = "auto",
                      model: nn.Module | None = None, device: str | torch.device = "cpu",
                      **options: Any) -> Method:
    """A method that runs `models.depth_from_photos.estimate_depth` on a sample's photos.

    The sample's `image` is given as the all-in-focus photo only where `has_all_in_focus` is
    true (or absent): a focal stack's fused stand-in is no measurement. With `method="auto"`
    that runs the sweep with an all-in-focus photo and the relative blur without one.

    Args:
        depth_range: `(near, far)` metres the scenes lie within.
        method: `"auto"` or a name of `models.depth_from_photos.METHODS`.
        model: a method object instead (e.g. `models.loading.load_depth_model`'s).
        device: where the method runs (the depth comes back on the CPU).
        **options: keyword arguments of `estimate_depth` (e.g. `max_pixels`, `progress`).

    Example:
        >>> label_free_method((0.5, 7.0), "focus").name
        'focus'
    """
    from .depth_from_photos import estimate_depth

    def run(sample: Mapping[str, Any]) -> Tensor:
        image = sample["image"].to(device) if sample.get("has_all_in_focus", True) else None
        kwargs = dict(options)
        if model is not None:
            kwargs["model"] = model.to(device)
        else:
            kwargs["method"] = method
        with torch.no_grad():
            out = estimate_depth(sample["focused"].to(device), sample["camera"].to(device),
                                 depth_range, image=image, all_in_focus=False, **kwargs)
        return out["depth"].cpu()

    run.name = type(model).__name__ if model is not None else method  # type: ignore[attr-defined]
    return run


def evaluate(predict: Method, samples: Iterable[Mapping[str, Any]], protocol: str | Protocol, *,
             report: Callable[[int, str, dict[str, float]], None] | None = None,
             ) -> dict[str, float]:
    """The protocol's metrics of `predict` averaged over the samples that have ground truth.

    Args:
        predict: `(sample) -> depth (1,H,W)` metres (e.g. `label_free_method`).
        samples: samples of `datasets.base` (a dataset, a list, ...), each with `depth`
            `(1,H,W)` metres and `mask`.
        protocol: a name of `models.protocols.PROTOCOLS` or a `Protocol`.
        report: called after each image as `report(index, sample id, its metrics)`.

    Returns:
        the averaged metrics (`models.protocols.PROTOCOL_METRIC_NAMES`), `images` (how many
        were scored) and `skipped` (samples without ground truth).

    Raises:
        ValueError: an unknown protocol, no sample with ground truth (e.g. ZEDD's test split,
            Mobile Depth), or depth of another shape from `predict`.

    Example:
        >>> import torch
        >>> sample = {"depth": torch.full((1, 4, 4), 2.0), "mask": torch.ones(1, 4, 4).bool()}
        >>> evaluate(lambda s: torch.full((1, 4, 4), 2.0), [sample], "zedd")["rmse"]
        0.0
    """
    if isinstance(protocol, str) and protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {sorted(PROTOCOLS)}, got {protocol!r}")
    means = MeanMetrics()
    skipped = 0
    for index, sample in enumerate(samples):
        if not bool(sample["mask"].any()):
            skipped += 1
            continue
        depth = predict(sample)
        if tuple(depth.shape) != tuple(sample["depth"].shape):
            raise ValueError(f"the method returned depth of shape {tuple(depth.shape)} for sample "
                             f"{sample.get('id', index)!r}, expected {tuple(sample['depth'].shape)}")
        values = protocol_metrics(pred=depth, target=sample["depth"], mask=sample["mask"],
                                  protocol=protocol)
        means.add(values)
        if report is not None:
            report(index, str(sample.get("id", index)), values)
    if means.count == 0:
        raise ValueError(f"no sample has ground-truth depth ({skipped} without): this split is "
                         "scored elsewhere (a benchmark server) or judged by eye")
    result = means.mean()
    result.update(images=means.count, skipped=skipped)
    return result


__all__ = ["MeanMetrics", "Method", "evaluate", "label_free_method"]
