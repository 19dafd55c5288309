"""Train a depth network (`defocus train`): a `TrainConfig` from a YAML file and overrides, the
run, and the checks of its result."""

from __future__ import annotations

import dataclasses
import inspect
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


def config_fields_help() -> str:
    """One line per `TrainConfig` field: name, default and the `#:` comment above it in the
    source (where the units are written).

    Example:
        >>> config_fields_help().splitlines()[0]
        'TrainConfig fields (--config YAML keys and --set KEY=VALUE):'
    """
    from models.training import TrainConfig

    comments: dict[str, str] = {}
    pending: list[str] = []
    for line in inspect.getsource(TrainConfig).splitlines():
        stripped = line.strip()
        if stripped.startswith("#:"):
            pending.append(stripped[2:].strip())
        elif pending and ":" in stripped:
            comments[stripped.split(":", 1)[0].strip()] = " ".join(pending)
            pending = []
    lines = ["TrainConfig fields (--config YAML keys and --set KEY=VALUE):"]
    for item in dataclasses.fields(TrainConfig):
        if item.default is not dataclasses.MISSING:
            default = item.default
        elif item.default_factory is not dataclasses.MISSING:
            default = item.default_factory()
        else:
            default = "(required)"
        lines.append(f"  {item.name} = {default!s}: {comments.get(item.name, '')}")
    return "\n".join(lines)


def training_config(config: Path | None = None, overrides: Sequence[str] = (),
                    out: Path | None = None, resume: bool = False, overwrite: bool = False,
                    **fields: Any):
    """The `TrainConfig` of a YAML file (or the defaults) with `KEY=VALUE` overrides; `out`
    overrides `out_dir`, `resume`/`overwrite` set how an existing run folder is treated, and
    `fields` (the options `--minutes`, `--learn-optics`, `--optics-lr`: `--` and the field's
    name with dashes) set those fields, where not None.

    Raises:
        FileNotFoundError: `config` is not a file.
        ValueError: an invalid config or override, a key set twice, or `--set out_dir=...`
            with `--out` (`--set resume=...` with `--resume`/`--overwrite`, a field with its
            option): which one was meant is unknown.

    Example:
        >>> training_config(overrides=["out_dir=a"], out=Path("b"))
        Traceback (most recent call last):
        ...
        ValueError: --set out_dir=a and --out b both name the output folder: give only --out
    """
    from models.training import TrainConfig

    if config is not None and not config.is_file():
        raise FileNotFoundError(f"--config {config} does not exist or is not a file")
    keys = {item.partition("=")[0].strip(): item for item in overrides}
    flag = "--resume" if resume else "--overwrite"
    for refused, message in (
            (out and "out_dir" in keys, lambda: f"--set {keys['out_dir']} and --out {out} both "
             "name the output folder: give only --out"),
            ((resume or overwrite) and "resume" in keys, lambda: f"--set {keys['resume']} and "
             f"{flag} both say what to do with an earlier run: give only {flag}"),
            *(((value is not None and key in keys, lambda key=key: f"--set {keys[key]} and "
                f"--{key.replace('_', '-')} both set {key}: give only the option")
               for key, value in fields.items()))):
        if refused:
            raise ValueError(message())
    overrides = list(overrides) + ([f"out_dir={out}"] if out else [])
    overrides += [f"{key}={value!r}" if not isinstance(value, str) else f"{key}={value}"
                  for key, value in fields.items() if value is not None]
    if resume or overwrite:
        overrides.append(f"resume={'resume' if resume else 'overwrite'}")
    return TrainConfig.load(config, overrides)


def check_learned_optics(learn_optics: str, data: str, focus: str | None) -> None:
    """Refuse learning the camera (`learn_optics`, `--learn-optics`) on a dataset `data` whose
    focused images are real photos (`focus`, `--focus`; None: the dataset's own,
    `datasets.registry.focus_of`): they cannot be rendered again through another camera.

    Example:
        >>> check_learned_optics("focus", "dslr", "real")
        Traceback (most recent call last):
        ...
        ValueError: --learn-optics focus: the dslr data's focused images are real photos, which cannot be rendered through a learned camera; learn the optics on synthesised focus (--focus synthesized) or procedural scenes (--data synthetic)
    """
    from datasets.registry import focus_of

    if learn_optics and focus_of(data, focus) == "real":
        raise ValueError(f"--learn-optics {learn_optics}: the {data} data's focused images are "
                         "real photos, which cannot be rendered through a learned camera; learn "
                         "the optics on synthesised focus (--focus synthesized) or procedural "
                         "scenes (--data synthetic)")


def check_out_dir(out_dir: Path, root: Path | None = None, config: Path | None = None,
                  overwrite: bool = False) -> None:
    """Refuse a run folder `out_dir` (`--out`) that cannot hold a run or would write an input,
    before any data is read: a file, a symbolic link, the dataset folder `--root` or a folder
    inside it (`defocus.app.outputs.check_output_folder`), a path below a file, or, with
    `--overwrite` (which deletes the earlier run's files), a folder whose `config.yaml` is the
    `--config` given.

    Example:
        >>> check_out_dir(Path("data"), root=Path("data"))
        Traceback (most recent call last):
        ...
        ValueError: --out data is the input --root data: a run never writes into its input; choose an --out outside it
    """
    from models.training.run_folder import check_run_folder

    from .outputs import check_output_folder

    check_output_folder(out_dir, "--out", {"--root": root})
    check_run_folder(out_dir, "--out")
    if overwrite and config is not None and (Path(out_dir) / "config.yaml").is_file() and \
            (Path(out_dir) / "config.yaml").samefile(config):
        raise ValueError(f"--config {config} is the config.yaml of the run in --out {out_dir}, "
                         "which --overwrite deletes: copy it elsewhere first, or continue the "
                         "run with --resume")


@dataclass
class TrainResult:
    """What `train` did."""

    trainer: Any
    #: metrics on the validation set, when one was given
    metrics: dict[str, float] | None = None
    #: what the user should know (a collapse to the depth limits, ...), each once
    warnings: list[str] = field(default_factory=list)


def train(cfg, train_set, validation: Callable[[], Any] | None = None,
          report: Callable[[str], None] = lambda text: None) -> TrainResult:
    """Train on `train_set` with `cfg` (its depth hints found first where `cfg.hint_weight`
    asks for them, `models.training.hints.attach_hints`); then, on the main process, evaluate
    on `validation()` when given.

    Example:
        >>> result = train(training_config(overrides=["steps=2"]), scenes)  # doctest: +SKIP
    """
    from models.training import COLLAPSE_FRACTION, DataWaitWarning, DepthCollapseWarning, Trainer
    from models.training.hints import attach_hints

    for category in (DepthCollapseWarning, DataWaitWarning):  # in the result's warnings instead
        warnings.simplefilter("ignore", category)
    trainer = Trainer(cfg, attach_hints(train_set, cfg, cfg.progress))
    if trainer.is_main and trainer.resumed_from is not None:
        report(f"continuing the run in {cfg.out_dir} from step {trainer.step} of {cfg.steps}")
    trainer.fit()
    result = TrainResult(trainer)
    if trainer.is_main and validation is not None:
        result.metrics = metrics = trainer.evaluate(validation())
        if metrics["at_depth_limits"] >= COLLAPSE_FRACTION:
            trainer.warnings.append(
                f"{metrics['at_depth_limits']:.0%} of the predicted validation pixels sit at "
                f"depth_min or depth_max: the network collapsed to its depth limits (often a "
                f"too large lr, here {cfg.lr})")
    result.warnings = list(dict.fromkeys(trainer.warnings))
    return result
