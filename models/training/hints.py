"""Depth hints for self-supervised training (Watson et al., "Self-Supervised Monocular Depth
Hints", ICCV 2019): the depth the label-free estimator finds in each training sample's own
photos, no depth labels read. `DepthDataset.with_hints` attaches them, `TrainConfig.hint_weight`
weighs them in the loss (`models.losses.DefocusLoss`), where they render better than the
network's depth.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor
from torch.utils.data import Dataset

from optics import CameraSettings
from optics.progress import progress_bar

from ..depth_from_photos import estimate_depth
from .config import TrainConfig


def label_free_depth(sample: Mapping[str, Any], depth_range: tuple[float, float],
                     max_pixels: int = 300_000,
                     image_settings: Callable[[CameraSettings], CameraSettings] | None = None,
                     side: str = "both", options: Mapping[str, Any] | None = None) -> Tensor:
    """The label-free depth `(1, H, W)` metres of a sample: `estimate_depth` of its `focused`
    photos with its `camera`, its `image` as the sharp photo (`image_settings(camera)`: that
    photo's own settings where it is only nearly sharp, e.g. an f/8 photo; None: all in focus),
    at `max_pixels` working pixels, a blur both sides explain put on `side`, with the method's
    `options` (e.g. `{"smoothing": 300.0}`). Its `depth` is not read.

    Example:
        >>> from optics import render_focal_stack
        >>> camera = CameraSettings(0.05, 2.0, [1.5, 4.0], 180e-6)
        >>> g = torch.Generator().manual_seed(0)
        >>> image, depth = torch.rand(3, 32, 32, generator=g), torch.full((1, 32, 32), 2.5)
        >>> focused = render_focal_stack(image[None], depth[None], camera)[0]
        >>> found = label_free_depth({"image": image, "focused": focused, "camera": camera},
        ...                          (1.0, 10.0))
        >>> tuple(found.shape), bool(((found - 2.5).abs() < 0.5).float().mean() > 0.9)
        ((1, 32, 32), True)
    """
    camera = sample["camera"]
    with torch.no_grad():
        return estimate_depth(sample["focused"], camera, depth_range, image=sample["image"],
                              image_settings=None if image_settings is None
                              else image_settings(camera), all_in_focus=False,
                              max_pixels=max_pixels, side=side, options=options)["depth"]


def label_free_hints(samples: Sequence[Mapping[str, Any]], depth_range: tuple[float, float],
                     progress: bool = True, **options: Any) -> list[Tensor]:
    """The depth hint of each of `samples` (whole samples, not random crops: a hint is cropped
    with its sample when read, `DepthDataset.with_hints`): `label_free_depth` with `options`,
    under a progress bar.

    Example:
        >>> from datasets import Middlebury
        >>> whole = Middlebury(None, size=(40, 60))
        >>> hints = label_free_hints(whole, (1.0, 10.0), progress=False)
        >>> [tuple(h.shape) for h in hints]
        [(1, 40, 60)]
    """
    return [label_free_depth(samples[i], depth_range, **options)
            for i in progress_bar(range(len(samples)), desc="depth hints (label-free)",
                                  disable=not progress)]


def attach_hints(dataset: Any, config: TrainConfig, progress: bool = True,
                 source: Sequence[Mapping[str, Any]] | None = None, **options: Any) -> Any:
    """`dataset` with the depth hints `config.hint_weight` asks for (`dataset` itself when it
    is 0): `label_free_hints` (with `options`: `label_free_depth`'s `max_pixels`,
    `image_settings`, `side`) in `config`'s depth range of its whole samples, or of `source`'s
    (the same scenes as the estimator reads them, e.g. real photos as taken where training
    reads them registered), attached with `DepthDataset.with_hints` (kept through its
    augmentation), or to each sample of a dataset that holds the same samples at every read
    (`HintedSamples`).

    Raises:
        ValueError: hints are asked for a dataset that cannot carry them: no length (an
            iterable dataset) or an augmentation of its own (random crops) that is not a
            `datasets.DepthDataset`'s.

    Example:
        >>> from datasets import Middlebury
        >>> whole = Middlebury(None, size=(40, 60))
        >>> attach_hints(whole, TrainConfig()) is whole
        True
        >>> sample = attach_hints(whole, TrainConfig(hint_weight=1.0), progress=False)[0]
        >>> tuple(sample["hint"].shape)
        (1, 40, 60)
    """
    if config.hint_weight == 0:
        return dataset
    carries = hasattr(dataset, "with_hints")  # a DepthDataset: crops its hints with it
    if not carries and (not hasattr(dataset, "__len__")
                        or getattr(dataset, "augment", None) is not None):
        raise ValueError(f"hint_weight={config.hint_weight!r} needs a dataset that holds the "
                         f"same samples at every read, to find their hints once (a "
                         f"datasets.DepthDataset, procedural scenes, a list), got a "
                         f"{type(dataset).__name__}; set hint_weight=0")
    whole = dataset.with_augment(None) if carries else dataset
    hints = label_free_hints(whole if source is None else source,
                             (config.depth_min, config.depth_max), progress, **options)
    return dataset.with_hints(hints) if carries else HintedSamples(dataset, hints)


class HintedSamples(Dataset):
    """The samples of `samples` (the same at every read, without random augmentation), each
    with its `hint` from `hints`.

    Example:
        >>> hinted = HintedSamples([{"image": torch.zeros(3, 2, 2)}], [torch.ones(1, 2, 2)])
        >>> len(hinted), sorted(hinted[0])
        (1, ['hint', 'image'])
    """

    def __init__(self, samples: Sequence[Mapping[str, Any]], hints: Sequence[Tensor]) -> None:
        if len(hints) != len(samples):
            raise ValueError(f"HintedSamples needs one hint per sample: {len(samples)} samples, "
                             f"got {len(hints)} hints")
        self.samples, self.hints = samples, list(hints)

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, index: int) -> dict[str, Any]:
        return {**self.samples[index], "hint": self.hints[index]}
