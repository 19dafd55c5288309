"""Calibrating the camera a dataset was shot with, from its own samples with depth.

A dataset of real aperture pairs (`datasets.DSLR`: an f/8 photo as `image`, the f/2.8 photo as
`focused`, a registered depth map) is a calibration target that covers every depth at once.
`depth_pairs` turns samples into aligned `optics.CalibrationPair`s (the two photos of a pair
can be several pixels apart, which would read as blur); `calibrate_dataset` fits the camera
(`optics.calibrate_from_depth`) and is what `defocus calibrate --data` runs. Its JSON is what
`defocus predict --camera` and the loaders' `camera=` read.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from optics import (
    DEFAULT_APERTURE,
    CalibrationPair,
    DepthCalibration,
    align_shots,
    calibrate_from_depth,
)
from optics.progress import progress_bar


def depth_pairs(dataset: Sequence[dict[str, Any]], indices: Sequence[int] | None = None,
                align: bool = True, progress: bool = False) -> list[CalibrationPair]:
    """The `(image, focused[0], depth)` of each sample as a `CalibrationPair`, float64, the
    focused photo moved onto the image (`optics.align_shots`) unless `align` is False.

    Raises:
        ValueError: a sample without an `image`, a focused photo or a depth map, or no sample.

    Example:
        >>> import torch
        >>> sample = {"image": torch.rand(3, 16, 16), "focused": torch.rand(1, 3, 16, 16),
        ...           "depth": torch.full((1, 16, 16), 2.0), "id": "a"}
        >>> pair = depth_pairs([sample], align=False)[0]
        >>> pair.depth.shape, pair.name
        (torch.Size([1, 1, 16, 16]), 'a')
    """
    indices = list(range(len(dataset))) if indices is None else list(indices)
    if not indices:
        raise ValueError("no samples to calibrate from: indices is empty")
    ids = getattr(dataset, "ids", None)
    pairs = []
    for index in progress_bar(indices, desc="aligning pairs", disable=not progress):
        sample = dataset[index]
        missing = [k for k in ("image", "focused", "depth") if sample.get(k) is None]
        if missing:
            raise ValueError(f"sample {index} has no {missing}: calibration needs a reference "
                             "photo, a defocused photo and a depth map")
        image = sample["image"].to(torch.float64)[None]
        focused = sample["focused"][:1].to(torch.float64)[None]
        if align:
            focused, _ = align_shots(image, focused)
        name = str(sample.get("id", ids[index] if ids else index))
        pairs.append(CalibrationPair(image, focused[:, 0], sample["depth"].to(torch.float64),
                                     name=name))
    return pairs


def calibrate_dataset(dataset: Sequence[dict[str, Any]], indices: Sequence[int] | None = None,
                      aperture: str = DEFAULT_APERTURE, reference_f_number: float | None = None,
                      focus_distance: float | None = None, align: bool = True,
                      progress: bool = False, pairs: Sequence[CalibrationPair] | None = None,
                      **measure: Any) -> DepthCalibration:
    """The camera of a dataset's focused photos, fitted from its samples with depth.

    The focal length and f-number come from the first sample's `camera` (the dataset's stated
    values); the focus distance (unless given), the effective pixel pitch and the floor are
    fitted. `reference_f_number` defaults to the dataset's own (`DSLR.reference_f_number`).

    Args:
        dataset: samples with `image`, `focused`, `depth` and `camera`.
        indices: the samples to use (e.g. the training scenes), default all.
        aperture: the PSF's spec.
        reference_f_number: the f-number of `image`, whose own blur is taken out.
        focus_distance: metres if known, else fitted.
        align: align each pair first.
        progress: show progress bars.
        pairs: the samples' pairs as `depth_pairs(dataset, indices, align)` gives them, made
            once to fit several apertures (aligning is the slow part); made here by default.
        **measure: keyword arguments of `optics.measure_blur_curve`.

    Raises:
        ValueError: `pairs` that are not one per sample of `indices`.
    """
    indices = list(range(len(dataset))) if indices is None else list(indices)
    if pairs is None:
        pairs = depth_pairs(dataset, indices, align, progress)
    elif len(pairs) != len(indices):
        raise ValueError(f"pairs must hold one pair per sample of indices ({len(indices)}), "
                         f"got {len(pairs)}")
    camera = dataset[indices[0]]["camera"]
    if reference_f_number is None:
        reference_f_number = getattr(dataset, "reference_f_number", None)
    return calibrate_from_depth(
        pairs, float(camera.focal_length.reshape(-1)[0]), float(camera.f_number.reshape(-1)[0]),
        aperture=aperture, reference_f_number=reference_f_number,
        focus_distance=focus_distance, progress=progress, **measure)
