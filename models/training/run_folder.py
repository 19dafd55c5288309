"""One folder holds one training run: which files are the run's, and what `resume` does with a
folder that already holds one (continue it, refuse another, or delete it when `fit` starts).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from ..checkpoints import (
    CheckpointError,
    CheckpointStore,
    file_in_the_way,
    load_checkpoint,
    to_plain,
)
from .config import RUN_CONTROL_KEYS, TrainConfig
from .run_log import RunLog

_log = logging.getLogger("models.training")


#: the files of a run in `out_dir` besides `checkpoints/*.pt` and `figures/step_*.png`
RUN_FILES = ("config.yaml", "train_log.csv", "val_log.csv", "warnings.log",
             "camera.json", "mask.png", "optics.png")  # the last three: a learned camera


def run_files(out_dir: str | Path) -> list[Path]:
    """The files of a training run in `out_dir`: config, logs, checkpoints (and stray
    temporaries) and figures; other files in the folder are not the run's."""
    out_dir = Path(out_dir)
    files = [out_dir / name for name in RUN_FILES if (out_dir / name).is_file()]
    for folder, patterns in (("checkpoints", ("*.pt", ".*.tmp")), ("figures", ("step_*.png",))):
        if (out_dir / folder).is_dir():
            for pattern in patterns:
                files += sorted((out_dir / folder).glob(pattern))
    return files


def check_run_folder(out_dir: str | Path, option: str = "out_dir") -> Path:
    """Refuse an `out_dir` that cannot become a folder: it, or a folder above it, is a file.

    Args:
        out_dir: the run's folder.
        option: its name in the message (`"--out"` for the command line).

    Returns:
        `out_dir` as a `Path`.

    Raises:
        NotADirectoryError: naming `out_dir` and the file in the way.

    Example:
        >>> import tempfile
        >>> file = Path(tempfile.mkdtemp()) / "notes.txt"
        >>> _ = file.write_text("x")
        >>> check_run_folder(file / "run")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        NotADirectoryError: out_dir .../notes.txt/run cannot be a folder: .../notes.txt is a file; choose another out_dir
    """
    out_dir = Path(out_dir)
    blocker = file_in_the_way(out_dir)
    if blocker is not None:
        raise NotADirectoryError(f"{option} {out_dir} cannot be a folder: {blocker} is a file; "
                                 f"choose another {option}")
    return out_dir


def config_diff(old: TrainConfig, new: TrainConfig) -> dict[str, tuple[Any, Any]]:
    """`{key: (old value, new value)}` for the keys (not in `RUN_CONTROL_KEYS`) that differ."""
    a, b = to_plain(old.to_dict(), "config"), to_plain(new.to_dict(), "config")
    return {key: (a[key], b[key]) for key in a
            if key not in RUN_CONTROL_KEYS and a[key] != b[key]}


def describe_diff(diff: Mapping[str, tuple[Any, Any]]) -> str:
    """`key (there old, here new), ...` for an error message."""
    return ", ".join(f"{key} (there {old!r}, here {new!r})" for key, (old, new) in diff.items())


@dataclass(frozen=True)
class RunToContinue:
    """The run that `out_dir` holds and that a trainer continues.

    Attributes:
        source: `checkpoints/last.pt`, or `config.yaml` where the run saved no checkpoint.
        state: the checkpoint's state (`None` without a checkpoint): the trainer loads it.
    """

    source: Path
    state: dict[str, Any] | None


class RunFolder:
    """Owns one run's folder, `config.out_dir`: what `config.resume` does with a run it holds
    already, the old run's files that an overwrite deletes when `fit` starts (`removals`), and
    the step that a continued run's logs, checkpoints and figures are cut back to then
    (`truncate_to`).

    Args:
        config: the run's `TrainConfig` (`out_dir`, `resume`, and the config to compare).
        checkpoints: the run's `CheckpointStore` (in `out_dir/checkpoints`).
        log: the run's CSV logs.
    """

    def __init__(self, config: TrainConfig, checkpoints: CheckpointStore, log: RunLog) -> None:
        self.config, self.checkpoints, self.log = config, checkpoints, log
        #: the old run's files, deleted when fit starts
        self.removals: list[Path] = []
        #: cut the logs, checkpoints and figures back to this step when fit starts
        self.truncate_to: int | None = None

    def open(self, device: torch.device) -> RunToContinue | None:
        """Apply `config.resume` to what `out_dir` holds: plan to delete it (`"overwrite"`),
        refuse it, or return the run to continue (`None`: nothing to continue).

        Raises:
            ValueError: `out_dir` holds another run (naming the keys that differ), no run to
                continue with `resume="resume"`, a run without its config, a
                `checkpoints/last.pt` that is not a file, or (to overwrite) files named like a
                run's but no run.
            CheckpointError: `checkpoints/last.pt` (without it: the newest step checkpoint,
                which holds the same) is not a checkpoint.
        """
        cfg = self.config
        files = run_files(cfg.out_dir)
        overwrite = cfg.resume == "overwrite"
        if not overwrite:
            self._check_last()
        names = sorted(str(path.relative_to(cfg.out_dir)) for path in files)
        for refused, message in (
                (overwrite and not self._is_a_run(files), f"out_dir {cfg.out_dir} holds {names}, "
                 "named like a run's files, but no training run (no checkpoint, no config.yaml "
                 "of a run): resume='overwrite' (--overwrite) deletes only a run's files; move "
                 "them away or choose another out_dir"),
                (cfg.resume == "resume" and not files, f"resume='resume' (--resume) but out_dir "
                 f"{cfg.out_dir} holds no run to continue; check the folder, or start a new run "
                 "without --resume")):
            if refused:
                raise ValueError(message)
        if overwrite or not files:
            self.removals = files if overwrite else []
            return None
        source, state, saved = self._saved_run(files, device)
        self._check_same_run(saved, int(state["step"]) if state is not None else 0)
        return RunToContinue(source, state)

    def _is_a_run(self, files: list[Path]) -> bool:
        """Whether `files` (named like a run's) may be deleted: none, or the folder holds a run
        (a checkpoint or a `config.yaml` that reads as a `TrainConfig`; `--out . --overwrite`
        in a project folder would delete its own config.yaml)."""
        if not files or self.checkpoints.exists() or self.checkpoints.list():
            return True
        try:
            TrainConfig.from_yaml(self.config.out_dir / "config.yaml")
            return True
        except (OSError, ValueError, TypeError):
            return False

    def _check_last(self) -> None:
        """Refuse a `checkpoints/last.pt` that is there but is no file (a folder, a broken
        link): neither continued from nor replaced."""
        last = self.checkpoints.last
        if (last.exists() or last.is_symlink()) and not last.is_file():
            raise ValueError(f"out_dir {self.config.out_dir} holds {last}, which is not a "
                             "checkpoint file (a folder or a broken link); move it away, then "
                             "run again")

    def _saved_run(self, files: list[Path], device: torch.device,
                   ) -> tuple[Path, dict[str, Any] | None, TrainConfig]:
        """The source, checkpoint state (if any) and config of the run that `out_dir` holds."""
        cfg = self.config
        steps = self.checkpoints.list()
        if self.checkpoints.exists() or steps:
            # without last.pt the newest step file holds the same (both are written together)
            source: Path = self.checkpoints.last if self.checkpoints.exists() else steps[-1]
            try:
                state = load_checkpoint(source, map_location=device)
            except CheckpointError as error:
                newest = (f"the newest step checkpoint is {steps[-1].name}: copy it over "
                          f"{source.name} to continue from it, "
                          if steps and source != steps[-1] else "")
                raise CheckpointError(f"cannot continue the run in {cfg.out_dir}: {error}; "
                                      f"{newest}start over with --overwrite "
                                      "(resume='overwrite') or choose another out_dir") from None
            if source != self.checkpoints.last:
                _log.warning("%s is missing: continuing from %s", self.checkpoints.last, source)
            from ..loading import config_from_state  # loading reads configs of this package

            return source, state, config_from_state(state, source, device="auto", resume="auto")
        source = cfg.out_dir / "config.yaml"
        names = ", ".join(str(p.relative_to(cfg.out_dir)) for p in files[:3])
        problem = f"out_dir {cfg.out_dir} holds files of a training run ({names}) without its " \
            "config.yaml or checkpoints/last.pt"
        if source.is_file():
            try:
                return source, None, TrainConfig.from_yaml(source)
            except (TypeError, ValueError) as error:
                problem = f"{source} of the run in out_dir holds an invalid config ({error})"
        raise ValueError(f"{problem}; start over with --overwrite (resume='overwrite') or choose "
                         "another out_dir") from None

    def _check_same_run(self, saved: TrainConfig, step: int) -> None:
        """Refuse to continue a run (at `step`) whose config `saved` differs from this one."""
        cfg = self.config
        diff = config_diff(saved, cfg)
        resume = cfg.resume == "resume"
        if resume and "steps" in diff and cfg.steps >= saved.steps:
            del diff["steps"]
        if diff:
            raise ValueError(
                f"cannot resume the run in {cfg.out_dir} (step {step}): its config differs in "
                f"{describe_diff(diff)}; only a larger steps may differ when resuming (besides "
                "device, progress and the checkpoint settings); start over with --overwrite "
                "(resume='overwrite') or choose another out_dir" if resume else
                f"out_dir {cfg.out_dir} holds another run (step {step}) whose config differs in "
                f"{describe_diff(diff)}; continue it with --resume (resume='resume'; only a larger "
                "steps may differ), start over with --overwrite (resume='overwrite'), or choose "
                "another out_dir")

    def continue_at(self, step: int) -> None:
        """Keep the run's files: `prepare` cuts them back to `step` instead of deleting them."""
        self.removals = []
        self.truncate_to = step

    def prepare(self) -> None:
        """At the start of `fit` (rank 0): delete an overwritten run's files or cut a resumed
        run's logs, checkpoints and figures back to its step; write `config.yaml`."""
        cfg = self.config
        check_run_folder(cfg.out_dir)
        self._check_last()
        if self.removals:
            for path in self.removals:
                path.unlink(missing_ok=True)
            _log.warning("deleted the previous run's %d files in %s (resume='overwrite')",
                         len(self.removals), cfg.out_dir)
            self.removals = []
        self.checkpoints.remove_temporaries()
        if self.truncate_to is not None:
            step = self.truncate_to
            self.log.truncate(step)
            for path in self.checkpoints.list():
                if int(path.stem.split("_")[1]) > step:
                    path.unlink(missing_ok=True)
            for path in (cfg.out_dir / "figures").glob("step_[0-9]*.png"):
                if path.stem.split("_")[1].isdigit() and int(path.stem.split("_")[1]) > step:
                    path.unlink(missing_ok=True)
            self.truncate_to = None
        cfg.out_dir.mkdir(parents=True, exist_ok=True)
        cfg.to_yaml(cfg.out_dir / "config.yaml")
