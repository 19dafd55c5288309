"""Training: a config, a trainer with exact resume, CSV logs, figures and DDP.

`Trainer` takes any map-style `torch.utils.data.Dataset` (or any iterable) of samples in the
sample format (see the datasets tutorial). With `supervision="self"` (default) the loss never
sees depth labels: the predicted depth is rendered through each focused image's camera
(`optics.render_focal_stack` with the sample's `CameraSettings`) and compared with the real focused image
(`models.losses.DefocusLoss`). `supervision="depth"` trains on the ground truth instead
(a baseline).

Reproducibility: the batch of step `k` is drawn from a permutation seeded by `(seed, epoch)`,
so a run resumed from a checkpoint sees the same batches and gives the same losses as an
uninterrupted run. Launched with `torchrun --nproc_per_node=N`, training is data parallel (DDP;
gloo on CPU, NCCL on GPU): `batch_size` is per process, every process holds the same weights
after each step, and only rank 0 writes files.

Files under `out_dir`: `config.yaml`, `train_log.csv` (step, losses, learning rate,
seconds), `val_log.csv` (validation metrics), `checkpoints/last.pt` (and `step_XXXXXX.pt`),
`figures/step_XXXXXX.png`.

The pieces: `models.sampling` (the batches of each step, flips), `models.checkpoints` (checkpoint
files that open without running code, `CheckpointStore`), `models.run_log` (CSV logs) and
`models.plotting` (figures); `Trainer` runs the loop. Checkpoints hold only tensors and plain
data and are read with `torch.load(..., weights_only=True)`: a file holding anything else is
refused with `CheckpointError` (see `docs/security.md`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
import yaml
from torch import Tensor, nn
from torch.utils.data import default_collate

from optics import CameraSettings, parse_aperture

from .checkpoints import (
    CHECKPOINT_FORMAT,
    CheckpointError,
    CheckpointStore,
    load_checkpoint,
    save_checkpoint,
    to_plain,
)
from .losses import DefocusLoss, supervised_depth_loss
from .metrics import METRIC_NAMES, depth_metrics
from .networks import INPUT_MODES, NETWORKS, build_network
from .plotting import plot_prediction
from .run_log import RunLog
from .sampling import StepSampler, random_flip

SUPERVISIONS = ("self", "depth")


@dataclass
class TrainConfig:
    """Everything a training run depends on (lengths in metres).

    Load from YAML with `from_yaml`, change fields with `override`
    (`["steps=100", "lr=3e-4"]`), save with `to_yaml`.

    Example:
        >>> cfg = TrainConfig(steps=10).override(["lr=3e-4", "input_mode=aif"])
        >>> cfg.steps, cfg.lr, cfg.input_mode
        (10, 0.0003, 'aif')
    """

    #: optimisation steps
    steps: int = 300
    #: samples per step and per process
    batch_size: int = 8
    #: Adam learning rate (the paper: 2e-5 for its large network)
    lr: float = 1e-3
    #: "small" (CPU encoder-decoder) or "paper" (ResNet-50 + dense ASPP + attention + DeepLabV3+)
    network: str = "small"
    #: "aif+focused" (depth from defocus at test time) or "aif" (monocular at test time)
    input_mode: str = "aif+focused"
    #: "self" (rendered vs real focused images, no depth labels) or "depth" (supervised baseline)
    supervision: str = "self"
    #: output folder (logs, checkpoints, figures)
    out_dir: Path = Path("runs/train")
    #: random seed (weights, batch order)
    seed: int = 0
    #: nearest depth the network can output, metres
    depth_min: float = 1.0
    #: farthest depth the network can output, metres
    depth_max: float = 10.0
    #: focused images per sample
    n_focus: int = 2
    #: first-scale channels of the small network
    width: int = 32
    #: AdamW weight decay
    weight_decay: float = 0.0
    #: "cosine" (decay to 0 over steps) or "constant"
    lr_schedule: str = "cosine"
    #: gradient-norm clipping (0: off)
    grad_clip: float = 1.0
    #: SSIM share of the photometric loss
    ssim_weight: float = 0.85
    #: weight of the sharpness-map L1 term
    sharpness_weight: float = 0.1
    #: weight of the edge-aware depth smoothness
    smoothness_weight: float = 0.001
    #: SSIM window width, pixels
    ssim_window: int = 7
    #: PSF used to render in the loss, a spec of optics.aperture_spec: "gaussian" (sigma = CoC/2),
    #: "gaussian:S", "disk", "polygon:N"
    aperture: str = "gaussian"
    #: renderer semantics: "scatter", "gather" or "layered"
    render_mode: str = "scatter"
    #: largest PSF window, pixels
    max_kernel_size: int = 63
    #: random horizontal flips of the training samples
    flip: bool = True
    #: write a train_log.csv row every this many steps
    log_every: int = 1
    #: save a checkpoint every this many steps (0: only at the end)
    checkpoint_every: int = 0
    #: keep only the newest this many step_XXXXXX.pt checkpoints (0: keep all; last.pt is kept)
    keep_checkpoints: int = 0
    #: evaluate on the validation set every this many steps (0: only at the end)
    val_every: int = 0
    #: write a figure every this many steps (0: only at the end)
    figure_every: int = 0
    #: continue from out_dir/checkpoints/last.pt when it exists
    resume: bool = True
    #: "auto" (CUDA when available), "cpu", "cuda", ...
    device: str = "auto"
    #: tqdm progress bar
    progress: bool = True
    #: extra keys for your own code (kept in config.yaml)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        choices = {"network": tuple(NETWORKS), "input_mode": INPUT_MODES,
                   "supervision": SUPERVISIONS,
                   "lr_schedule": ("cosine", "constant")}
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        parse_aperture(self.aperture)
        for name in ("steps", "batch_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if not 0 < self.depth_min < self.depth_max:
            raise ValueError(f"need 0 < depth_min < depth_max metres, got {self.depth_min!r} "
                             f"and {self.depth_max!r}")
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr!r}")

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["out_dir"] = str(self.out_dir)
        return data

    def to_yaml(self, path: str | Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown config keys {unknown}; allowed: {sorted(known)}")
        return cls(**{k: _coerce(cls, k, v) for k, v in data.items()})

    @classmethod
    def from_yaml(cls, path: str | Path) -> TrainConfig:
        """Load a config from a YAML mapping of field names to values."""
        data = yaml.safe_load(Path(path).read_text()) or {}
        if not isinstance(data, Mapping):
            raise ValueError(f"{path} must hold a YAML mapping of config keys, got {type(data)}")
        return cls.from_dict(data)

    def override(self, assignments: Sequence[str]) -> TrainConfig:
        """A copy with `key=value` assignments applied (values parsed as YAML)."""
        data = self.to_dict()
        for item in assignments:
            key, sep, value = item.partition("=")
            if not sep:
                raise ValueError(f"overrides must look like key=value, got {item!r}")
            data[key.strip()] = yaml.safe_load(value)
        return TrainConfig.from_dict(data)


def _coerce(cls: type, name: str, value: Any) -> Any:
    """Convert a YAML value to the type of field `name`."""
    kind = {f.name: f.type for f in dataclasses.fields(cls)}.get(name)
    kind = kind if isinstance(kind, str) else getattr(kind, "__name__", "")
    try:
        if kind == "int":
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(value)
        if kind == "float":
            return float(value)
        if kind == "bool":
            if not isinstance(value, bool):
                raise ValueError
            return value
        if kind == "Path":
            return Path(value)
        if kind == "str":
            return str(value)
    except (TypeError, ValueError):
        raise ValueError(f"config key {name} must be of type {kind}, got {value!r}") from None
    return value


def _distributed() -> tuple[int, int]:
    """(rank, world size), initialising the process group under `torchrun`."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend)
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _select_device(name: str) -> torch.device:
    """`name`, or for `"auto"` this process's GPU when CUDA is available, else the CPU."""
    if name == "auto":
        available = torch.cuda.is_available()
        name = f"cuda:{int(os.environ.get('LOCAL_RANK', 0))}" if available else "cpu"
    return torch.device(name)


def _build_scheduler(optimizer: torch.optim.Optimizer,
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


class Trainer:
    """Trains a depth network on samples in the sample format.

    The loop lives here; the batches of each step come from `models.sampling.StepSampler`,
    checkpoints go to a `models.checkpoints.CheckpointStore`, CSV logs to a
    `models.run_log.RunLog` and figures through `models.plotting.plot_prediction`.

    Args:
        config: the `TrainConfig`.
        train_set: a map-style dataset (exactly reproducible batches) or any iterable of samples.
        val_set: optional samples to evaluate on at `val_every` and at the end.
        step_callback: optional `f(trainer, step, losses)` called after every step (hooks,
            tests).

    Raises:
        CheckpointError: `out_dir/checkpoints/last.pt` exists (and `config.resume`) but is not
            a checkpoint or holds more than tensors and plain data (it is not run).

    Example:
        >>> samples = [{"image": torch.rand(3, 8, 8), "depth": torch.full((1, 8, 8), 2.0),
        ...             "mask": torch.ones(1, 8, 8, dtype=torch.bool)}] * 2
        >>> import tempfile
        >>> cfg = TrainConfig(steps=2, batch_size=2, input_mode="aif", supervision="depth",
        ...                   width=4, progress=False, out_dir=tempfile.mkdtemp())
        >>> trainer = Trainer(cfg, samples)
        >>> len(trainer.fit())
        2
    """

    def __init__(self, config: TrainConfig, train_set: Iterable[Mapping[str, Any]],
                 val_set: Iterable[Mapping[str, Any]] | None = None,
                 step_callback: Callable[[Trainer, int, dict[str, float]], None] | None = None):
        self.config = cfg = config
        to_plain(cfg.to_dict(), "config")  # a config that a checkpoint cannot hold fails now
        self.train_set, self.val_set = train_set, val_set
        self.step_callback = step_callback
        self.rank, self.world_size = _distributed()
        self.is_main = self.rank == 0
        self.device = _select_device(cfg.device)
        torch.manual_seed(cfg.seed)
        self.model = build_network(cfg.network, cfg.input_mode, cfg.n_focus, cfg.depth_min,
                                   cfg.depth_max, cfg.width).to(self.device)
        self.ddp_model: nn.Module = self.model
        if self.world_size > 1:
            ids = [self.device.index] if self.device.type == "cuda" else None
            self.ddp_model = nn.parallel.DistributedDataParallel(self.model, device_ids=ids)
        self.optimizer = torch.optim.AdamW(self.model.parameters(), lr=cfg.lr,
                                           weight_decay=cfg.weight_decay)
        self.scheduler = _build_scheduler(self.optimizer, cfg)
        self.loss_fn = DefocusLoss(cfg.ssim_weight, cfg.sharpness_weight, cfg.smoothness_weight,
                                   cfg.ssim_window, parse_aperture(cfg.aperture),
                                   mode=cfg.render_mode, max_kernel_size=cfg.max_kernel_size)
        self.sampler = StepSampler(train_set, cfg.batch_size, cfg.seed, self.rank,
                                   self.world_size)
        self.checkpoints = CheckpointStore(cfg.out_dir / "checkpoints", keep=cfg.keep_checkpoints)
        self.log = RunLog(cfg.out_dir)
        self.step = 0
        self.history: list[dict[str, float]] = []
        if cfg.resume and self.checkpoints.exists():
            self.load_checkpoint(self.checkpoints.last)

    @property
    def checkpoint_dir(self) -> Path:
        """The folder of `last.pt` and the step checkpoints."""
        return self.checkpoints.directory

    def _indices(self, step: int) -> list[int]:
        """Dataset indices of this process's part of the batch of `step` (0-based)."""
        return self.sampler.indices(step)

    # -- model -----------------------------------------------------------------------------
    def predict(self, image: Tensor, focused: Tensor | None = None,
                settings: CameraSettings | None = None) -> Tensor:
        """Depth `(B,1,H,W)` metres for a batch (`focused` `(B,F,3,H,W)` and their
        `(B,F)` or `(F,)` `CameraSettings` in `"aif+focused"` mode), without gradients."""
        was_training = self.model.training
        self.model.eval()
        with torch.no_grad():
            image = image.to(self.device)
            if self.config.input_mode == "aif":
                depth = self.model(image)
            else:
                depth = self.model(image, focused.to(self.device), to_device(settings, self.device))
        self.model.train(was_training)
        return depth

    def _forward(self, batch: Mapping[str, Any]) -> dict[str, Tensor]:
        image = batch["image"]
        if self.config.input_mode == "aif":
            depth = self.ddp_model(image)
        else:
            depth = self.ddp_model(image, batch["focused"], batch["camera"])
        if self.config.supervision == "self":
            return self.loss_fn(depth, image, batch["focused"], batch["camera"])
        return {"loss": supervised_depth_loss(depth, batch["depth"], batch.get("mask"))}

    def train_step(self, batch: Mapping[str, Any]) -> dict[str, float]:
        """One optimisation step on a collated batch; returns the losses (mean over processes)."""
        self.model.train()
        terms = self._forward(batch)
        if not bool(torch.isfinite(terms["loss"])):
            raise FloatingPointError(f"loss is not finite at step {self.step + 1}: "
                                     f"{ {k: float(v.detach()) for k, v in terms.items()} }")
        self.optimizer.zero_grad(set_to_none=True)
        terms["loss"].backward()
        if self.config.grad_clip > 0:
            nn.utils.clip_grad_norm_(self.model.parameters(), self.config.grad_clip)
        self.optimizer.step()
        self.scheduler.step()
        values = torch.stack([v.detach() for v in terms.values()])
        if self.world_size > 1:
            dist.all_reduce(values)
            values = values / self.world_size
        return dict(zip(terms, values.tolist(), strict=True))

    # -- loop ------------------------------------------------------------------------------
    def fit(self, until: int | None = None) -> list[dict[str, float]]:
        """Train from the current step to `until` (default `config.steps`); returns the
        history of logged losses (one dict per step of this run and of resumed runs)."""
        from tqdm.auto import tqdm

        cfg = self.config
        until = cfg.steps if until is None else min(int(until), cfg.steps)
        if self.is_main:
            cfg.out_dir.mkdir(parents=True, exist_ok=True)
            cfg.to_yaml(cfg.out_dir / "config.yaml")
        bar = tqdm(total=until, initial=self.step, desc="train", unit="step",
                   disable=not (cfg.progress and self.is_main))
        started = time.perf_counter()
        while self.step < until:
            losses = self._advance(until, started)
            bar.set_postfix(loss=f"{losses['loss']:.4f}")
            bar.update(1)
            if self.step_callback is not None:
                self.step_callback(self, self.step, losses)
            self._periodic_tasks()
        bar.close()
        if self.val_set is not None and not (cfg.val_every and self.step % cfg.val_every == 0):
            self._validate()
        self.save_figure()
        self.save_checkpoint()
        return self.history

    def _advance(self, until: int, started: float) -> dict[str, float]:
        """Train one step on this step's batch, record it in the history and the train log."""
        batch = to_device(default_collate(self.sampler.samples(self.step)), self.device)
        if self.config.flip:
            batch = random_flip(batch, self.config.seed, self.step, self.rank)
        losses = self.train_step(batch)
        self.step += 1
        row = {"step": self.step, **losses, "lr": self.scheduler.get_last_lr()[0],
               "seconds": time.perf_counter() - started}
        self.history.append(row)
        if self.is_main and (self.step % self.config.log_every == 0 or self.step == until):
            self.log.train.append(row)
        return losses

    def _periodic_tasks(self) -> None:
        """Validation, figure and checkpoint when the step is a multiple of their period."""
        cfg = self.config
        if self.val_set is not None and cfg.val_every and self.step % cfg.val_every == 0:
            self._validate()
        if cfg.figure_every and self.step % cfg.figure_every == 0:
            self.save_figure()
        if cfg.checkpoint_every and self.step % cfg.checkpoint_every == 0:
            self.save_checkpoint()

    # -- evaluation --------------------------------------------------------------------------
    def evaluate(self, test_set: Iterable[Mapping[str, Any]], depth_cap: float | None = None,
                 crop: str | Sequence[float] | None = None, median_scaling: bool = False,
                 min_depth: float = 1e-3) -> dict[str, float]:
        """Mean per-image metrics (`models.metrics.METRIC_NAMES`) over `test_set`.

        Args:
            test_set: samples with `image`, `depth` (and `mask`; `focused` and `camera`
                in `"aif+focused"` mode), unbatched.
            depth_cap: ignore ground truth beyond this (metres) and clamp predictions to it.
            crop: `None`, `"garg"`, `"eigen"` or `(top, bottom, left, right)` fractions.
            median_scaling: scale predictions by the median ratio (adds `median_scale`).
            min_depth: ignore ground truth at or below this (metres).
        """
        totals: dict[str, float] = {}
        count = 0
        for sample in test_set:
            batch = default_collate([sample])
            depth = self.predict(batch["image"], batch.get("focused"), batch.get("camera"))
            metrics = depth_metrics(pred=depth.cpu(), target=batch["depth"],
                                    mask=batch.get("mask"), min_depth=min_depth,
                                    max_depth=depth_cap, crop=crop,
                                    median_scaling=median_scaling)
            for key, value in metrics.items():
                totals[key] = totals.get(key, 0.0) + value
            count += 1
        if count == 0:
            raise ValueError("test_set holds no samples")
        return {key: value / count for key, value in totals.items()}

    def _validate(self) -> None:
        metrics = self.evaluate(self.val_set)
        if self.is_main:
            self.log.val.append({"step": self.step, **metrics})

    # -- figures -----------------------------------------------------------------------------
    def _figure_sample(self) -> Mapping[str, Any]:
        source = self.val_set if self.val_set is not None else self.train_set
        if hasattr(source, "__getitem__"):
            return source[0]
        return next(iter(source))

    def save_figure(self, path: str | Path | None = None) -> Path | None:
        """Plot the prediction on the first validation (else training) sample (rank 0 only)."""
        if not self.is_main:
            return None
        sample = self._figure_sample()
        batch = default_collate([sample])
        depth = self.predict(batch["image"], batch.get("focused"), batch.get("camera"))
        path = path or self.config.out_dir / "figures" / f"step_{self.step:06d}.png"
        return plot_prediction(path, sample["image"], depth[0], sample.get("focused"),
                               sample.get("depth"), sample.get("mask"),
                               title=f"{sample.get('id', '')} step {self.step}",
                               depth_range=(self.config.depth_min, self.config.depth_max))

    # -- checkpoints -------------------------------------------------------------------------
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
            return save_checkpoint(self.state_dict(), path)
        return self.checkpoints.save(self.state_dict(), self.step)

    @classmethod
    def from_checkpoint(cls, path: str | Path, train_set: Iterable[Mapping[str, Any]] = (),
                        device: str = "auto") -> Trainer:
        """A trainer holding a checkpoint's config and weights (for evaluation and prediction).

        Raises:
            CheckpointError: the file is not a checkpoint or holds more than tensors and plain
                data (refused without running anything).
        """
        state = load_checkpoint(path)
        cfg = _config_from(state, path, resume=False, progress=False, device=device)
        trainer = cls(cfg, train_set)
        trainer.load_state_dict(state)
        return trainer

    def load_checkpoint(self, path: str | Path, restore_logs: bool = True) -> None:
        """Restore a checkpoint written by `save_checkpoint` (exact resume); with
        `restore_logs` the CSV logs are cut back to the checkpoint's step.

        Raises:
            CheckpointError: the file is not a checkpoint or holds more than tensors and plain
                data (refused without running anything).
        """
        self.load_state_dict(load_checkpoint(path, map_location=self.device))
        if self.is_main and restore_logs:
            self.log.truncate(self.step)


def _config_from(state: Mapping[str, Any], path: str | Path, **changes: Any) -> TrainConfig:
    """The `TrainConfig` of a loaded checkpoint, with `changes`; a bad one is a
    `CheckpointError` naming the file."""
    try:
        return TrainConfig.from_dict({**state["config"], **changes})
    except (TypeError, ValueError) as error:
        raise CheckpointError(f"checkpoint {path} holds an invalid config: {error}") from None


def load_model(checkpoint: str | Path, device: str | torch.device = "cpu") -> tuple[nn.Module,
                                                                                     TrainConfig]:
    """The trained network (in eval mode) and its config from a checkpoint file.

    Raises:
        CheckpointError: the file is not a checkpoint or holds more than tensors and plain data
            (refused without running anything).
    """
    state = load_checkpoint(checkpoint, map_location=device)
    cfg = _config_from(state, checkpoint)
    model = build_network(cfg.network, cfg.input_mode, cfg.n_focus, cfg.depth_min, cfg.depth_max,
                          cfg.width)
    model.load_state_dict(state["model"])
    return model.to(device).eval(), cfg


__all__ = ["METRIC_NAMES", "CheckpointError", "TrainConfig", "Trainer", "load_model",
           "to_device"]
