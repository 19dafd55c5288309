"""Fit a camera (`defocus calibrate`): from raw photo pairs (a sharp reference and a defocused
shot of a planar target at a known distance), or from a dataset of real aperture pairs with
depth (`datasets.calibration.calibrate_dataset`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

from optics import DEFAULT_APERTURE, LENS_APERTURE

from .outputs import OutputPlan


def parse_distance(text: str) -> float:
    """A `--pair` distance in metres.

    Example:
        >>> parse_distance("2.5")
        2.5
    """
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0:
        raise ValueError(f"a --pair distance must be > 0 metres, got {text!r}"
                         if value <= 0 else
                         f"a --pair distance must be a number of metres, got {text!r}")
    return value


def parse_scenes(text: str | None, length: int) -> list[int]:
    """The sample indices a `--scenes START:STOP[:STEP]` slice selects (all for None).

    Example:
        >>> parse_scenes("1:5:2", 10)
        [1, 3]
    """
    if text is None:
        return list(range(length))
    try:
        parts = [int(p) if p else None for p in text.split(":")]
        indices = list(range(length))[slice(*parts)]
    except (ValueError, TypeError):
        indices = None
    if not indices:
        raise ValueError(f"--scenes must be a slice START:STOP[:STEP] of sample indices, got "
                         f"{text!r}" if indices is None else
                         f"--scenes {text!r} selects none of the {length} samples")
    return indices


def calibrate_from_dataset(name: str, root: Path | None, split: str = "train",
                           scenes: str | None = None, psf: str = "gaussian",
                           focus_distance: float | None = None, progress: bool = False):
    """The camera a dataset of real pairs with depth was shot with, fitted on the samples
    `scenes` selects; returns the fit (`datasets.calibration.calibrate_dataset`) and the
    number of samples used."""
    from datasets.calibration import calibrate_dataset
    from datasets.registry import STACK_DATASET_NAMES, dataset_classes

    classes = dataset_classes()
    allowed = sorted(set(classes) - {"synthetic", *STACK_DATASET_NAMES})
    if name not in allowed or root is None:
        stack = " (a focal-stack benchmark: shots focused at many distances, not aperture " \
            "pairs; score it with `defocus evaluate --data`)" if name in STACK_DATASET_NAMES else ""
        raise ValueError("--data needs --root, the dataset's folder" if name in allowed else
                         f"--data must be a dataset of real photos with depth, one of "
                         f"{allowed}, got {name!r}{stack}")
    dataset = classes[name](root, split=split)  # full resolution
    indices = parse_scenes(scenes, len(dataset))
    aperture = DEFAULT_APERTURE if psf == "gaussian" else psf
    fit = calibrate_dataset(dataset, indices, aperture=aperture, focus_distance=focus_distance,
                            progress=progress)
    return fit, len(indices)


def read_pairs(pairs: Sequence[Sequence[str]], binning: int = 1, white_balance: str = "camera"):
    """The `CalibrationPair`s of `(sharp file, defocused file, distance text)` triples and the
    metadata of the last defocused file."""
    from datasets.photos import read_raw
    from optics import CalibrationPair

    found, meta = [], None
    for sharp_path, blurred_path, distance_text in pairs:
        distance = parse_distance(distance_text)
        options = {"binning": binning, "white_balance": white_balance}
        sharp, _ = read_raw(sharp_path, **options)
        blurred, meta = read_raw(blurred_path, **options)
        if sharp.shape != blurred.shape:
            raise ValueError(
                f"{sharp_path} is {tuple(sharp.shape[-2:])} pixels but {blurred_path} is "
                f"{tuple(blurred.shape[-2:])}; a pair must have one size"
            )
        found.append(CalibrationPair(sharp, blurred, distance, name=Path(blurred_path).stem))
    return found, meta


def calibrate_from_pairs(pairs: Sequence[Sequence[str]], known: Mapping[str, Any],
                         fit: Collection[str] = (), aperture: str = LENS_APERTURE, binning: int = 1,
                         white_balance: str = "camera", **options: Any):
    """Fit a camera to raw pairs: `known` values (`focal_length`, `f_number`, `pixel_pitch`,
    `focus_distance`, `psf_scale`; None where unknown) come first, then the defocused file's
    metadata (`optics.resolve_known`, except for the names in `fit`); the rest is fitted.
    Returns the `CalibrationResult` and where each known value came from ("option" or
    "metadata"). `options` go to `optics.calibrate` (margin_px, adam_steps, ...)."""
    from datasets.photos import resolve_known
    from optics import calibrate

    found, meta = read_pairs(pairs, binning, white_balance)
    # known values: the options', else the last defocused file's metadata (pitch x binning)
    values, origin = resolve_known(
        [meta], {name: known.get(name) for name in ("focal_length", "f_number", "pixel_pitch")},
        ignore=fit)
    given = {"focal_length": None, "f_number": None, "pixel_pitch": None, **values,
             "focus_distance": known.get("focus_distance"), "psf_scale": known.get("psf_scale")}
    sources = {name: "option" if source == "given" else "metadata"
               for name, source in origin.items()}
    if given["focal_length"] is None:
        raise ValueError("the focal length is unknown: the files do not state it; pass "
                         "--focal-length in metres")
    return calibrate(found, aperture=aperture, **options, **given), sources


def plan_fit_outputs(out: Path, figure: Path | None, overwrite: bool = False,
                     pairs: Sequence[Sequence[str]] = (), root: Path | None = None
                     ) -> tuple[OutputPlan, Path]:
    """The checked plan of a fit's JSON `out` and its figure (`figure`, by default `out` with
    `.png`), before any work: neither is a `--pair` file or an existing file of the dataset's
    `--root`, they differ from each other, and neither replaces an earlier result without
    `overwrite` (`defocus.app.outputs`); returns the plan and the figure's path.

    Example:
        >>> plan_fit_outputs(Path("fit.png"), None)
        Traceback (most recent call last):
        ...
        ValueError: the calibration figure and the calibration JSON would both be written to fit.png; give them different paths
    """
    inputs = [("--pair", Path(name)) for pair in pairs for name in pair[:2]]
    plan = OutputPlan(inputs, {"--root": root}, overwrite, how="or choose another --out")
    plan.add(out, "calibration JSON")
    figure = figure or out.with_suffix(".png")
    plan.add(figure, "calibration figure")
    return plan, figure


def write_fit(out: Path, figure: Path | None, save: Callable[[Path], Any],
              plot: Callable[[Path], Any], plan: OutputPlan | None = None) -> Path:
    """Save a fit's JSON at `out` and its figure beside it (or at `figure`), both whole or
    neither, through `plan` (by default `plan_fit_outputs(out, figure)`); returns the
    figure's path."""
    if plan is None:
        plan, figure = plan_fit_outputs(out, figure)
    figure = figure or out.with_suffix(".png")
    with plan.writing() as write:
        write(out, save)
        write(figure, plot)
    return figure
