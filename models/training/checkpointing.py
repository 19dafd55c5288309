"""When and how a training run writes its checkpoints: periodically, once per step, never with
non-finite weights, and after a failure with the random state the failed step started with.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from ..checkpoints import CheckpointStore, save_checkpoint
from .state import rng_state

_log = logging.getLogger("models.training")


def require_finite_weights(state: dict[str, Any], step: int) -> dict[str, Any]:
    """`state` (a trainer's `state_dict`), after checking that the model's weights are finite.

    Raises:
        FloatingPointError: a floating-point weight is not finite (naming `step`).
    """
    tensors = [t for t in state["model"].values() if t.is_floating_point()]
    if tensors and not bool(torch.stack([torch.isfinite(t).all() for t in tensors]).all()):
        raise FloatingPointError(f"not saving a checkpoint of step {step}: the weights "
                                 "are not finite")
    return state


class Checkpointer:
    """Owns the writing of a run's checkpoints: the `CheckpointStore`, the step saved last
    (`saved_step`), the time of the last save (`last_save`, for `checkpoint_minutes`), and what
    a checkpoint after a failure needs: the random state the step under way started with
    (`rng_at_step`) and whether the weights are being updated (`in_update`: no checkpoint of a
    half step).

    The trainer hands it the state to write (its `state_dict`) and the step.

    Args:
        store: where the checkpoints go (`last.pt` and `step_XXXXXX.pt`).
        is_main: whether this process writes files (rank 0).
    """

    def __init__(self, store: CheckpointStore, is_main: bool) -> None:
        self.store, self.is_main = store, is_main
        self.saved_step: int | None = None
        self.last_save = time.monotonic()
        self.rng_at_step: dict[str, Any] | None = None
        self.in_update = False

    def restart_clock(self) -> None:
        """Count `checkpoint_minutes` from now."""
        self.last_save = time.monotonic()

    def start_step(self) -> None:
        """Remember the random state the step about to start begins with."""
        self.rng_at_step = rng_state()

    def is_saved(self, step: int) -> bool:
        """Whether `last.pt` holds `step` already."""
        return self.saved_step == step and self.store.exists()

    def due(self, step: int, every: int, minutes: float) -> bool:
        """Whether a periodic checkpoint is due: `step` is a multiple of `every`, or `minutes`
        passed since the last save (0 turns either off)."""
        if every and step % every == 0:
            return True
        return bool(minutes) and time.monotonic() - self.last_save >= 60 * minutes

    def save(self, state: dict[str, Any], step: int, path: str | Path | None = None) -> Path:
        """Write `state` (finite weights only; atomic) to `path`, or without it as `step`'s
        checkpoint and `last.pt` in the store (pruned; then `step` counts as saved)."""
        if path is not None:
            return save_checkpoint(require_finite_weights(state, step), path)
        written = self.store.save(require_finite_weights(state, step), step)
        self.saved_step, self.last_save = step, time.monotonic()
        return written

    def save_after_failure(self, state: Callable[[], dict[str, Any]], step: int) -> None:
        """After an exception: save the last completed `step` (the trainer's `state` with the
        random state it started the failed step with), unless it is saved, half-done or not
        finite, or this process writes no files. Never raises."""
        if not self.is_main or self.in_update or step == 0 or self.saved_step == step:
            return
        try:
            data = state()
            if self.rng_at_step is not None:
                data["rng"] = self.rng_at_step
            self.save(data, step)
        except Exception as error:  # never hide the original error
            _log.warning("could not save a checkpoint after the failure: %s", error)
