"""Training: a trainer with exact resume, CSV logs, figures and DDP, run by a `TrainConfig`
(`models.training.config`, also importable from here).

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
seconds, `at_depth_limits`, `data_s`, `compute_s` and the compute's phases `network_s`,
`loss_s`, `backward_s`, `optimizer_s`), `val_log.csv` (validation metrics),
`checkpoints/last.pt` (and the newest `step_XXXXXX.pt`), `figures/step_XXXXXX.png`, and
`warnings.log` when a run ends with a warning.

The camera can be learned with the network (`TrainConfig.learn_optics`: focus distances,
f-numbers, an aperture mask; `optics.LearnableCamera`): each batch's focused images are then
rendered from its all-in-focus image and depth through it, its parameters are a param group of
their own (`optics_lr`), and the run adds `camera.json`, `mask.png`, `optics.png` and the
camera's values as `train_log.csv` columns (`models.training.learned_camera`).

One folder holds one run. `TrainConfig.resume` says what happens when `out_dir` already holds
one: `"auto"` (default) continues it when its config is the same and otherwise refuses with
the keys that differ; `"resume"` continues it, also to a larger `steps`; `"overwrite"` deletes
its files (config, logs, checkpoints, figures; nothing else) when `fit` starts. A continued run
starts from `checkpoints/last.pt` with its logs cut back to that step, so its logs and losses
match those of an uninterrupted run.

Speed: each step's batch is prepared ahead in `TrainConfig.workers` worker processes
(`models.training.batches.BatchStream`; the same batches as without them) and, on a GPU, moved
to the device in a thread (`DevicePrefetch`); the network may run under bfloat16 autocast
(`precision`), and the network and the loss through one `torch.compile` graph (`compile`,
`compile_mode`; `models.training.forward.NetworkAndLoss`); each step waits for the device
once. Every logged step's time is split into `data_s` (waiting for the batch) and `compute_s`
(and that into its phases), shown in the progress bar, summed up by `StepTimer.summary`
(`Trainer.step_timer`), and a `DataWaitWarning` says when the wait exceeds a quarter of the
steps (`models.training.step_timing`).

Failures are safe: every config field is checked when the config is built; `fit` checks the
samples (`n_focus`, ground-truth depth > 0 where valid), saves checkpoints periodically (by
steps and by minutes), when a step fails and on SIGINT/SIGTERM (then it raises
`TrainingInterrupted`), stops at the first non-finite loss or gradient (`FloatingPointError`)
without saving non-finite weights, and warns (`DepthCollapseWarning`) when most predicted pixels
sit at `depth_min` or `depth_max`.

The pieces: `Trainer` (`models.training.trainer`) runs the loop and is composed of helpers that
each own their state: a `RunFolder` (`models.training.run_folder`: one run per folder), a
`Checkpointer` (`models.training.checkpointing`: when checkpoints are written, exact resume
after a failure), a `SignalGuard` (`models.training.interruption`: SIGINT and SIGTERM) and a
`SampleChecker` (`models.training.sample_checks`); `models.training.state` holds the rank, the
schedule, the random states and `to_device`; `models.training.config` the `TrainConfig`,
`models.training.sampling` the batches of each step (and flips), `models.training.run_log` the
CSV logs, `models.training.learned_camera` a learned camera's part in a run. Outside the package: `models.checkpoints` (checkpoint files that open without running
code, `CheckpointStore`), `models.loading` (a checkpoint's config and network),
`models.devices` (device names) and `models.plotting` (figures). Checkpoints hold only
tensors and plain data and are read with `torch.load(..., weights_only=True)`: a file holding
anything else is refused with `CheckpointError` (see `docs/security.md`).
"""


from ..checkpoints import CheckpointError
from ..metrics import METRIC_NAMES
from .batches import BatchStream, auto_workers
from .checkpointing import Checkpointer
from .config import RESUME_MODES, RUN_CONTROL_KEYS, SUPERVISIONS, TrainConfig
from .interruption import SignalGuard, TrainingInterrupted
from .run_folder import RunFolder, RunToContinue, run_files
from .run_warnings import COLLAPSE_FRACTION, LIMIT_TOLERANCE, DepthCollapseWarning, RunWarnings
from .sample_checks import SampleChecker
from .state import build_scheduler, process_rank, rng_state, set_rng_state, to_device
from .step_timing import DataWaitWarning, StepTimer
from .trainer import Trainer

__all__ = ["COLLAPSE_FRACTION", "LIMIT_TOLERANCE", "METRIC_NAMES", "RESUME_MODES",
           "RUN_CONTROL_KEYS", "SUPERVISIONS", "BatchStream", "CheckpointError", "Checkpointer",
           "DataWaitWarning", "DepthCollapseWarning", "RunFolder", "RunToContinue",
           "RunWarnings", "SampleChecker", "SignalGuard", "StepTimer", "auto_workers",
           "TrainConfig", "Trainer", "TrainingInterrupted", "build_scheduler", "process_rank",
           "rng_state", "run_files", "set_rng_state", "to_device"]
