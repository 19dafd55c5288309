"""One folder holds one training run: which files are the run's, and what `resume` does with a
folder that already holds one (continue it, refuse another, or delete it when `fit` starts).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .checkpoints import load_checkpoint, to_plain
from .train_config import RUN_CONTROL_KEYS, TrainConfig
from .training_state import config_from_state

_log = logging.getLogger("models.training")


#: the files of a run in `out_dir` besides `checkpoints/*.pt` and `figures/step_*.png`
RUN_FILES = ("config.yaml", "train_log.csv", "val_log.csv", "warnings.log")


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


def config_diff(old: TrainConfig, new: TrainConfig) -> dict[str, tuple[Any, Any]]:
    """`{key: (old value, new value)}` for the keys (not in `RUN_CONTROL_KEYS`) that differ."""
    a, b = to_plain(old.to_dict(), "config"), to_plain(new.to_dict(), "config")
    return {key: (a[key], b[key]) for key in a
            if key not in RUN_CONTROL_KEYS and a[key] != b[key]}


def describe_diff(diff: Mapping[str, tuple[Any, Any]]) -> str:
    """`key (there old, here new), ...` for an error message."""
    return ", ".join(f"{key} (there {old!r}, here {new!r})" for key, (old, new) in diff.items())


class RunFolderMixin:
    """The run-folder methods of `models.training.Trainer`."""

    def _open_run(self) -> None:
        """Apply `config.resume` to what `out_dir` holds: continue, refuse, or plan to delete."""
        cfg = self.config
        files = run_files(cfg.out_dir)
        if cfg.resume == "overwrite":
            self._removals = files
            return
        if not files:
            if cfg.resume == "resume":
                raise ValueError(f"resume='resume' (--resume) but out_dir {cfg.out_dir} holds no "
                                 "run to continue; check the folder, or start a new run without "
                                 "--resume")
            return
        state = None
        if self.checkpoints.exists():
            source: Path = self.checkpoints.last
            state = load_checkpoint(source, map_location=self.device)
            saved = config_from_state(state, source, device="auto", resume="auto")
        elif (cfg.out_dir / "config.yaml").is_file():
            source = cfg.out_dir / "config.yaml"
            try:
                saved = TrainConfig.from_yaml(source)
            except (TypeError, ValueError) as error:
                raise ValueError(f"{source} of the run in out_dir holds an invalid config "
                                 f"({error}); start over with --overwrite (resume='overwrite') "
                                 "or choose another out_dir") from None
        else:
            names = ", ".join(str(p.relative_to(cfg.out_dir)) for p in files[:3])
            raise ValueError(f"out_dir {cfg.out_dir} holds files of a training run ({names}) "
                             "without its config.yaml or checkpoints/last.pt; start over with "
                             "--overwrite (resume='overwrite') or choose another out_dir")
        step = int(state["step"]) if state is not None else 0
        diff = config_diff(saved, cfg)
        if cfg.resume == "resume":
            if "steps" in diff and cfg.steps >= saved.steps:
                del diff["steps"]
            if diff:
                raise ValueError(
                    f"cannot resume the run in {cfg.out_dir} (step {step}): its config differs "
                    f"in {describe_diff(diff)}; only a larger steps may differ when resuming "
                    "(besides device, progress and the checkpoint settings); start over with "
                    "--overwrite (resume='overwrite') or choose another out_dir")
        elif diff:
            raise ValueError(
                f"out_dir {cfg.out_dir} holds another run (step {step}) whose config differs in "
                f"{describe_diff(diff)}; continue it with --resume (resume='resume'; only a larger "
                "steps may differ), start over with --overwrite (resume='overwrite'), or choose "
                "another out_dir")
        if state is not None:
            self.load_state_dict(state)
            self._saved_step = self.step
        self.resumed_from = source
        self._truncate_logs = self.step
        _log.info("continuing the run in %s from step %d", cfg.out_dir, self.step)

    def _prepare_out_dir(self) -> None:
        """At the start of `fit` (rank 0): delete an overwritten run's files or cut a resumed
        run's logs, checkpoints and figures back to its step; write `config.yaml`."""
        cfg = self.config
        if self._removals:
            for path in self._removals:
                path.unlink(missing_ok=True)
            _log.warning("deleted the previous run's %d files in %s (resume='overwrite')",
                         len(self._removals), cfg.out_dir)
            self._removals = []
        self.checkpoints.remove_temporaries()
        if self._truncate_logs is not None:
            step = self._truncate_logs
            self.log.truncate(step)
            for path in self.checkpoints.list():
                if int(path.stem.split("_")[1]) > step:
                    path.unlink(missing_ok=True)
            for path in (cfg.out_dir / "figures").glob("step_[0-9]*.png"):
                if path.stem.split("_")[1].isdigit() and int(path.stem.split("_")[1]) > step:
                    path.unlink(missing_ok=True)
            self._truncate_logs = None
        cfg.out_dir.mkdir(parents=True, exist_ok=True)
        cfg.to_yaml(cfg.out_dir / "config.yaml")
