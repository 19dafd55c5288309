"""Batches of samples that hold `CameraSettings`: the collate function of data loaders.

`collate` stacks the settings of `B` samples into `(B, F)` settings and leaves everything else
to `torch.utils.data.default_collate`; pass it as a `DataLoader`'s `collate_fn`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch.utils.data import default_collate

from .camera import SETTING_FIELDS, CameraSettings


def collate_settings(batch: Sequence[CameraSettings], **_: Any) -> CameraSettings:
    """Stack `(F,)` settings of `B` samples into `(B, F)` (`collate` calls it).

    Raises:
        ValueError: for settings with different apertures or shapes.

    Example:
        >>> s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-5)
        >>> tuple(collate_settings([s, s, s]).shape)
        (3, 2)
    """
    specs, shapes = {s.aperture for s in batch}, {tuple(s.shape) for s in batch}
    if len(specs) > 1 or len(shapes) > 1:  # one batch, one camera: an aperture, a shot count
        raise ValueError(f"cannot batch camera settings of different apertures {sorted(specs)} "
                         f"or different shapes {sorted(shapes)} (samples with different "
                         "numbers of shots)")
    stacked = {k: torch.stack([s.tensors()[k] for s in batch]) for k in SETTING_FIELDS}
    return CameraSettings(**stacked, aperture=batch[0].aperture)


def collate(batch: Sequence[Any]) -> Any:
    """`torch.utils.data.default_collate` that also batches `CameraSettings`: the collate function
    of data loaders whose samples hold camera settings (`DataLoader(..., collate_fn=collate)`).

    Samples (dicts, lists, tuples, named tuples) are walked like `default_collate` does; settings
    are stacked into `(B, F)` by `collate_settings`, and every part without settings goes to
    `default_collate` unchanged.

    Args:
        batch: the `B` samples.

    Returns:
        the batch: tensors stacked along a new first dimension, `(B, F)` settings.

    Raises:
        ValueError: for settings with different apertures or shapes, or sequences of different
            lengths that hold settings.

    Example:
        >>> s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-5)
        >>> batch = collate([{"camera": s, "x": torch.zeros(3)}] * 4)
        >>> tuple(batch["camera"].shape), tuple(batch["x"].shape)
        ((4, 2), (4, 3))
    """
    first = batch[0]
    if isinstance(first, CameraSettings):
        return collate_settings(batch)
    if not _holds_settings(first):
        return default_collate(batch)
    if isinstance(first, Mapping):
        merged = {key: collate([sample[key] for sample in batch]) for key in first}
        try:
            return type(first)(merged)
        except TypeError:  # a mapping that cannot be built from a dict
            return merged
    if any(len(sample) != len(first) for sample in batch):
        raise ValueError("each sample in a batch must hold the same number of elements")
    parts = [collate(list(samples)) for samples in zip(*batch, strict=True)]
    if isinstance(first, tuple) and hasattr(first, "_fields"):  # a named tuple
        return type(first)(*parts)
    return parts


def _holds_settings(sample: Any) -> bool:
    """Whether `sample` is or contains (in dicts, lists and tuples) `CameraSettings`."""
    if isinstance(sample, CameraSettings):
        return True
    if isinstance(sample, Mapping):
        return any(_holds_settings(value) for value in sample.values())
    if isinstance(sample, (list, tuple)):
        return any(_holds_settings(value) for value in sample)
    return False
