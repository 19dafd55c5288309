"""Scoring a depth method: the one evaluation loop of the library (`evaluate`).

A *method* is any callable `predict(sample) -> depth` that takes a sample of `datasets.base`
(`image`, `focused`, `camera`, and `has_all_in_focus` for the focal-stack benchmarks) and
returns depth `(1,H,W)` in metres. Two adapters make one: `label_free_method` runs a method of
`models.depth_from_photos.estimate_depth` (the sweep where the sample has a real all-in-focus
image, the relative blur between the shots where it has not; a model of
`models.loading.load_depth_model` runs through it too), and `network_method` runs a trained
depth network (a `Trainer`'s `model`, `models.loading.load_model`'s network) whole or in
tiles; any other callable can be swapped in.

`evaluate(method, samples, protocol, **keywords)` runs a method over samples and averages each
image's metrics: a benchmark's protocol (`models.protocols.PROTOCOLS`, as the benchmarks' own
code scores), `"eigen"` (`models.metrics.depth_metrics`) or any `score(depth, sample)`.
`Trainer.evaluate`, `models.experiment`, `defocus evaluate`, the examples and the benchmarks
all score through it.

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

from optics import Aperture

from .depth_from_photos.tiling import check_tiling, run_network
from .metrics import depth_metrics
from .protocols import Protocol, as_protocol, protocol_metrics

#: A depth method: a sample in, depth `(1,H,W)` metres out.
Method = Callable[[Mapping[str, Any]], Tensor]
#: A scoring rule: one image's metrics from its depth `(1,H,W)` and its sample.
Score = Callable[[Tensor, Mapping[str, Any]], Mapping[str, float]]
#: Whole images above this many pixels are predicted tile by tile (`network_method`).
TILE_PIXELS = 4_000_000


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


def network_method(network: nn.Module, device: str | torch.device | None = None,
                   max_pixels: int | None = TILE_PIXELS, tile: int = 1024,
                   overlap: int = 64, aperture: Aperture | None = None) -> Method:
    """A method that runs a trained depth network on a sample: its all-in-focus `image` and, in
    `"aif+focused"` mode, its `focused` photos and `camera` settings, whole up to `max_pixels`
    pixels and in tiles above (`models.depth_from_photos.tiling.run_network`, which also
    handles the input mode).

    Args:
        network: a network of `models.networks.build_network` (`Trainer.model`,
            `models.loading.load_model`'s), in any mode: it is run in eval mode.
        device: where it runs (default: where its weights are); the depth comes back on the
            CPU.
        max_pixels: whole images up to this many pixels go through in one piece (None: all).
        tile: side of a tile's kept centre, pixels (> 0).
        overlap: context around each tile, pixels (>= 0).
        aperture: the photos' PSF where their settings cannot name it (a learned mask), for a
            network that sweeps (`TrainConfig.sweep_inputs`).

    Raises:
        ValueError: `tile <= 0` or `overlap < 0`.

    Example:
        >>> from models.networks import build_network
        >>> method = network_method(build_network("small", "aif", 0, 1.0, 10.0, width=4))
        >>> method({"image": torch.rand(3, 8, 8)}).shape
        torch.Size([1, 8, 8])
    """
    check_tiling(tile, overlap)
    if device is None:
        device = next(network.parameters()).device

    def run(sample: Mapping[str, Any]) -> Tensor:
        focused, camera = sample.get("focused"), sample.get("camera")
        depth = run_network(network, sample["image"][None].to(device),
                            None if focused is None else focused[None].to(device),
                            None if camera is None else camera.to(device), max_pixels, tile,
                            overlap, aperture)
        return depth[0].cpu()

    return run


def evaluate_network(network: nn.Module, config: Any, samples: Iterable[Mapping[str, Any]],
                     checker: Any = None, device: str | torch.device | None = None,
                     aperture: Aperture | None = None, **options: Any) -> dict[str, float]:
    """`evaluate` of a network trained with `config` (a `TrainConfig`) on whole `samples`
    (`"eigen"`), each checked against the config first (`checker`, by default a new
    `models.training.sample_checks.TestSampleChecker`): `Trainer.evaluate` and
    `defocus evaluate`.

    Args:
        network: the network (`Trainer.model`, `models.loading.load_model`'s).
        config: its `TrainConfig` (input mode, focused photos, depth range).
        samples: unbatched samples with `image`, `depth` (and `mask`; `focused` and `camera`
            in `"aif+focused"` mode).
        checker: checks each sample and counts its ground truth outside the depth range.
        device: where the network runs (default: where its weights are).
        aperture: the samples' PSF where their settings cannot name it (see `network_method`).
        **options: `min_depth`, `max_depth`, `crop`, `median_scaling` of `depth_metrics`.

    Returns:
        the mean metrics (`models.metrics.METRIC_NAMES`) and `at_depth_limits`: the share of
        predicted pixels at `depth_min` or `depth_max` (near 1: the network collapsed).
    """
    from .metrics import at_depth_limits
    from .training.sample_checks import TestSampleChecker

    checker = checker if checker is not None else TestSampleChecker(config, "the network")
    checked = (checker.check(sample, index) for index, sample in enumerate(samples))
    metrics = evaluate(network_method(network, device, max_pixels=None, aperture=aperture),
                       checked, "eigen",
                       also=lambda depth, _: {"at_depth_limits": float(at_depth_limits(
                           depth, config.depth_min, config.depth_max))}, **options)
    del metrics["images"], metrics["skipped"]
    return metrics


def _scorer(protocol: str | Protocol | Score, options: Mapping[str, Any]) -> Score | None:
    """The score of each image under `protocol`; None for a callable (it scores itself)."""
    if callable(protocol):
        return None
    if protocol == "eigen":
        return lambda depth, s: depth_metrics(pred=depth, target=s["depth"], mask=s.get("mask"),
                                              **options)
    protocol = as_protocol(protocol)
    return lambda depth, s: protocol_metrics(pred=depth, target=s["depth"], mask=s.get("mask"),
                                             protocol=protocol, **options)


def _has_truth(sample: Mapping[str, Any]) -> bool:
    """Whether `sample` holds ground-truth depth with at least one valid pixel."""
    mask = sample.get("mask")
    return sample.get("depth") is not None and (mask is None or bool(mask.any()))


def evaluate(predict: Method, samples: Iterable[Mapping[str, Any]],
             protocol: str | Protocol | Score, *,
             report: Callable[[int, str, dict[str, float]], None] | None = None,
             also: Score | None = None, **options: Any) -> dict[str, float]:
    """The metrics of `predict` averaged over `samples`: the only evaluation loop of the library.

    Each image's metrics come first (in the order the samples come), then their mean: the
    protocol's metrics of a sample are those of its one image, as the benchmarks' code does.

    Args:
        predict: `(sample) -> depth (1,H,W)` metres (e.g. `label_free_method`,
            `network_method`).
        samples: samples of `datasets.base` (a dataset, a list, a generator, ...).
        protocol: how an image is scored: a name of `models.protocols.PROTOCOLS` or a
            `Protocol` (`protocol_metrics`), or `"eigen"` (`models.metrics.depth_metrics`),
            each against the sample's `depth` `(1,H,W)` metres and `mask`, samples without
            ground truth skipped; or a callable `score(depth, sample) -> metrics`, which scores
            every sample (e.g. the self-supervised losses of data without depth).
        report: called after each image as `report(index, sample id, its metrics)`.
        also: more metrics of each image, `also(depth, sample) -> metrics` (e.g.
            `models.metrics.depth_order`), averaged with the protocol's.
        **options: keywords of the protocol's metric function, e.g. `min_depth`,
            `max_depth`, `crop` and `median_scaling` of `depth_metrics` for `"eigen"`.

    Returns:
        the averaged metrics, `images` (how many were scored) and `skipped` (samples without
        ground truth).

    Raises:
        ValueError: an unknown protocol, no sample to score (for a protocol with ground truth:
            none has it, e.g. ZEDD's test split, Mobile Depth), or depth of another shape than
            the sample's ground truth from `predict`; and the metric functions' refusals.

    Example:
        >>> sample = {"depth": torch.full((1, 4, 4), 2.0), "mask": torch.ones(1, 4, 4).bool()}
        >>> evaluate(lambda s: torch.full((1, 4, 4), 2.0), [sample], "zedd")["rmse"]
        0.0
        >>> evaluate(lambda s: torch.full((1, 4, 4), 2.5), [sample], "eigen", max_depth=10.0)["abs_rel"]
        0.25
    """
    score = _scorer(protocol, options) or protocol
    needs_truth = score is not protocol
    means, skipped = MeanMetrics(), 0
    for index, sample in enumerate(samples):
        if needs_truth and not _has_truth(sample):
            skipped += 1
            continue
        depth = predict(sample)
        truth = sample.get("depth")
        if truth is not None and tuple(depth.shape) != tuple(truth.shape):
            raise ValueError(f"the method returned depth of shape {tuple(depth.shape)} for sample "
                             f"{sample.get('id', index)!r}, expected {tuple(truth.shape)}")
        values = {**score(depth, sample), **(also(depth, sample) if also is not None else {})}
        means.add(values)
        if report is not None:
            report(index, str(sample.get("id", index)), values)
    if means.count == 0:
        raise ValueError(f"no sample has ground-truth depth ({skipped} without): this split is "
                         "scored elsewhere (a benchmark server) or judged by eye" if needs_truth
                         else "samples holds no samples to score")
    result = means.mean()
    result.update(images=means.count, skipped=skipped)
    return result


__all__ = ["TILE_PIXELS", "MeanMetrics", "Method", "Score", "evaluate", "evaluate_network",
           "label_free_method", "network_method"]
