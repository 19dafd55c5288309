"""The dataset base class: one sample format for every dataset.

A sample is a dict:

==============  ==================  ==========================================================
key             shape / type        meaning
==============  ==================  ==========================================================
`image`       `(3,H,W)` float   all-in-focus image, linear intensity in [0, 1]
`focused`     `(F,3,H,W)`       focused images (synthesised or real), linear in [0, 1]
`camera`      `CameraSettings`    `(F,)` focal length (m), f-number, focus distance (m),
                                    effective pixel pitch (m) and aperture of the focused
                                    images; `sample["camera"].shot(i)` is shot i's `Camera`
`depth`       `(1,H,W)` float   metres, > 0 everywhere (unknown pixels filled, see mask)
`mask`        `(1,H,W)` bool    where `depth` is a real measurement
`hint`        `(1,H,W)` float   (`with_hints` only) a depth found without labels, metres
`dataset`     str                 dataset name, e.g. `"nyu"`
`id`          str                 sample id within the dataset
==============  ==================  ==========================================================

After `datasets.collate` (`optics.collate`: `DataLoader(..., collate_fn=collate)`) the settings
become `(B,F)` and `focused` `(B,F,3,H,W)`.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import Dataset

from optics import Aperture, CameraSettings

from .focus import CameraPreset, cached_focal_stack, resolve_cache_dir
from .io import is_size, require_args
from .transforms import JointAugment, crop_sample, resize_sample


def _augment_rule(augment: Any) -> tuple[str, str, bool, str]:
    return ("augment", type(augment).__name__, augment is None or isinstance(augment, JointAugment),
            "a JointAugment or None")


class _MemoryCache:
    """Samples by index, least recently used dropped first beyond `limit_mb` MiB."""

    def __init__(self, limit_mb: float):
        self.limit = float(limit_mb) * 2**20
        self.entries: OrderedDict[int, tuple[dict[str, Any], int]] = OrderedDict()
        self.size = 0

    def get(self, index: int) -> dict[str, Any] | None:
        entry = self.entries.get(index)
        if entry is None:
            return None
        self.entries.move_to_end(index)
        return dict(entry[0])

    def put(self, index: int, sample: dict[str, Any]) -> None:
        size = sum(v.numel() * v.element_size() for v in sample.values()
                   if isinstance(v, torch.Tensor))
        if size > self.limit:
            return
        while self.entries and self.size + size > self.limit:
            _, (_, dropped) = self.entries.popitem(last=False)
            self.size -= dropped
        self.entries[index] = (dict(sample), size)
        self.size += size


class DepthDataset(Dataset):
    """Base class: subclasses list their samples and load one; this class does the rest.

    Subclasses set `name`, fill `self.ids` (one string per sample) and implement
    `load` returning `image`, `depth` and `mask` at native resolution, plus
    `focused` and `camera` where the dataset has real focused images (otherwise they are
    synthesised from depth with the preset). `__getitem__` then crops, resizes (scaling the
    pixel pitch), synthesises (cached), augments and checks the sample.

    Training on crops: pass `augment=JointAugment(crop_size=(h, w))`. The crop is taken *after*
    the focal stack was synthesised at full resolution, so the blur in pixels is the preset's
    (cropping leaves the pixel pitch alone), and image, focused images, depth and mask get the
    same window. With `memory_cache_mb` the full-resolution synthesised sample is kept in
    memory, so each step only loads nothing, crops and augments.

    Args:
        preset: the camera that synthesises the focused images.
        size: `(height, width)` to resize to, in pixels, or None to keep the native size.
        crop: `(top, left, height, width)` fixed crop at native resolution, before resizing.
        augment: a `JointAugment`, applied last (training only).
        cache_dir: folder to keep synthesised focal stacks in, `"auto"` for the per-user
            `datasets.focus.default_cache_dir()` (None when it is not writable), or None.
        aperture: PSF shape for synthesis (Gaussian, `sigma = CoC/2`, by default).
        render_kwargs: extra arguments of `optics.render_defocus` for synthesis.
        dtype: floating dtype of the returned tensors.
        memory_cache_mb: keep up to this many MiB of loaded, synthesised samples (before
            `augment`) in memory, least recently used dropped first; 0 keeps none.
    """

    #: Dataset name stored in each sample's `dataset` entry.
    name = "dataset"
    #: Image width in pixels at which the preset's pixel pitch holds; images of another width
    #: (e.g. small test files) get the pitch scaled by `native_width / width`. None: as is.
    native_width: int | None = None

    def __init__(
        self,
        preset: CameraPreset,
        size: Sequence[int] | None = None,
        crop: Sequence[int] | None = None,
        augment: JointAugment | None = None,
        cache_dir: str | Path | None = None,
        aperture: Aperture | None = None,
        render_kwargs: Mapping[str, Any] | None = None,
        dtype: torch.dtype = torch.float32,
        memory_cache_mb: float = 0,
    ):
        require_args(
            ("preset", type(preset).__name__, isinstance(preset, CameraPreset), "a CameraPreset"),
            ("size", size, is_size(size), "(height, width) in pixels, both > 0"),
            ("crop", crop, crop is None or len(crop) == 4, "(top, left, height, width) in pixels"),
            _augment_rule(augment),
            ("dtype", dtype, dtype.is_floating_point, "a floating-point dtype"),
            ("memory_cache_mb", memory_cache_mb, float(memory_cache_mb) >= 0, ">= 0 MiB"))
        self.preset = preset
        self.size = None if size is None else (int(size[0]), int(size[1]))
        self.crop = None if crop is None else tuple(int(c) for c in crop)
        self.augment = augment
        self.cache_dir = resolve_cache_dir(cache_dir)
        self.memory_cache_mb = float(memory_cache_mb)
        self._memory = _MemoryCache(self.memory_cache_mb)
        self.aperture = aperture
        self.render_kwargs = dict(render_kwargs or {})
        self.dtype = dtype
        self.ids: list[str] = []
        #: the depth hint of each sample (`with_hints`), None: none
        self.hints: list[torch.Tensor] | None = None

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def depth_range(self) -> tuple[float, float]:
        """`(near, far)` metres the dataset's scenes lie within: the preset's
        `(min_depth, depth_cap)`; a benchmark states its own (`FocalStackDataset`)."""
        return self.preset.depth_range

    def load(self, index: int) -> dict[str, Any]:
        """Native-resolution `image`, `depth`, `mask` (and real `focused`/`camera`)."""
        raise NotImplementedError

    def camera_settings(self, index: int) -> CameraSettings:
        """`(F,)` camera settings at native resolution; the preset's by default."""
        return self.preset.settings(self.dtype)

    def __getitem__(self, index: int) -> dict[str, Any]:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {self.name} with {len(self)} samples")
        index = index % len(self)
        sample = self._memory.get(index)
        if sample is None:
            sample = self._prepare(index)
        if self.hints is not None:  # before the augmentation: cropped and flipped alike
            sample = {**sample, "hint": self.hints[index]}
        kept = {v.untyped_storage().data_ptr() for v in sample.values()
                if isinstance(v, torch.Tensor)} if self._memory.limit > 0 or \
            self.hints is not None else set()
        if self.augment is not None:
            sample = self.augment(sample)
        for key, value in sample.items():  # the caller gets its own tensors, never the cache's
            if isinstance(value, torch.Tensor) and value.untyped_storage().data_ptr() in kept:
                sample[key] = value.clone(memory_format=torch.contiguous_format)
        sample["dataset"] = self.name
        sample["id"] = self.ids[index]
        return self._finish(sample)

    def _prepare(self, index: int) -> dict[str, Any]:
        """Load, crop, resize and synthesise sample `index` (kept in memory when asked)."""
        sample = self.load(index)
        if "camera" not in sample:
            sample["camera"] = self.camera_settings(index)
            if self.native_width is not None:
                scale = self.native_width / sample["image"].shape[-1]
                camera = sample["camera"]
                sample["camera"] = camera.replace(pixel_pitch=camera.pixel_pitch * scale)
        if self.crop is not None:
            sample = crop_sample(sample, *self.crop)
        if self.size is not None:
            sample = resize_sample(sample, self.size)
        if "focused" not in sample:
            depth = sample["depth"].clamp_min(self.preset.min_depth)
            sample["focused"] = cached_focal_stack(
                sample["image"], depth, sample["camera"], self.aperture, self.cache_dir,
                **self.render_kwargs,
            ).clamp(0, 1)
        self._memory.put(index, sample)
        return sample

    def with_augment(self, augment: JointAugment | None) -> DepthDataset:
        """A view of this dataset with another `augment` (e.g. random crops for training and
        none for the best-constant baseline), sharing the in-memory cache of samples.

        Example:
            >>> from datasets import Middlebury
            >>> whole = Middlebury(None, size=(50, 74), memory_cache_mb=64)
            >>> crops = whole.with_augment(JointAugment(crop_size=(16, 24)))
            >>> crop, sample = crops[0], whole[0]
            >>> crop["image"].shape, sample["image"].shape
            (torch.Size([3, 16, 24]), torch.Size([3, 50, 74]))
        """
        require_args(_augment_rule(augment))
        view = copy.copy(self)
        view.augment = augment
        return view

    def first(self, count: int) -> DepthDataset:
        """A view of this dataset's first `count` samples (all of them when it holds fewer),
        sharing its in-memory cache, augmentation and hints: a quick run on part of a set.

        Example:
            >>> from datasets import Middlebury
            >>> whole = Middlebury(None, size=(40, 60))
            >>> len(whole.first(0)), len(whole.first(5)) == len(whole)
            (0, True)
        """
        view = copy.copy(self)
        view.ids = self.ids[:max(int(count), 0)]
        view.hints = None if self.hints is None else self.hints[:len(view.ids)]
        return view

    def with_hints(self, hints: Sequence[torch.Tensor]) -> DepthDataset:
        """A view of this dataset whose samples also carry `hint`: a depth `(1, H, W)` metres
        of each sample found without labels (e.g. `models.training.hints.label_free_hints`),
        cropped and flipped with the sample (`TrainConfig.hint_weight`: depth hints).

        Raises:
            ValueError: not one hint per sample, a hint not finite and > 0 metres, or not of
                its sample's `(1, H, W)` (the latter when that sample is read).

        Example:
            >>> from datasets import Middlebury
            >>> whole = Middlebury(None, size=(50, 74))
            >>> hinted = whole.with_hints([torch.full((1, 50, 74), 2.0)])
            >>> crops = hinted.with_augment(JointAugment(crop_size=(16, 24)))
            >>> crop = crops[0]
            >>> tuple(crop["hint"].shape), "hint" in whole[0]
            ((1, 16, 24), False)
        """
        bad = next((h for h in hints if not bool(torch.isfinite(h).all() and (h > 0).all())),
                   None)
        require_args(("len(hints)", len(hints), len(hints) == len(self),
                      f"{len(self)} (one hint per sample)"),
                     ("hints", "a NaN, an infinity or a depth <= 0", bad is None,
                      "finite depths > 0"))
        view = copy.copy(self)
        view.hints = list(hints)
        return view

    def _finish(self, sample: dict[str, Any]) -> dict[str, Any]:
        out = {
            "image": sample["image"].to(self.dtype).contiguous(),
            "focused": sample["focused"].to(self.dtype).contiguous(),
            "camera": sample["camera"].to(self.dtype),
            "depth": sample["depth"].to(self.dtype).contiguous(),
            "mask": sample["mask"].bool().contiguous(),
            "dataset": sample["dataset"],
            "id": sample["id"],
        }
        if "hint" in sample:
            out["hint"] = sample["hint"].to(self.dtype).contiguous()
        h, w = out["image"].shape[-2:]
        n = out["camera"].n_shots
        wrong = [f"{key} has shape {tuple(out[key].shape)}, expected {shape}"
                 for key, shape in (("focused", (n, 3, h, w)), ("depth", (1, h, w)),
                                    ("mask", (1, h, w)), ("hint", (1, h, w)))
                 if key in out and tuple(out[key].shape) != shape]
        if not bool(torch.isfinite(out["depth"]).all() and (out["depth"] > 0).all()):
            wrong.append("depth must be finite and > 0")
        if wrong:
            raise ValueError(f"{self.name} sample {sample['id']!r}: {'; '.join(wrong)}")
        return out

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(samples={len(self)}, size={self.size}, crop={self.crop}, "
            f"augment={self.augment}, cache_dir={self.cache_dir}, "
            f"memory_cache_mb={self.memory_cache_mb:g})"
        )
