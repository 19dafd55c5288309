"""Each training step's time, split into waiting for its batch and computing it (and the
computing into its phases: the network, the loss with its render, the backward pass and the
optimiser), and the warning when the wait grows: a step that waits for data leaves its device
idle.

Example:
    >>> timer = StepTimer()
    >>> for _ in range(30):
    ...     timer.add(data_s=0.05, compute_s=0.05, phases={"network": 0.02, "backward": 0.03})
    >>> round(timer.share(), 2)
    0.5
    >>> timer.wait_message(workers=0) is not None
    True
    >>> timer.summary()
    'step 100 ms: data 50 ms, network 20 ms, backward 30 ms (mean of 28 steps)'
"""

from __future__ import annotations

import statistics

#: warn when waiting for data takes more than this share of the steps
DATA_WAIT_LIMIT = 0.25
#: steps left out of the share at the start of each `fit` (worker start-up, cold caches)
WARMUP_STEPS = 2
#: steps timed after the warm-up before the share is judged
JUDGED_AFTER = 20
#: a mean wait below this many seconds per step is never worth a warning
NEGLIGIBLE_WAIT_S = 0.005
#: the phases of a step's computation, in order: the forward pass of the network, the loss (with
#: the render through the PSF layer, or the depth error of a supervised run; the two together
#: as "network and loss" when compiled into one graph), the backward pass of all of them and
#: the optimiser's update (with the schedule's)
PHASES = ("network", "loss", "network and loss", "backward", "optimizer")


class DataWaitWarning(UserWarning):
    """Waiting for data took more than `DATA_WAIT_LIMIT` of the training steps: the device idled
    while samples were prepared."""


class StepTimer:
    """The data-wait and compute seconds of the steps of one `fit`, and the compute's phases
    (`PHASES`, host seconds: on a GPU a phase's kernels may still run in a later phase, and the
    step's one wait for the device falls in "other")."""

    def __init__(self) -> None:
        self.data_s: list[float] = []
        self.compute_s: list[float] = []
        self.phases_s: list[dict[str, float]] = []
        self.warned = False

    def add(self, data_s: float, compute_s: float,
            phases: dict[str, float] | None = None) -> None:
        """Record one step (with the seconds of its phases, if timed)."""
        self.data_s.append(float(data_s))
        self.compute_s.append(float(compute_s))
        self.phases_s.append({k: float(v) for k, v in (phases or {}).items()})

    def _judged(self) -> slice:
        """The steps after the warm-up (all of them in a short fit)."""
        return slice(WARMUP_STEPS, None) if len(self.data_s) > WARMUP_STEPS else slice(None)

    def share(self, last: int | None = None) -> float | None:
        """The share of the step time spent waiting for data, over the steps after the warm-up
        (or the `last` ones); None before any such step."""
        data, compute = self.data_s[self._judged()], self.compute_s[self._judged()]
        if last is not None:
            data, compute = data[-last:], compute[-last:]
        total = sum(data) + sum(compute)
        return None if not data or total <= 0 else sum(data) / total

    def split(self) -> dict[str, float]:
        """Mean seconds per step after the warm-up (they add up to the step's): `step` (data and compute), `data`, each
        timed phase of `PHASES` and `other` (the compute outside the phases: checks, the loss
        values read back), in that order; empty before the first step."""
        judged = self._judged()
        data, compute = self.data_s[judged], self.compute_s[judged]
        if not data:
            return {}
        phases = self.phases_s[judged]
        out = {"step": statistics.fmean(d + c for d, c in zip(data, compute, strict=True)),
               "data": statistics.fmean(data)}
        timed = [name for name in PHASES if any(name in p for p in phases)]
        for name in timed:
            out[name] = statistics.fmean(p.get(name, 0.0) for p in phases)
        if timed:
            out["other"] = statistics.fmean(
                max(c - sum(p.values()), 0.0) for c, p in zip(compute, phases, strict=True))
        return out

    def summary(self) -> str:
        """`split` in words, e.g. `'step 1.2 s: data 8 ms, network 380 ms, ...'`; empty before
        the first step."""
        split = self.split()
        if not split:
            return ""
        steps = len(self.data_s[self._judged()])
        parts = ", ".join(f"{name} {_duration(seconds)}" for name, seconds in split.items()
                          if name != "step" and (name != "other" or seconds >= 0.0005))
        return f"step {_duration(split['step'])}: {parts} (mean of {steps} steps)"

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


def _duration(seconds: float) -> str:
    """`'8 ms'`, `'380 ms'` or `'1.2 s'`."""
    return f"{seconds * 1000:.0f} ms" if seconds < 0.9995 else f"{seconds:.3g} s"
