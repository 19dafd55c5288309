"""Checks of samples against a run's config: the training samples before any step is taken,
and the samples a trained network is evaluated on as they pass."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import torch
from torch import Tensor

from optics import CameraSettings

from ..depth_from_photos.trained_network import camera_record
from .config import TrainConfig
from .sampling import StepSampler

#: the refusal of a training set without samples
EMPTY = "train_set holds no samples; give at least one sample"


class SampleChecker:
    """Checks training samples against a config; owns nothing that changes: the config and the
    `StepSampler` whose dataset (`sampler.dataset`) and batch indices it checks and names.

    Args:
        config: the run's `TrainConfig` (input mode, supervision, `n_focus`).
        sampler: the run's sampler (its dataset is the `train_set`).
    """

    def __init__(self, config: TrainConfig, sampler: StepSampler) -> None:
        self.config, self.sampler = config, sampler
        #: the camera of the first training sample (`camera_record`), None where unknown
        self.camera: dict[str, list[float]] | None = None

    def needs(self) -> list[str]:
        """The sample keys that training with this config reads."""
        cfg = self.config
        keys = ["image"]
        if cfg.input_mode == "aif+focused" or cfg.supervision == "self":
            keys += ["focused", "camera"]
        if cfg.supervision == "depth" or cfg.learn_optics:  # learn_optics: rendered from it
            keys.append("depth")
        if cfg.supervision == "self" and cfg.hint_weight > 0:
            keys.append("hint")
        return keys

    def fit_first_sample(self) -> TrainConfig:
        """The config with `n_focus` taken from the first sample when it is 0, after refusing
        a map-style train_set whose first sample does not fit the config (also `config`)."""
        train_set, cfg = self.sampler.dataset, self.config
        if not self.sampler.is_map_style() or len(train_set) == 0:
            if cfg.n_focus == 0 and "focused" in self.needs() and self.sampler.is_map_style():
                raise ValueError(EMPTY)
            return cfg  # an empty train_set is refused by `fit`
        with torch.random.fork_rng(devices=[]):  # the read leaves the run's randomness alone
            sample = train_set[0]
        name = repr(sample.get("id", "#0")) if isinstance(sample, Mapping) else "#0"
        missing = [key for key in self.needs() if key not in sample] \
            if isinstance(sample, Mapping) else None
        focused = sample.get("focused") if missing == [] else None
        if isinstance(sample, Mapping) and isinstance(sample.get("camera"), CameraSettings):
            self.camera = camera_record(sample["camera"])
        n = (focused.shape[0] if focused.ndim == 4 else -1) \
            if "focused" in self.needs() and isinstance(focused, Tensor) else cfg.n_focus
        self.config = cfg = replace(cfg, n_focus=n) if cfg.n_focus == 0 and n > 0 else cfg
        for refused, message in (
            (missing is None, f"train_set[0] must be a sample mapping (image, focused, camera, "
             f"depth, mask), got a {type(sample).__name__}"),
            (bool(missing), f"sample {name} has no {missing}, which input_mode="
             f"{cfg.input_mode!r} with supervision={cfg.supervision!r}"
             + (f" and hint_weight={cfg.hint_weight!r} (their depth hints: "
                "models.training.hints.attach_hints)" if missing and "hint" in missing else "")
             + f" needs; it has {sorted(sample) if isinstance(sample, Mapping) else ''}"),
            (n != cfg.n_focus, f"n_focus is {cfg.n_focus} but sample {name} holds focused images "
             f"of shape {tuple(getattr(focused, 'shape', ()))} (F, 3, H, W); set n_focus to its "
             "number of focused images")):
            if refused:
                raise (TypeError if missing is None else ValueError)(message)
        return cfg

    def check_depth(self, batch: Mapping[str, Any], step: int) -> None:
        """Refuse ground-truth depth that is not finite and > 0 where the mask says valid (at
        every pixel with `learn_optics`: the focused images are rendered from it), in the
        collated batch of `step` (0-based); the message names the sample."""
        depth, mask = batch["depth"], batch.get("mask")
        everywhere = mask is None or bool(self.config.learn_optics)
        valid = torch.ones_like(depth, dtype=torch.bool) if everywhere else mask.bool()
        bad = valid & ~(torch.isfinite(depth) & (depth > 0))
        if not bool(bad.any()):
            return
        i = int(bad.flatten(1).any(1).nonzero()[0])
        indices = self.sampler.indices(step) if self.sampler.is_map_style() else None
        where = f"train_set[{indices[i]}]" if indices is not None else "a train_set sample"
        ids = batch.get("id")
        name = ids[i] if isinstance(ids, Sequence) and not isinstance(ids, str) else where
        raise ValueError(
            f"sample {name!r} ({where}) has ground-truth depth that is not finite and > 0 "
            f"at {int(bad[i].sum())} of its valid pixels (e.g. {float(depth[i][bad[i]][0])!r}); "
            + ("depth must be positive metres at every pixel to render focused images from it "
               "(learn_optics): fill the data's unknown depths" if self.config.learn_optics else
               "depth must be positive metres wherever its mask is valid: fix the data or "
               "mark those pixels invalid in its mask"))


class TestSampleChecker:
    """Checks the samples a trained network is evaluated on against its config, as they pass
    (`checked`), and counts the valid ground-truth pixels outside the network's depth range,
    which it cannot output (`outside`, `valid`).

    Args:
        config: the checkpoint's `TrainConfig` (input mode, `n_focus`, depth range).
        name: the network as named in messages, e.g. `"checkpoint run/checkpoints/last.pt"`.
    """

    __test__ = False  # not a pytest class

    def __init__(self, config: TrainConfig, name: str) -> None:
        self.config, self.name = config, name
        self.outside, self.valid = 0, 0

    def check(self, sample: Any, index: int) -> Mapping[str, Any]:
        """`sample` (the `index`-th), after checking that the network can read it.

        Raises:
            TypeError: it is not a sample mapping.
            ValueError: it lacks a key the network reads, or holds another number of
                focused photos than the network was trained on (naming both).
        """
        cfg = self.config
        if not isinstance(sample, Mapping):
            raise TypeError(f"test sample #{index} must be a sample mapping, got a "
                            f"{type(sample).__name__}")
        name = repr(sample.get("id", f"#{index}"))
        needs = ["image", "depth"] + (["focused", "camera"] if cfg.input_mode == "aif+focused"
                                      else [])
        missing = [key for key in needs if sample.get(key) is None]
        focused = sample.get("focused")
        n = cfg.n_focus if not isinstance(focused, Tensor) or cfg.input_mode != "aif+focused" \
            else focused.shape[0] if focused.ndim == 4 else -1
        refusal = (f"test sample {name} has no {missing}, which {self.name} (input_mode="
                   f"{cfg.input_mode!r}) needs; it has {sorted(sample)}" if missing else
                   f"{self.name} was trained on n_focus={cfg.n_focus} focused photos, but test "
                   f"sample {name} holds focused images of shape {tuple(focused.shape)} (F, 3, "
                   f"H, W); evaluate it on data with {cfg.n_focus} focused photos per scene"
                   if n != cfg.n_focus else None)
        if refusal is not None:
            raise ValueError(refusal)
        self._count_range(sample)
        return sample

    def _count_range(self, sample: Mapping[str, Any]) -> None:
        depth = sample["depth"]
        if not isinstance(depth, Tensor):
            return
        mask = sample.get("mask")
        valid = torch.isfinite(depth) & (depth > 0)
        if isinstance(mask, Tensor) and mask.shape == depth.shape:
            valid &= mask.bool()
        cfg = self.config
        outside = valid & ((depth < cfg.depth_min) | (depth > cfg.depth_max))
        self.valid += int(valid.sum())
        self.outside += int(outside.sum())

    def range_message(self, share: float = 0.05) -> str | None:
        """A warning when more than `share` of the valid ground-truth pixels lie outside the
        network's depth range, else None."""
        if not self.valid or self.outside <= share * self.valid:
            return None
        cfg = self.config
        return (f"{self.outside / self.valid:.0%} of the valid ground-truth pixels lie outside "
                f"the depth range of {self.name} ({cfg.depth_min} to {cfg.depth_max} "
                "m), which the network cannot output: these metrics measure the range more than "
                "the network; evaluate a checkpoint trained for these depths")
