"""The training loop: `Trainer`, composed of the helpers of `models.training` (a `RunFolder`, a
`Checkpointer`, a `SignalGuard` and a `SampleChecker`), and the depth-collapse warning.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor, nn
from torch.profiler import record_function

from optics import CameraSettings, collate, parse_aperture
from optics.checks import values_checked

from ..checkpoints import (
    CHECKPOINT_FORMAT,
    CheckpointStore,
    load_checkpoint,
    restore_weights,
    to_plain,
)
from ..depth_from_photos.tiling import run_network
from ..devices import select_device
from ..evaluation import evaluate_network
from ..losses import DefocusLoss
from ..metrics import at_depth_limits
from ..plotting import figure_title, plot_prediction
from . import learned_camera as learned
from .batches import BatchStream, auto_workers
from .checkpointing import Checkpointer
from .config import TrainConfig
from .forward import NetworkAndLoss
from .interruption import SignalGuard, TrainingInterrupted
from .run_folder import RunFolder
from .run_log import RunLog
from .run_warnings import (
    LIMIT_TOLERANCE,
    DepthCollapseWarning,
    RunWarnings,
    check_finite_step,
    collapse_message,
)
from .sample_checks import EMPTY, SampleChecker, TestSampleChecker
from .sampling import StepSampler, random_flip
from .state import Progress, build_scheduler, process_rank, rng_state, set_rng_state, to_device
from .step_timing import DataWaitWarning, StepTimer

_log = logging.getLogger("models.training")


class Trainer:
    """Trains a depth network on samples in the sample format.

    The loop lives here and owns the model, optimiser, schedule, `step`, `history` and
    `warnings`; the rest is composed: the batches of each step come from a
    `models.training.sampling.StepSampler` (`sampler`), the run's folder is a
    `models.training.run_folder.RunFolder` (`run_folder`), checkpoints are written by a
    `models.training.checkpointing.Checkpointer` (`checkpointer`) into a
    `models.checkpoints.CheckpointStore` (`checkpoints`), signals are caught by a
    `models.training.interruption.SignalGuard` (`signals`), samples are checked by a
    `models.training.sample_checks.SampleChecker` (`sample_checks`), CSV logs go to a
    `models.training.run_log.RunLog` (`log`) and figures through `models.plotting.plot_prediction`.

    One run per `out_dir`: what happens when the folder already holds a run follows
    `config.resume` ("auto": continue the same run, refuse another; "resume": continue, also
    with a larger `steps`; "overwrite": delete the old run's files when `fit` starts). A
    resumed run continues from `checkpoints/last.pt` with its logs cut back to that step.

    `fit` saves checkpoints every `checkpoint_every` steps and `checkpoint_minutes` minutes, at
    the end, when a step fails (the last completed step) and on SIGINT or SIGTERM (after the
    step under way; then it raises `TrainingInterrupted`). It stops with `FloatingPointError`
    at the first non-finite loss or gradient, before the weights change, and never saves
    non-finite weights. When most predicted pixels sit at `depth_min` or `depth_max` at the
    end, it warns (`DepthCollapseWarning`, `Trainer.warnings`, `warnings.log`).

    Args:
        config: the `TrainConfig`.
        train_set: a map-style dataset (exactly reproducible batches) or any iterable of samples.
        val_set: optional samples to evaluate on at `val_every` and at the end.
        step_callback: optional `f(trainer, step, losses)` called after every step (hooks,
            tests).
        camera: the samples' `camera_record` where `train_set` has none (`from_checkpoint`).

    Raises:
        ValueError: `out_dir` holds another run (the message names the config keys that
            differ), `resume="resume"` without a run to continue, or samples that do not fit
            the config (`n_focus`, missing keys).
        CheckpointError: `out_dir/checkpoints/last.pt` is to be resumed but is not a checkpoint
            or holds more than tensors and plain data (it is not run).

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
                 step_callback: Callable[[Trainer, int, dict[str, float]], None] | None = None,
                 camera: Mapping[str, Sequence[float]] | None = None):
        to_plain(config.to_dict(), "config")  # a config that a checkpoint cannot hold fails now
        self.train_set, self.val_set = train_set, val_set
        self.step_callback = step_callback
        self.rank, self.world_size = process_rank()
        self.is_main = self.rank == 0
        self.sampler = StepSampler(train_set, config.batch_size, config.seed, self.rank,
                                   self.world_size)
        self.sample_checks = SampleChecker(config, self.sampler)
        #: the run's config, its `n_focus` taken from the data when it was 0
        self.config = cfg = self.sample_checks.fit_first_sample()
        self.device = select_device(cfg.device)
        torch.manual_seed(cfg.seed)
        self.model = cfg.build_network().to(self.device)
        self.ddp_model: nn.Module = self.model
        if self.world_size > 1:
            ids = [self.device.index] if self.device.type == "cuda" else None
            self.ddp_model = nn.parallel.DistributedDataParallel(self.model, device_ids=ids)
        #: processes preparing batches ahead of the step (`config.workers`, resolved)
        self.workers = auto_workers(self.device) if cfg.workers < 0 else cfg.workers
        self.step_timer = StepTimer()
        #: the host seconds of the phases of the last step (`step_timing.PHASES`)
        self.phases: dict[str, float] = {}
        #: the camera learned with the network (`config.learn_optics`), None when it is fixed
        self.camera = learned.build_learned_camera(cfg, self.sample_checks.camera or camera,
                                                   self.device)
        #: the learned mask the photos are rendered through (None: their settings' PSF)
        self.learned_aperture = None if self.camera is None else self.camera.aperture
        self.optimizer = torch.optim.AdamW(  # on a GPU: one fused kernel for every tensor
            learned.param_groups(self.model, self.camera, cfg), lr=cfg.lr,
            weight_decay=cfg.weight_decay,
            fused=True if self.device.type == "cuda" else None)
        self.progress = Progress(cfg.steps, cfg.minutes)  # what the learning rate follows
        self.scheduler = build_scheduler(self.optimizer, cfg, self.progress)
        self.loss_fn = DefocusLoss(cfg.ssim_weight, cfg.sharpness_weight, cfg.smoothness_weight,
                                   cfg.ssim_window, parse_aperture(cfg.aperture) if self.camera
                                   is None else self.camera.aperture,  # a learned mask too (.to)
                                   cfg.hint_weight, cfg.hint_gate, mode=cfg.render_mode,
                                   max_kernel_size=cfg.max_kernel_size).to(self.device)
        #: the step's network and loss (one compiled graph when `config.compile`)
        self.forward = NetworkAndLoss(cfg, self.ddp_model, self.loss_fn, self.device,
                                      self.camera)
        self.checkpoints = CheckpointStore(cfg.out_dir / "checkpoints", keep=cfg.keep_checkpoints)
        self.log = RunLog(cfg.out_dir)
        self.checkpointer = Checkpointer(self.checkpoints, self.is_main)
        self.run_folder = RunFolder(cfg, self.checkpoints, self.log)
        self.signals = SignalGuard(self.world_size, self.device)
        self.step = 0
        self.history: list[dict[str, float]] = []
        self.run_warnings = RunWarnings(cfg.out_dir, self.is_main)
        #: the checkpoint (or config.yaml) of the run this trainer continues, if any
        self.resumed_from: Path | None = None
        self.last_validation: dict[str, float] | None = None
        #: whether the last `fit` stopped before its last step because `config.minutes` was spent
        self.out_of_time = False
        self._open_run()

    @property
    def checkpoint_dir(self) -> Path:
        """The folder of `last.pt` and the step checkpoints."""
        return self.checkpoints.directory

    def _stop_requested(self) -> int:
        """The signal that asks to stop (0: none), agreed by all processes."""
        return self.signals.requested()

    def _open_run(self) -> None:
        """Continue the run that `out_dir` holds, if `config.resume` says so."""
        run = self.run_folder.open(self.device)
        if run is None:
            return
        if run.state is not None:
            self.load_state_dict(run.state, run.source)
            self.checkpointer.saved_step = self.step
        self.resumed_from = run.source
        self.run_folder.continue_at(self.step)
        _log.info("continuing the run in %s from step %d", self.config.out_dir, self.step)

    # -- model -----------------------------------------------------------------------------
    def predict(self, image: Tensor, focused: Tensor | None = None,
                settings: CameraSettings | None = None) -> Tensor:
        """Depth `(B,1,H,W)` metres for a batch (`focused` `(B,F,3,H,W)` and their
        `(B,F)` or `(F,)` `CameraSettings` in `"aif+focused"` mode), without gradients
        (`models.depth_from_photos.tiling.run_network`)."""
        return run_network(self.model, image.to(self.device), to_device(focused, self.device),
                           to_device(settings, self.device), aperture=self.learned_aperture)

    def at_depth_limits(self, depth: Tensor) -> Tensor:
        """The share of the pixels of `depth` at `depth_min` or `depth_max` (within
        `LIMIT_TOLERANCE` of the range), a 0-d tensor."""
        return at_depth_limits(depth, self.config.depth_min, self.config.depth_max,
                               LIMIT_TOLERANCE)

    def train_step(self, batch: Mapping[str, Any]) -> dict[str, float]:
        """One optimisation step on a collated batch; returns the losses (mean over processes)
        and `at_depth_limits` (the share of predicted pixels at a depth limit).

        Raises:
            FloatingPointError: the loss or the gradient is not finite (the weights are left
                as they were).
        """
        self.model.train()
        with values_checked():  # checked on the host where prepared; the loss checked below
            depth, terms = self.forward(batch)
        self.optimizer.zero_grad(set_to_none=True)
        backward = time.perf_counter()
        with record_function("backward"):
            terms["loss"].backward()
        self.phases = {**self.forward.phases, "backward": time.perf_counter() - backward}
        params = [p for p in self.model.parameters() if p.grad is not None]
        if self.config.grad_clip > 0:
            norm = nn.utils.clip_grad_norm_(params, self.config.grad_clip)
        else:
            norm = torch.linalg.vector_norm(torch.stack([p.grad.norm() for p in params]))
        norm = learned.optics_gradients(self.camera, norm, self.config.grad_clip, self.world_size)
        values = torch.stack([v.detach().float() for v in terms.values()]
                             + [self.at_depth_limits(depth), norm.detach().float()])
        if self.world_size > 1:
            dist.all_reduce(values)
            values = values / self.world_size
        *numbers, grad_norm = values.tolist()  # the step's one wait for the device
        losses = dict(zip([*terms, "at_depth_limits"], numbers, strict=True))
        check_finite_step(losses, grad_norm, self.step + 1, self.config.lr)
        self.checkpointer.in_update = True  # until the step is counted: no half-step checkpoint
        optimizing = time.perf_counter()
        with record_function("optimizer"):
            self.optimizer.step()
            self.scheduler.step()
        self.phases["optimizer"] = time.perf_counter() - optimizing
        return losses

    # -- loop ------------------------------------------------------------------------------
    def fit(self, until: int | None = None) -> list[dict[str, float]]:
        """Train from the current step to `until` (default `config.steps`), or until the time
        budget `config.minutes` is spent (then `out_of_time` is set; the checkpoint, figure and
        validation follow as at the end); returns the history of logged losses (one dict per
        step of this run and of resumed runs).

        Raises:
            ValueError: `train_set` holds no samples, or a sample has ground-truth depth that
                is not finite and > 0 where its mask is valid (named by its id).
            FloatingPointError: a non-finite loss or gradient (the last good step is saved).
            TrainingInterrupted: SIGINT or SIGTERM arrived (the last step is saved).
        """
        from optics.progress import progress_bar

        cfg = self.config
        if self.sampler.is_map_style() and len(self.train_set) == 0:
            raise ValueError(EMPTY)
        until = cfg.steps if until is None else min(int(until), cfg.steps)
        self.run_warnings = RunWarnings(cfg.out_dir, self.is_main)
        if self.is_main:
            self.run_folder.prepare()
        bar = progress_bar(total=until, initial=self.step, desc="train", unit="step",
                           disable=not (cfg.progress and self.is_main))
        started = time.perf_counter()
        self.progress.start()
        self.out_of_time = False
        self.checkpointer.restart_clock()
        self.step_timer = StepTimer()
        check = self.sample_checks.check_depth \
            if cfg.supervision == "depth" or cfg.learn_optics else None
        batches = BatchStream(self.sampler, self.step, until, self.device, self.workers,
                              check=check)
        try:
            with self.signals.caught(), batches:
                while self.step < until:
                    losses = self._advance(batches, until, started)
                    bar.set_postfix(loss=f"{losses['loss']:.4f}",
                                    data=f"{self.step_timer.share(last=20) or 0:.0%}",
                                    refresh=False)
                    bar.update(1)
                    if self.step_callback is not None:
                        self.step_callback(self, self.step, losses)
                    self._periodic_tasks()
                    self._stop_if_asked()
                    if self.progress.time_spent:  # read at this step's update
                        self.out_of_time = self.step < until
                        break
            self._stop_if_asked()  # a signal after the last step's check: not swallowed
        except TrainingInterrupted:
            raise
        except BaseException:
            self.checkpointer.save_after_failure(self.state_dict, self.step)
            raise
        finally:
            bar.close()
        if self.val_set is not None and not (cfg.val_every and self.step % cfg.val_every == 0):
            self._validate()
        self.save_figure()
        self._save_once()
        self._check_collapse()
        return self.history

    def _advance(self, batches: BatchStream, until: int, started: float) -> dict[str, float]:
        """Train one step on this step's batch, record it in the history and the train log."""
        self.checkpointer.start_step()
        with record_function("data"):
            batch, data_s = next(batches)
        if self.config.flip:
            batch = random_flip(batch, self.config.seed, self.step, self.rank)
        computing = time.perf_counter()
        losses = self.train_step(batch)
        compute_s = time.perf_counter() - computing
        self.step += 1
        self.step_timer.add(data_s, compute_s, self.phases)
        terms = {k: v for k, v in losses.items() if k != "at_depth_limits"}
        row = {"step": self.step, **terms, "lr": self.scheduler.get_last_lr()[0],
               "seconds": time.perf_counter() - started,
               "at_depth_limits": losses["at_depth_limits"], "data_s": data_s,
               "compute_s": compute_s,
               **{f"{name.replace(' ', '_')}_s": s for name, s in self.phases.items()},
               **({} if self.camera is None else learned.log_columns(self.camera))}
        self.history.append(row)
        self.checkpointer.in_update = False
        if self.is_main and (self.step % self.config.log_every == 0 or self.step == until):
            self.log.train.append(row)
        self._check_data_wait()
        return losses

    def _periodic_tasks(self) -> None:
        """Validation, figure and checkpoint when the step is a multiple of their period (or,
        for checkpoints, `checkpoint_minutes` passed)."""
        cfg = self.config
        if self.val_set is not None and cfg.val_every and self.step % cfg.val_every == 0:
            self._validate()
        if cfg.figure_every and self.step % cfg.figure_every == 0:
            self.save_figure()
        if self.checkpointer.due(self.step, cfg.checkpoint_every, cfg.checkpoint_minutes):
            self._save_once()

    def _stop_if_asked(self) -> None:
        """Save and raise `TrainingInterrupted` when a signal asked the run to stop."""
        signum = self._stop_requested()
        if signum:
            raise TrainingInterrupted(signum, self.step, self._save_once())

    @property
    def warnings(self) -> list[str]:
        """The warnings of the last `fit` (also in `out_dir/warnings.log`)."""
        return self.run_warnings.messages

    def _check_collapse(self) -> None:
        """Warn when most predicted pixels sit at a depth limit (validation, else the last
        training batch)."""
        cfg = self.config
        if self.last_validation is not None:
            share, where = self.last_validation.get("at_depth_limits"), "the validation set"
        elif self.history:
            share, where = self.history[-1].get("at_depth_limits"), "the last training batch"
        else:
            return
        message = collapse_message(share, where, (cfg.depth_min, cfg.depth_max), cfg.lr)
        if message is not None:
            self.run_warnings.warn(f"step {self.step}: {message}", DepthCollapseWarning)

    def _check_data_wait(self) -> None:
        """Warn once per `fit` when the steps wait for their data (`StepTimer.wait_message`)."""
        message = self.step_timer.wait_message(self.workers)
        if message is not None:
            self.run_warnings.warn(f"step {self.step}: {message}", DataWaitWarning)

    # -- evaluation --------------------------------------------------------------------------
    def evaluate(self, test_set: Iterable[Mapping[str, Any]], depth_cap: float | None = None,
                 crop: str | Sequence[float] | None = None, median_scaling: bool = False,
                 min_depth: float = 1e-3, checker: TestSampleChecker | None = None,
                 ) -> dict[str, float]:
        """Mean per-image metrics (`models.metrics.METRIC_NAMES`) over `test_set`, each sample
        checked against the config first (`checker`, by default a new `TestSampleChecker`).

        Args:
            test_set: samples with `image`, `depth` (and `mask`; `focused` and `camera`
                in `"aif+focused"` mode), unbatched.
            depth_cap: ignore ground truth beyond this (metres) and clamp predictions to it.
            crop: `None`, `"garg"`, `"eigen"` or `(top, bottom, left, right)` fractions.
            median_scaling: scale predictions by the median ratio (adds `median_scale`).
            min_depth: ignore ground truth at or below this (metres).
            checker: checks each sample and counts its ground truth outside the depth range.

        Raises:
            ValueError: a sample the network cannot read (`TestSampleChecker.check`), or none
                with ground-truth depth (`models.evaluation.evaluate`, which skips samples
                whose mask is empty).

        Returns:
            the mean metrics, and `at_depth_limits`: the share of predicted pixels at
            `depth_min` or `depth_max` (near 1: the network collapsed to its limits).
        """
        test_set = learned.rendered_samples(self.camera, test_set, self.config)  # if learned
        return evaluate_network(self.model, self.config, test_set, checker, self.device,
                                self.learned_aperture, min_depth=min_depth, max_depth=depth_cap,
                                crop=crop, median_scaling=median_scaling)

    def _validate(self) -> None:
        metrics = self.evaluate(self.val_set)
        self.last_validation = metrics
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
        if self.camera is not None:  # its files, and what the network reads through it
            learned.save_camera(self.camera, self.config.out_dir, self.step, self.log.train)
            sample = next(learned.rendered_samples(self.camera, [sample], self.config))
        batch = collate([sample])
        depth = self.predict(batch["image"], batch.get("focused"), batch.get("camera"))
        path = path or self.config.out_dir / "figures" / f"step_{self.step:06d}.png"
        return plot_prediction(path, sample["image"], depth[0], sample.get("focused"),
                               sample.get("depth"), sample.get("mask"),
                               title=figure_title(sample.get("id"), self.step),
                               depth_range=(self.config.depth_min, self.config.depth_max))

    # -- checkpoints -------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything exact resume needs, as tensors and plain data only (see
        `models.checkpoints`), and a learned camera's `learned_camera.checkpoint_entries`."""
        camera = self.sample_checks.camera
        return {"format": CHECKPOINT_FORMAT, "model": self.model.state_dict(),
                "optimizer": self.optimizer.state_dict(),
                "scheduler": self.scheduler.state_dict(), "step": self.step,
                "config": to_plain(self.config.to_dict(), "config"),
                "history": [dict(row) for row in self.history], "rng": rng_state(),
                **({} if camera is None else {"camera": camera}),
                **({} if self.camera is None else learned.checkpoint_entries(self.camera))}

    def load_state_dict(self, state: Mapping[str, Any], source: str | Path = "checkpoint") -> None:
        """Restore what `state_dict` returned (also older checkpoints without `rng`) from
        `source` (as named in errors)."""
        restore_weights(self.model, state["model"], source)
        learned.restore(self.camera, state)
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
        return self.checkpointer.save(self.state_dict(), self.step, path)

    def _save_once(self) -> Path | None:
        """`save_checkpoint()` unless this step is saved already; returns `last.pt`."""
        if self.checkpointer.is_saved(self.step):
            return self.checkpoints.last
        return self.save_checkpoint()

    @classmethod
    def from_checkpoint(cls, path: str | Path, train_set: Iterable[Mapping[str, Any]] = (),
                        device: str = "auto") -> Trainer:
        """A trainer holding a checkpoint's config and weights (for evaluation and prediction).

        Raises:
            CheckpointError: the file is not a checkpoint or holds more than tensors and plain
                data (refused without running anything).
        """
        from ..loading import read_checkpoint  # loading reads configs of this package

        state, cfg = read_checkpoint(path, resume="overwrite", progress=False, device=device)
        # "overwrite" only skips reading the run folder here:
        trainer = cls(cfg, train_set, camera=learned.starting_camera(state))
        trainer.load_state_dict(state, path)
        trainer.run_folder.continue_at(trainer.step)  # fit() would continue it
        return trainer

    def load_checkpoint(self, path: str | Path, restore_logs: bool = True) -> None:
        """Restore a checkpoint written by `save_checkpoint` (exact resume); with
        `restore_logs` the CSV logs are cut back to the checkpoint's step.

        Raises:
            CheckpointError: the file is not a checkpoint or holds more than tensors and plain
                data (refused without running anything).
        """
        self.load_state_dict(load_checkpoint(path, map_location=self.device), path)
        if self.is_main and restore_logs:
            self.log.truncate(self.step)
