"""Which samples each training step sees, and their random flips, as functions of the step.

The batch of step `k` is drawn from a permutation seeded by `(seed, epoch)`, each of its samples
is prepared with torch's global generator seeded by `(seed, step, rank, position)` (a dataset's
random crops, flips and gains), and its batch flips come from a generator seeded by
`(seed, step, rank)`. A step's batch is thus a function of the step alone: a run resumed at step
`k` sees the same batches as an uninterrupted run, and so does a run whose batches are prepared
ahead in worker processes (`models.training.batches`). Under data parallelism each process takes
its own part of the global batch of `batch_size * world_size` samples.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor


class StepSampler:
    """The samples of each step from a map-style dataset (exactly reproducible) or an iterable.

    Args:
        dataset: a map-style dataset (`len` and indexing) or any iterable of samples.
        batch_size: samples per step and per process.
        seed: seed of the batch order.
        rank: this process's index.
        world_size: the number of processes.
    """

    def __init__(self, dataset: Iterable[Mapping[str, Any]], batch_size: int, seed: int,
                 rank: int = 0, world_size: int = 1):
        self.dataset = dataset
        self.batch_size, self.seed = batch_size, seed
        self.rank, self.world_size = rank, world_size
        self._iterator: Iterator[Mapping[str, Any]] | None = None

    def is_map_style(self) -> bool:
        return hasattr(self.dataset, "__len__") and hasattr(self.dataset, "__getitem__")

    def indices(self, step: int) -> list[int]:
        """Dataset indices of this process's part of the batch of `step` (0-based)."""
        n, b = len(self.dataset), self.batch_size
        start = step * b * self.world_size + self.rank * b
        indices, permutations = [], {}
        for position in range(start, start + b):
            epoch = position // n
            if epoch not in permutations:
                generator = torch.Generator().manual_seed(self.seed * 100_003 + epoch)
                permutations[epoch] = torch.randperm(n, generator=generator)
            indices.append(int(permutations[epoch][position % n]))
        return indices

    def samples(self, step: int) -> list[Mapping[str, Any]]:
        """This process's samples of step `step` (0-based).

        From a map-style dataset each sample is prepared under torch's global generator seeded
        by `sample_seed(seed, step, rank, position)` (and restored afterwards), so its random
        augmentation depends on the step alone; an iterable's samples come in their own order
        and randomness.
        """
        if self.is_map_style():
            samples = []
            with torch.random.fork_rng(devices=[]):
                for position, index in enumerate(self.indices(step)):
                    torch.manual_seed(sample_seed(self.seed, step, self.rank, position))
                    samples.append(self.dataset[index])
            return samples
        per_step = self.batch_size * self.world_size
        if self._iterator is None:  # iterable: consume, skipping what earlier steps used
            self._iterator = self._cycle()
            for _ in range(step * per_step):
                next(self._iterator)
        samples = [next(self._iterator) for _ in range(per_step)]
        return samples[self.rank :: self.world_size]

    def _cycle(self) -> Iterator[Mapping[str, Any]]:
        while True:
            empty = True
            for sample in self.dataset:
                empty = False
                yield sample
            if empty:
                raise ValueError("train_set yielded no samples")


def sample_seed(seed: int, step: int, rank: int, position: int) -> int:
    """A 64-bit seed for one sample of one step, well mixed from its four integers.

    Example:
        >>> sample_seed(0, 3, 0, 1) == sample_seed(0, 3, 0, 1) != sample_seed(0, 3, 0, 2)
        True
    """
    state = np.random.SeedSequence([seed, step, rank, position]).generate_state(1, np.uint64)
    return int(state[0])


def random_flip(batch: dict[str, Any], seed: int, step: int, rank: int = 0) -> dict[str, Any]:
    """Flip each sample of a collated batch left-right with probability 1/2 (`image`,
    `focused`, `depth` and `mask` together), reproducibly from `(seed, step, rank)`."""
    generator = torch.Generator().manual_seed(seed * 7919 + step * 31 + rank)
    flip = torch.rand(batch["image"].shape[0], generator=generator) < 0.5
    out = dict(batch)
    for key in ("image", "focused", "depth", "mask"):
        if key in batch and isinstance(batch[key], Tensor):
            value = batch[key]
            shape = (-1,) + (1,) * (value.ndim - 1)
            out[key] = torch.where(flip.view(shape).to(value.device), value.flip(-1), value)
    return out


__all__ = ["StepSampler", "random_flip", "sample_seed"]
