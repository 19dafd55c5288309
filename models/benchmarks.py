"""Scoring a depth method on a focal-stack benchmark with the benchmark's own protocol.

A *method* is any callable `method(sample) -> depth` that takes a sample of
`datasets.base` (`image`, `focused`, `camera`, and `has_all_in_focus` for the focal-stack
benchmarks) and returns depth `(1,H,W)` in metres; `label_free_method` makes one of the
methods of `models.depth_from_photos.estimate_depth` (the sweep where the sample has a real
all-in-focus image, the relative blur between the shots where it has not), and any other
callable can be swapped in. `evaluate_benchmark` runs a method over samples and averages
`models.metrics.protocol_metrics` over the images with ground truth, as the benchmarks' own
code does.

Example:
    >>> import torch
    >>> from optics import CameraSettings
    >>> sample = {"image": torch.rand(3, 8, 8), "focused": torch.rand(2, 3, 8, 8),
    ...           "camera": CameraSettings(0.05, 2.0, [1.0, 3.0], 1e-5),
    ...           "depth": torch.full((1, 8, 8), 2.0), "mask": torch.ones(1, 8, 8, dtype=torch.bool)}
    >>> result = evaluate_benchmark([sample], lambda s: torch.full((1, 8, 8), 2.5), "zedd")
    >>> result["images"], round(result["abs_rel"], 3), result["delta1"]
    (1, 0.25, 0.0)
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import torch
from torch import Tensor, nn

from .metrics import PROTOCOLS, Protocol, protocol_metrics

#: A depth method: a sample in, depth `(1,H,W)` metres out.
Method = Callable[[Mapping[str, Any]], Tensor]


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
        model: a method object instead (e.g. a `TrainedNetwork`).
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


def evaluate_benchmark(samples: Iterable[Mapping[str, Any]], method: Method,
                       protocol: str | Protocol, *,
                       report: Callable[[int, str, dict[str, float]], None] | None = None,
                       ) -> dict[str, float]:
    """The protocol's metrics of `method` averaged over the samples that have ground truth.

    Args:
        samples: samples of `datasets.base` (a dataset, a list, ...), each with `depth`
            `(1,H,W)` metres and `mask`.
        method: `(sample) -> depth (1,H,W)` metres.
        protocol: a name of `models.metrics.PROTOCOLS` or a `Protocol`.
        report: called after each image as `report(index, sample id, its metrics)`.

    Returns:
        the averaged metrics (`models.metrics.PROTOCOL_METRIC_NAMES`), `images` (how many
        were scored) and `skipped` (samples without ground truth).

    Raises:
        ValueError: no sample has ground truth (e.g. ZEDD's test split, Mobile Depth), or
            the method returns depth of another shape.
    """
    if isinstance(protocol, str) and protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {sorted(PROTOCOLS)}, got {protocol!r}")
    totals: dict[str, float] = {}
    scored = skipped = 0
    for index, sample in enumerate(samples):
        if not bool(sample["mask"].any()):
            skipped += 1
            continue
        depth = method(sample)
        if tuple(depth.shape) != tuple(sample["depth"].shape):
            raise ValueError(f"the method returned depth of shape {tuple(depth.shape)} for sample "
                             f"{sample.get('id', index)!r}, expected {tuple(sample['depth'].shape)}")
        values = protocol_metrics(pred=depth, target=sample["depth"], mask=sample["mask"],
                                  protocol=protocol)
        for key, value in values.items():
            totals[key] = totals.get(key, 0.0) + value
        scored += 1
        if report is not None:
            report(index, str(sample.get("id", index)), values)
    if scored == 0:
        raise ValueError(f"no sample has ground-truth depth ({skipped} without): this split is "
                         "scored elsewhere (a benchmark server) or judged by eye")
    result = {key: value / scored for key, value in totals.items()}
    result.update(images=scored, skipped=skipped)
    return result
