"""The pieces of state every training run shares: the process's rank, the learning-rate
schedule, the global random states (exact resume) and moving a batch to a device.
"""

from __future__ import annotations

import math
import os
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


def build_scheduler(optimizer: torch.optim.Optimizer,
                    cfg: TrainConfig) -> torch.optim.lr_scheduler.LRScheduler:
    """Cosine decay to 0 over `cfg.steps`, or a constant learning rate."""
    if cfg.lr_schedule == "cosine":
        return torch.optim.lr_scheduler.LambdaLR(
            optimizer, lambda s: 0.5 * (1 + math.cos(math.pi * min(s, cfg.steps) / cfg.steps)))
    return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: 1.0)


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
