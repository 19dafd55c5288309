"""The batches of a run's steps, prepared ahead of the step that needs them.

A `BatchStream` yields the collated batch of each step from `first` to `until`, in order, with
the seconds the training loop waited for it. With `workers > 0` the batches are prepared in
`torch.utils.data.DataLoader` worker processes, `prefetch` batches per worker ahead of the step
(pinned memory and `non_blocking` copies when the device is a GPU); with `workers = 0` each batch
is prepared when it is asked for. On a GPU with workers, a thread of the training process moves
the next batches to the device on a side CUDA stream while the current step runs, so that the
step finds its batch there. All give the same batches: `models.training.sampling.StepSampler` makes each
step's samples a function of the step alone.

Example:
    >>> from models.training.sampling import StepSampler
    >>> samples = [{"image": torch.full((3, 2, 2), float(i))} for i in range(4)]
    >>> with BatchStream(StepSampler(samples, 2, seed=0), 0, 2, torch.device("cpu")) as stream:
    ...     [tuple(batch["image"].shape) for batch, waited in stream]
    [(2, 3, 2, 2), (2, 3, 2, 2)]
"""

from __future__ import annotations

import os
import pickle
import queue
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import torch
from torch import Tensor
from torch.utils.data import DataLoader, Dataset

from optics import CameraSettings, collate
from optics.checks import values_checked

from .sampling import StepSampler
from .state import to_device

#: batches each worker prepares ahead of the step that needs them
PREFETCH_BATCHES = 2
#: batches the device thread (`DevicePrefetch`) holds on the device ahead of the step
DEVICE_AHEAD = 2
#: a check of a collated batch and its step (0-based) that raises for a batch not to be used
BatchCheck = Callable[[Mapping[str, Any], int], None]


def usable_cpus() -> int:
    """The CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def auto_workers(device: torch.device, cpus: int | None = None) -> int:
    """The worker processes `workers = -1` means: on a GPU up to 4, leaving a core to the
    training loop; on the CPU, where the workers take cores from the step itself, one per 8 cores
    beyond the first 4 (none on a small machine).

    Example:
        >>> auto_workers(torch.device("cuda"), cpus=16), auto_workers(torch.device("cpu"), cpus=2)
        (4, 0)
    """
    cpus = usable_cpus() if cpus is None else cpus
    if device.type == "cpu":
        return max(0, (cpus - 4) // 8)
    return max(1, min(4, cpus - 1))


class _Failure:
    """An exception raised while a worker prepared a batch, carried to the training loop."""

    def __init__(self, error: BaseException):
        try:
            pickle.dumps(error)
            self.error = error
        except Exception:  # an exception that cannot cross processes: keep its words
            self.error = RuntimeError(f"{type(error).__name__}: {error}")
        self.trace = "".join(traceback.format_exception(error))

    def reraise(self) -> None:
        self.error.add_note(f"raised while a worker prepared the batch:\n{self.trace}")
        raise self.error


class StepBatches(Dataset):
    """Step -> the collated batch of this process for that step (a `Dataset` of batches).

    Args:
        sampler: the run's `StepSampler`.
        check: optional `f(batch, step)` that raises for a batch the run must not use.
    """

    def __init__(self, sampler: StepSampler, check: BatchCheck | None = None):
        self.sampler, self.check = sampler, check

    def batch(self, step: int) -> Any:
        """The checked batch of `step`."""
        batch = collate(self.sampler.samples(step))
        if self.check is not None:
            self.check(batch, step)
        return batch

    def __getitem__(self, step: int) -> Any:
        try:
            return self.batch(step)
        except Exception as error:  # raised again, with its own type, in the training loop
            return _Failure(error)


def _quiet_worker(_: int) -> None:
    """Workers leave SIGINT and SIGTERM to the training loop, which stops after its step and
    closes them; they end by themselves when the loop's process ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def tensors(batch: Any) -> Iterator[Tensor]:
    """Every tensor of a (nested) batch, the fields of its `CameraSettings` too."""
    if isinstance(batch, Tensor):
        yield batch
    elif isinstance(batch, Mapping):
        for value in batch.values():
            yield from tensors(value)
    elif isinstance(batch, list | tuple):
        for value in batch:
            yield from tensors(value)
    elif isinstance(batch, CameraSettings):
        yield from batch.tensors().values()


_END = object()


class DevicePrefetch:
    """Move the batches of `source` to `device` in a thread, `ahead` batches ahead of the loop
    that takes them; an iterator of the moved batches.

    On a GPU the copies run on a side CUDA stream; each batch is handed over with an event that
    the taking stream waits for, and its tensors are recorded on that stream so that their
    memory is not reused while it still reads them. The thread only moves batches (the
    `DataLoader` workers prepare them); an error it meets is raised where the batch is taken.

    Example:
        >>> batches = iter([{"x": torch.zeros(2)}, {"x": torch.ones(2)}])
        >>> with DevicePrefetch(batches, torch.device("cpu")) as moved:
        ...     [batch["x"].tolist() for batch in moved]
        [[0.0, 0.0], [1.0, 1.0]]
    """

    def __init__(self, source: Iterator[Any], device: torch.device, ahead: int = DEVICE_AHEAD):
        self.source, self.device = source, device
        self.stream = torch.cuda.Stream(device) if device.type == "cuda" else None
        self.ready: queue.Queue = queue.Queue(maxsize=max(1, ahead))
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._move, name="defocus-batches", daemon=True)
        self.thread.start()

    def _put(self, item: Any) -> bool:
        """Hand `item` over, unless the loop stopped taking batches (then False)."""
        while not self.stopping.is_set():
            try:
                self.ready.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _move(self) -> None:
        try:
            for batch in self.source:
                if isinstance(batch, _Failure):
                    self._put(batch)
                    return
                event = None
                with values_checked():  # checked where prepared; a read would wait for the GPU
                    if self.stream is None:
                        batch = to_device(batch, self.device)
                    else:
                        with torch.cuda.stream(self.stream):
                            batch = to_device(batch, self.device, non_blocking=True)
                            event = torch.cuda.Event()
                            event.record(self.stream)
                if not self._put((batch, event)):
                    return
            self._put(_END)
        except BaseException as error:  # raised again in the loop that takes the batches
            self._put(_Failure(error))

    def __iter__(self) -> DevicePrefetch:
        return self

    def __next__(self) -> Any:
        item = self.ready.get()
        if item is _END:
            self.ready.put(_END)  # every later call ends too
            raise StopIteration
        if isinstance(item, _Failure):
            item.reraise()
        batch, event = item
        if event is not None:
            stream = torch.cuda.current_stream(self.device)
            stream.wait_event(event)
            for tensor in tensors(batch):
                if tensor.device.type == "cuda":
                    tensor.record_stream(stream)
        return batch

    def close(self) -> None:
        """Stop the thread (it ends after the batch it is moving) and let go of the source."""
        self.stopping.set()
        self.thread.join(timeout=30)
        if not self.thread.is_alive():
            self.source = None

    def __enter__(self) -> DevicePrefetch:
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()


class BatchStream:
    """Iterate `(batch, seconds waited)` over the steps `first` to `until - 1` (0-based), each
    batch on `device`; a context manager that stops its workers on exit.

    Args:
        sampler: the run's `StepSampler`; an iterable (not map-style) dataset is always read in
            this process.
        first: the first step (0-based).
        until: the step after the last.
        device: where the batches go.
        workers: worker processes (0: prepare each batch when it is asked for).
        prefetch: batches each worker prepares ahead.
        check: optional `f(batch, step)` run on each batch where it is prepared, before it
            moves to the device.
        device_thread: move the batches to the device in a thread (`DevicePrefetch`); by
            default on a GPU with workers.
    """

    def __init__(self, sampler: StepSampler, first: int, until: int, device: torch.device,
                 workers: int = 0, prefetch: int = PREFETCH_BATCHES,
                 check: BatchCheck | None = None, device_thread: bool | None = None):
        if workers < 0:
            raise ValueError(f"workers must be >= 0, got {workers}")
        self.sampler, self.first, self.until = sampler, int(first), int(until)
        self.device = device
        self.workers = workers if sampler.is_map_style() else 0
        self.prefetch = prefetch
        self.batches = StepBatches(sampler, check)
        self.device_thread = (device.type == "cuda" and self.workers > 0
                              if device_thread is None else device_thread)
        self._iterator: Iterator[Any] | None = None
        self._mover: DevicePrefetch | None = None

    def _batches(self) -> Iterator[Any]:
        steps = range(self.first, self.until)
        if self.workers == 0:
            return (self.batches.batch(step) for step in steps)
        loader = DataLoader(self.batches, batch_size=None, sampler=steps,
                            num_workers=self.workers, prefetch_factor=self.prefetch,
                            pin_memory=self.device.type == "cuda",
                            worker_init_fn=_quiet_worker,
                            # the workers' base seed comes from here, not the global generator
                            generator=torch.Generator().manual_seed(self.sampler.seed))
        return iter(loader)

    def __iter__(self) -> BatchStream:
        if self._iterator is None:
            self._iterator = self._batches()
            if self.device_thread:
                self._mover = DevicePrefetch(self._iterator, self.device)
        return self

    def __next__(self) -> tuple[Mapping[str, Any], float]:
        started = time.perf_counter()
        iter(self)
        if self._mover is not None:
            return next(self._mover), time.perf_counter() - started
        batch = next(self._iterator)
        if isinstance(batch, _Failure):
            batch.reraise()
        with values_checked():  # checked where prepared; a check here would wait for the device
            batch = to_device(batch, self.device, non_blocking=True)
        return batch, time.perf_counter() - started

    def close(self) -> None:
        """Stop the device thread and the workers (a DataLoader iterator stops them when it is
        let go)."""
        if self._mover is not None:
            self._mover.close()
            self._mover = None
        # Stopped now, not when the iterator is collected: one kept alive by a reference cycle
        # (an exception's traceback) would outlive the process's exit, and workers that ignore
        # SIGTERM would then hold that exit up.
        shutdown = getattr(self._iterator, "_shutdown_workers", None)
        if shutdown is not None:
            shutdown()
        self._iterator = None

    def __enter__(self) -> BatchStream:
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()
