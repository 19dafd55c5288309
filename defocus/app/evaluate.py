"""Score depth (`defocus evaluate`): a trained checkpoint on a dataset, or a method on a
focal-stack benchmark with the benchmark's own protocol, through `models.evaluate`.

The command builds an `EvaluateRequest` from its options and prints the `EvaluateResult`;
the checkpoint is read by the one loader of model files (`models.loading`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from defocus.app import silent

Report = Callable[[str], None]


@dataclasses.dataclass
class EvaluateRequest:
    """What to score (the checked options of `defocus evaluate`, lengths in metres).

    With `protocol` (a name of `models.protocols.PROTOCOLS`) `samples` is a focal-stack
    benchmark scored with its paper's protocol: the label-free `method`, or the model of
    `checkpoint`, on at most `max_samples` samples. Without it the network of `checkpoint` is
    scored on `samples` with the depth metrics (`models.metrics.depth_metrics`).
    """

    samples: Sequence[Any]
    checkpoint: Path | None = None
    protocol: str | None = None
    method: str = "auto"
    max_samples: int | None = None
    #: most pixels of the label-free method's working resolution
    max_pixels: int = 1_500_000
    depth_cap: float | None = None
    min_depth: float = 1e-3
    crop: str | None = None
    median_scaling: bool = False
    #: the samples' focused images are synthesised from their image and depth: they are
    #: rendered anew with the camera the checkpoint was trained for (`checkpoint_focus`)
    synthesize: bool = False
    #: the camera as built (`optics.CameraTolerance`): its focus, f-number and mask off the
    #: checkpoint's design where the focused images are rendered (with `synthesize`)
    tolerance: Any = None
    #: called with each progress line
    report: Report = silent


@dataclasses.dataclass
class EvaluateResult:
    """The table row's name, its metrics, and a warning about them (or None)."""

    name: str
    metrics: dict[str, float]
    warning: str | None = None


def run_evaluation(request: EvaluateRequest) -> EvaluateResult:
    """Score what `request` asks (`evaluate_checkpoint` or `evaluate_on_benchmark`).

    Example:
        >>> result = run_evaluation(EvaluateRequest(samples, Path("run/checkpoints/last.pt")))  # doctest: +SKIP
    """
    if request.protocol is not None:
        return evaluate_on_benchmark(request)
    return evaluate_checkpoint(request)


def checkpoint_focus(samples: Sequence[Any], checkpoint: Path, aperture: str,
                     tolerance: Any = None, noise: tuple[float, float] = (0.0, 0.0),
                     ) -> tuple[Sequence[Any], str | None, str | None]:
    """`samples` with their focused images rendered anew from their image and depth with the
    camera `checkpoint` was trained for (`datasets.SynthesizedFocus`, PSF `aperture`): the blur
    a network learned is its camera's, so a network trained on one data set is scored on
    another with that blur; a camera learned with the network (`defocus train --learn-optics`)
    is the checkpoint's camera, its learned aperture mask included; with `tolerance` (an
    `optics.CameraTolerance`), that camera as built. A learned camera's images carry the
    sensor `noise` it was trained with (read, shot: `TrainConfig.read_noise`, `shot_noise`)
    at the light the camera gathers against the one it started from, seeded by sample, as in
    training: a camera built a third of a stop darker is noisier. Returns (the samples, a
    line saying which camera rendered them, a warning where the checkpoint records no camera:
    then the samples are left as they are).
    """
    from datasets import SynthesizedFocus
    from models.checkpoints import load_checkpoint
    from models.depth_from_photos.trained_network import describe_camera
    from models.training.learned_camera import checkpoint_aperture, starting_camera
    from optics import CameraSettings, relative_light
    from optics.camera import SETTING_FIELDS

    state = load_checkpoint(checkpoint, mmap=True)
    record = state.get("camera")
    if not isinstance(record, dict) or any(name not in record for name in SETTING_FIELDS):
        return samples, None, (f"checkpoint {checkpoint} records no camera (written before "
                                "checkpoints did): the focused images are rendered with the "
                                "data's own camera, which may not be the one it was trained for")
    settings = CameraSettings(*(record[name] for name in SETTING_FIELDS), aperture=aperture)
    mask = checkpoint_aperture(state)  # a learned aperture mask, or None
    through = "" if mask is None else \
        f", through its learned {'x'.join(map(str, mask.image.shape))} aperture mask"
    if tolerance is not None and not tolerance.exact:
        settings, mask = tolerance.settings(settings), tolerance.mask(mask)
        through += f"; as built: {tolerance.describe()}"
    start = starting_camera(state)  # None unless the camera was learned
    sensor = {} if start is None else {  # its training noise, at the light it gathers
        "read_noise": noise[0], "shot_noise": noise[1],
        "light": relative_light(settings.f_number, settings.f_number.new_tensor(start["f_number"]))}
    return (SynthesizedFocus(samples, settings, aperture=mask, **sensor),
            f"focused images rendered with the camera the checkpoint was trained for: "
            f"{describe_camera(record)}{through}", None)


def evaluate_checkpoint(request: EvaluateRequest) -> EvaluateResult:
    """The depth metrics of a `defocus train` checkpoint on `request.samples`, and a warning
    when the network collapsed to its depth limits, or when much of the ground truth lies
    outside the depth range the network can output (the metrics then mean little; both joined
    by "; "). With `request.synthesize` the samples' focused images are rendered with the
    checkpoint's camera first (`checkpoint_focus`; not for a network that reads the
    all-in-focus image alone).

    Raises:
        ValueError: a sample the network cannot read: a key it needs is missing, or it holds
            another number of focused photos than the network was trained on.
    """
    from models.checkpoints import load_checkpoint
    from models.devices import select_device
    from models.evaluation import evaluate_network
    from models.loading import load_model
    from models.training import COLLAPSE_FRACTION
    from models.training.learned_camera import checkpoint_aperture
    from models.training.sample_checks import TestSampleChecker

    checkpoint = request.checkpoint
    network, config = load_model(checkpoint, select_device("auto"))
    checker = TestSampleChecker(config, f"checkpoint {checkpoint}")
    samples, warnings = request.samples, []
    if request.tolerance is not None and not (request.synthesize
                                              and config.input_mode == "aif+focused"):
        raise ValueError(f"a camera tolerance ({request.tolerance.describe()}) changes only "
                         "focused images rendered with the checkpoint's camera: it needs "
                         "synthesised focus and a network that reads focused images "
                         f"(checkpoint {checkpoint} reads {config.input_mode!r})")
    if request.synthesize and config.input_mode == "aif+focused":
        samples, rendered, warning = checkpoint_focus(
            samples, checkpoint, config.aperture, request.tolerance,
            (config.read_noise, config.shot_noise))
        warnings.append(warning)
        if rendered is not None:
            request.report(rendered)
    # a network that sweeps reads the photos through the learned mask as designed
    designed = checkpoint_aperture(load_checkpoint(checkpoint, mmap=True)) \
        if config.sweep_inputs else None
    metrics = evaluate_network(network, config, samples, checker, aperture=designed,
                               min_depth=request.min_depth, max_depth=request.depth_cap,
                               crop=request.crop, median_scaling=request.median_scaling)
    if metrics["at_depth_limits"] >= COLLAPSE_FRACTION:
        warnings.append(f"{metrics['at_depth_limits']:.0%} of the predicted pixels sit at "
                        f"depth_min ({config.depth_min} m) or depth_max ({config.depth_max} m): "
                        "the network collapsed to its depth limits; these metrics mean little")
    warnings.append(checker.range_message())  # None where the ground truth fits the range
    return EvaluateResult(checkpoint.parent.parent.name or "model", metrics,
                          "; ".join(w for w in warnings if w) or None)


def robustness(request: EvaluateRequest) -> dict[str, EvaluateResult]:
    """The checkpoint of `request` scored with its camera as designed and as built with each
    tolerance of `optics.ROBUSTNESS` (the mask's only where it learned one), keyed by the
    tolerance in words: how much of a designed camera's gain survives a real lens.

    Example:
        >>> rows = robustness(EvaluateRequest(samples, Path("run/checkpoints/last.pt"),
        ...                                   synthesize=True))  # doctest: +SKIP
    """
    from models.checkpoints import load_checkpoint
    from models.training.learned_camera import checkpoint_aperture
    from optics import ROBUSTNESS

    learned_mask = checkpoint_aperture(load_checkpoint(request.checkpoint, mmap=True))
    return {tolerance.describe(): evaluate_checkpoint(
                dataclasses.replace(request, tolerance=tolerance))
            for tolerance in ROBUSTNESS if not tolerance.mask_noise or learned_mask is not None}


def evaluate_on_benchmark(request: EvaluateRequest) -> EvaluateResult:
    """Score a label-free method (or the model of `request.checkpoint`) on a focal-stack
    benchmark with its protocol (`models.protocols.PROTOCOLS`)."""
    from defocus.app.experiment import score_benchmark
    from models.evaluation import label_free_method
    from models.loading import load_depth_model

    dataset, checkpoint = request.samples, request.checkpoint
    model = None if checkpoint is None else load_depth_model(checkpoint, "cpu")
    scorer = label_free_method(dataset.depth_range, request.method, model=model,
                               max_pixels=request.max_pixels)
    count = len(dataset) if request.max_samples is None else min(request.max_samples,
                                                                 len(dataset))
    metrics = score_benchmark((dataset[i] for i in range(count)), scorer, request.protocol,
                              count, request.report)
    return EvaluateResult(checkpoint.name if checkpoint is not None else scorer.name, metrics)
