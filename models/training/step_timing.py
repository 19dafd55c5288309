"""Each training step's time, split into waiting for its batch and computing it, and the warning
when the wait grows: a step that waits for data leaves its device idle.

Example:
    >>> timer = StepTimer()
    >>> for _ in range(30):
    ...     timer.add(data_s=0.05, compute_s=0.05)
    >>> round(timer.share(), 2)
    0.5
    >>> timer.wait_message(workers=0) is not None
    True
"""

from __future__ import annotations

#: warn when waiting for data takes more than this share of the steps
DATA_WAIT_LIMIT = 0.25
#: steps left out of the share at the start of each `fit` (worker start-up, cold caches)
WARMUP_STEPS = 2
#: steps timed after the warm-up before the share is judged
JUDGED_AFTER = 20
#: a mean wait below this many seconds per step is never worth a warning
NEGLIGIBLE_WAIT_S = 0.005


class DataWaitWarning(UserWarning):
    """Waiting for data took more than `DATA_WAIT_LIMIT` of the training steps: the device idled
    while samples were prepared."""


class StepTimer:
    """The data-wait and compute seconds of the steps of one `fit`."""

    def __init__(self) -> None:
        self.data_s: list[float] = []
        self.compute_s: list[float] = []
        self.warned = False

    def add(self, data_s: float, compute_s: float) -> None:
        """Record one step."""
        self.data_s.append(float(data_s))
        self.compute_s.append(float(compute_s))

    def share(self, last: int | None = None) -> float | None:
        """The share of the step time spent waiting for data, over the steps after the warm-up
        (or the `last` ones); None before any such step."""
        data, compute = self.data_s[WARMUP_STEPS:], self.compute_s[WARMUP_STEPS:]
        if not data:  # a short fit: what there is
            data, compute = self.data_s, self.compute_s
        if last is not None:
            data, compute = data[-last:], compute[-last:]
        total = sum(data) + sum(compute)
        return None if not data or total <= 0 else sum(data) / total

    def wait_message(self, workers: int) -> str | None:
        """The warning's words when the data wait exceeds `DATA_WAIT_LIMIT` of the steps after
        the warm-up, once `JUDGED_AFTER` of them are timed (once per `fit`), else None."""
        steps = len(self.data_s) - WARMUP_STEPS
        if self.warned or steps < JUDGED_AFTER:
            return None
        share = self.share()
        mean_data = sum(self.data_s[WARMUP_STEPS:]) / steps
        if share is None or share <= DATA_WAIT_LIMIT or mean_data < NEGLIGIBLE_WAIT_S:
            return None
        self.warned = True
        mean_step = mean_data + sum(self.compute_s[WARMUP_STEPS:]) / steps
        return (f"waiting for data took {share:.0%} of the training steps (on average "
                f"{mean_data:.3g} s of {mean_step:.3g} s): the device idles while samples are "
                f"prepared; prepare them ahead with more workers (workers={workers} now), keep "
                "loaded samples in memory (the dataset's memory_cache_mb) or train on smaller "
                "crops")
