"""The pieces of state every training run shares: the process's rank, the learning-rate
schedule, the global random states (exact resume) and moving a batch to a device.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor

from optics import CameraSettings

from .config import TrainConfig


def process_rank() -> tuple[int, int]:
    """(rank, world size), initialising the process group under `torchrun`."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend)
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


class Progress:
    """A run's progress in [0, 1], which the learning-rate schedule follows:
    `max(step / steps, elapsed / budget)`, the elapsed time counted from `start` (one `fit`)
    against the time budget `minutes` (0: none, the steps alone). A budgeted run with a huge
    `steps` thus decays its learning rate over the budget; `time_spent` says whether the
    last reading found the budget spent (where `fit` stops).

    Example:
        >>> progress = Progress(steps=10)
        >>> progress(5), progress(20), progress.time_spent
        (0.5, 1.0, False)
    """

    def __init__(self, steps: int, minutes: float = 0.0) -> None:
        self.steps, self.budget_s = steps, minutes * 60.0
        self.started: float | None = None
        self.time_share = 0.0

    def start(self) -> None:
        """Start the clock of the time budget (each `fit`)."""
        self.started, self.time_share = time.perf_counter(), 0.0

    def __call__(self, step: int) -> float:
        if self.budget_s and self.started is not None:
            self.time_share = (time.perf_counter() - self.started) / self.budget_s
        return min(1.0, max(step / self.steps, self.time_share))

    @property
    def time_spent(self) -> bool:
        return self.time_share >= 1.0


def build_scheduler(optimizer: torch.optim.Optimizer, cfg: TrainConfig,
                    progress: Progress | None = None) -> torch.optim.lr_scheduler.LRScheduler:
    """Cosine decay to 0 over the run's `progress` (default: over `cfg.steps`), or a constant
    learning rate."""
    progress = progress or Progress(cfg.steps)
    curve = {"cosine": lambda p: 0.5 * (1 + math.cos(math.pi * p)),
             "constant": lambda p: 1.0}[cfg.lr_schedule]
    # the progress is read at every update, whatever the curve: `fit` stops on that reading
    return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: curve(progress(s)))


def rng_state() -> dict[str, Any]:
    """The global torch random states (CPU and CUDA) as `uint8` tensors (checkpoint data)."""
    state: dict[str, Any] = {"torch": torch.get_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: Mapping[str, Any]) -> None:
    """Restore states saved by `rng_state` (tensors may have been loaded onto a GPU)."""
    if "torch" in state:
        torch.set_rng_state(state["torch"].cpu())
    if "cuda" in state and torch.cuda.is_available():
        states = [s.cpu() for s in state["cuda"]]
        if len(states) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(states)


def to_device(batch: Any, device: torch.device, dtype: torch.dtype | None = None,
              non_blocking: bool = False) -> Any:
    """Move every tensor of a (nested) batch to `device` (floating tensors to `dtype`);
    `non_blocking` copies from pinned memory without waiting for them."""
    if isinstance(batch, Tensor):
        if dtype is not None and batch.is_floating_point():
            return batch.to(device=device, dtype=dtype, non_blocking=non_blocking)
        return batch.to(device, non_blocking=non_blocking)
    if isinstance(batch, Mapping):
        return {k: to_device(v, device, dtype, non_blocking) for k, v in batch.items()}
    if isinstance(batch, list | tuple):
        return type(batch)(to_device(v, device, dtype, non_blocking) for v in batch)
    if isinstance(batch, CameraSettings):
        if dtype is not None:
            return batch.to(device=device, dtype=dtype, non_blocking=non_blocking)
        return batch.to(device, non_blocking=non_blocking)
    return batch
