"""Stopping a training run on SIGINT or SIGTERM: after the step under way, with a checkpoint.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped on SIGINT or SIGTERM, after the step under way and a checkpoint.

    Attributes:
        signal: the signal number.
        step: the last completed step (saved in `checkpoint`).
        checkpoint: the path of `last.pt`, or `None` where nothing could be saved.
    """

    def __init__(self, signum: int, step: int, checkpoint: Path | None):
        self.signal, self.step, self.checkpoint = signum, step, checkpoint
        saved = f"saved {checkpoint}" if checkpoint else "no checkpoint saved"
        super().__init__(f"stopped by {signal.Signals(signum).name} after step {step} ({saved}); "
                         "continue with the same config (resume='auto') or `defocus train "
                         "--resume`")


class SignalGuard:
    """Owns the stop request of a training run: the signal caught while training (`signal`,
    `None` while none arrived) and the handlers installed for SIGINT and SIGTERM meanwhile.

    Args:
        world_size: the number of processes that must agree to stop (DDP).
        device: where the processes exchange the signal (the run's device).
    """

    def __init__(self, world_size: int, device: torch.device) -> None:
        self.world_size, self.device = world_size, device
        #: the signal that asks the run to stop, `None` while none arrived
        self.signal: int | None = None

    @contextlib.contextmanager
    def caught(self) -> Iterator[None]:
        """While training: SIGINT and SIGTERM ask the loop to save and stop after the step under
        way (a second SIGINT stops at once). Only in the main thread; an ignored signal stays
        ignored."""
        self.signal = None
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def handler(signum: int, frame: Any) -> None:
            if self.signal is not None and signum == signal.SIGINT:
                raise KeyboardInterrupt
            self.signal = signum

        previous = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                previous[sig] = signal.signal(sig, handler)
        try:
            yield
        finally:
            for sig, old in previous.items():
                signal.signal(sig, old)

    def requested(self) -> int:
        """The signal that asks to stop (0: none), agreed by all processes."""
        signum = self.signal or 0
        if self.world_size > 1:
            flag = torch.tensor([signum], device=self.device)
            dist.all_reduce(flag, op=dist.ReduceOp.MAX)
            signum = int(flag.item())
        return signum
