"""What a training run saves and restores: weights, optimiser, schedule, step, history and the
random states (exact resume), on one process or several (DDP).

`CheckpointingMixin` gives `models.training.Trainer` its checkpoint methods; the functions here
are the pieces of state every run shares: the process's rank, the learning-rate schedule, the
random states, moving a batch to a device, and reading a checkpoint's config back
(`models.loading` loads the network itself).
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor

from optics import CameraSettings

from .checkpoints import (
    CHECKPOINT_FORMAT,
    CheckpointError,
    save_checkpoint,
    to_plain,
)
from .train_config import TrainConfig

_log = logging.getLogger("models.training")


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


def to_device(batch: Any, device: torch.device, dtype: torch.dtype | None = None) -> Any:
    """Move every tensor of a (nested) batch to `device` (floating tensors to `dtype`)."""
    if isinstance(batch, Tensor):
        if dtype is not None and batch.is_floating_point():
            return batch.to(device=device, dtype=dtype)
        return batch.to(device)
    if isinstance(batch, Mapping):
        return {k: to_device(v, device, dtype) for k, v in batch.items()}
    if isinstance(batch, list | tuple):
        return type(batch)(to_device(v, device, dtype) for v in batch)
    if isinstance(batch, CameraSettings):
        return batch.to(device=device, dtype=dtype) if dtype is not None else batch.to(device)
    return batch


def config_from_state(state: Mapping[str, Any], path: str | Path, **changes: Any) -> TrainConfig:
    """The `TrainConfig` of a loaded checkpoint, with `changes`; a bad one is a
    `CheckpointError` naming the file."""
    try:
        return TrainConfig.from_dict({**state["config"], **changes})
    except (TypeError, ValueError) as error:
        raise CheckpointError(f"checkpoint {path} holds an invalid config: {error}") from None


class CheckpointingMixin:
    """The checkpoint methods of `models.training.Trainer` (which holds `model`, `optimizer`,
    `scheduler`, `step`, `history`, `config`, `checkpoints` and `is_main`)."""

    def state_dict(self) -> dict[str, Any]:
        """Everything exact resume needs, as tensors and plain data only (see
        `models.checkpoints`)."""
        return {"format": CHECKPOINT_FORMAT, "model": self.model.state_dict(),
                "optimizer": self.optimizer.state_dict(),
                "scheduler": self.scheduler.state_dict(), "step": self.step,
                "config": to_plain(self.config.to_dict(), "config"),
                "history": [dict(row) for row in self.history], "rng": rng_state()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore what `state_dict` returned (also older checkpoints without `rng`)."""
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.step = int(state["step"])
        self.history = [dict(row) for row in state.get("history", [])]
        set_rng_state(state.get("rng", {}))

    def save_checkpoint(self, path: str | Path | None = None) -> Path | None:
        """Save model, optimiser, scheduler, step, config, history and random states (rank 0
        only; atomic). Without `path`: `step_XXXXXX.pt` and `last.pt` in
        `checkpoint_dir`, pruned to `config.keep_checkpoints`. Returns the path written."""
        if not self.is_main:
            return None
        if path is not None:
            return save_checkpoint(self._finite(self.state_dict()), path)
        return self._write_checkpoint(self.state_dict())

    def _write_checkpoint(self, state: dict[str, Any]) -> Path:
        """Write `state` as this step's checkpoint and `last.pt` (finite weights only)."""
        path = self.checkpoints.save(self._finite(state), self.step)
        self._saved_step, self._last_save = self.step, time.monotonic()
        return path

    def _finite(self, state: dict[str, Any]) -> dict[str, Any]:
        """`state`, after checking that the model's weights are finite."""
        tensors = [t for t in state["model"].values() if t.is_floating_point()]
        if tensors and not bool(torch.stack([torch.isfinite(t).all() for t in tensors]).all()):
            raise FloatingPointError(f"not saving a checkpoint of step {self.step}: the weights "
                                     "are not finite")
        return state

    def _save_once(self) -> Path | None:
        """`save_checkpoint()` unless this step is saved already; returns `last.pt`."""
        if self._saved_step == self.step and self.checkpoints.exists():
            return self.checkpoints.last
        return self.save_checkpoint()

    def _save_after_failure(self) -> None:
        """After an exception: save the last completed step (with the random state it started
        the failed step with), unless it is saved, half-done or not finite."""
        if not self.is_main or self._in_update or self.step == 0 or self._saved_step == self.step:
            return
        try:
            state = self.state_dict()
            if self._rng_at_step is not None:
                state["rng"] = self._rng_at_step
            self._write_checkpoint(state)
        except Exception as error:  # never hide the original error
            _log.warning("could not save a checkpoint after the failure: %s", error)
