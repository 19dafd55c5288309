"""The warnings a training run ends with: kept in a list, written to `out_dir/warnings.log` and
raised as Python warnings; and the depth-collapse check.

Example:
    >>> import tempfile, pathlib, warnings
    >>> record = RunWarnings(pathlib.Path(tempfile.mkdtemp()), write=True)
    >>> with warnings.catch_warnings(record=True):
    ...     record.warn("the data wait grew", UserWarning)
    >>> record.messages, (record.folder / "warnings.log").read_text()
    (['the data wait grew'], 'the data wait grew\\n')
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

#: a prediction within this share of (depth_max - depth_min) of a limit counts as at the limit
LIMIT_TOLERANCE = 1e-3
#: warn when at least this share of the predicted pixels sits at depth_min or depth_max
COLLAPSE_FRACTION = 0.9


class DepthCollapseWarning(UserWarning):
    """Most predicted pixels sit at `depth_min` or `depth_max`: the network collapsed to its
    depth limits (often a too large learning rate) and its metrics mean little."""


def check_finite_step(losses: dict[str, float], grad_norm: float, step: int, lr: float) -> None:
    """Stop training at `step` (1-based) before the weights change when the loss or the
    gradient norm is not finite (`FloatingPointError`, naming the terms and `lr`)."""
    if not math.isfinite(losses["loss"]):
        terms = {k: v for k, v in losses.items() if k != "at_depth_limits"}
        raise FloatingPointError(
            f"loss is not finite at step {step}: {terms}; training stopped before changing "
            f"the weights (lr is {lr}: try a smaller one)")
    if not math.isfinite(grad_norm):
        raise FloatingPointError(
            f"gradient is not finite at step {step} (loss {losses['loss']:.4g}); training "
            f"stopped before changing the weights (lr is {lr}: try a smaller one, or grad_clip)")


def collapse_message(share: float | None, where: str, depth_range: tuple[float, float],
                     lr: float) -> str | None:
    """The collapse warning's words when `share` of the pixels of `where` sit at a depth limit
    (at least `COLLAPSE_FRACTION`), else None."""
    if share is None or share < COLLAPSE_FRACTION:
        return None
    return (f"{share:.0%} of the predicted pixels of {where} sit at depth_min "
            f"({depth_range[0]} m) or depth_max ({depth_range[1]} m): the network collapsed to "
            f"its depth limits (often a too large lr, here {lr}); its metrics mean little")


class RunWarnings:
    """The warnings of one `fit`.

    Args:
        folder: the run's folder (`warnings.log` goes there).
        write: whether this process writes the file (rank 0).
    """

    def __init__(self, folder: Path, write: bool):
        self.folder, self.write = Path(folder), write
        self.messages: list[str] = []

    def warn(self, message: str, category: type[Warning]) -> None:
        """Warn, keep the words in `messages` and append them to `warnings.log`."""
        self.messages.append(message)
        warnings.warn(message, category, stacklevel=4)
        if self.write:
            with (self.folder / "warnings.log").open("a") as handle:
                handle.write(message + "\n")
