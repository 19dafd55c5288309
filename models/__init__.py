"""models: depth networks, losses, metrics and self-supervised training through the renderer.

The names most work needs are here; each lives in one module:

| name | module | job |
|---|---|---|
| `estimate_depth` | `models.depth_from_photos` | depth of one scene from its photos (the label-free methods, or a trained model) |
| `load_depth_model` | `models.loading` | a trained model from any weight file (`defocus train` checkpoint or weights file) |
| `evaluate`, `label_free_method`, `network_method` | `models.evaluation` | the one evaluation loop: a method's metrics over samples, with a benchmark's protocol; a label-free method or a trained network as a method |
| `depth_metrics`, `depth_order`, `best_constant_depth`, `format_table` | `models.metrics` | metrics and the paper-style table |
| `PROTOCOLS`, `protocol_metrics` | `models.protocols` | the focal-stack benchmarks' own scoring |
| `Trainer`, `TrainConfig` | `models.training` | training runs |
| `DefocusLoss`, `supervised_depth_loss` | `models.losses` | the training losses |
| `loss_at_depths` | `models.diagnostics` | is the loss right: its value at the true depth and the alternatives |
| `SmallDepthNet`, `PaperDepthNet`, `build_network`, `NETWORKS` | `models.networks` | the depth networks |
| `train_and_evaluate`, `compare_on_scene` | `models.experiment` | experiments built from the pieces |

Example:
    >>> import torch
    >>> import models
    >>> sample = {"depth": torch.full((1, 4, 4), 2.0), "mask": torch.ones(1, 4, 4).bool()}
    >>> models.evaluate(lambda s: torch.full((1, 4, 4), 2.0), [sample], "zedd")["abs_rel"]
    0.0
"""

from .depth_from_photos import TrainedNetwork, estimate_depth
from .diagnostics import loss_at_depths
from .evaluation import MeanMetrics, Method, evaluate, label_free_method, network_method
from .experiment import compare_on_scene, train_and_evaluate
from .loading import is_weights_file, load_depth_model, load_weights, save_weights
from .losses import DefocusLoss, supervised_depth_loss
from .metrics import (
    METRIC_NAMES,
    best_constant_depth,
    depth_metrics,
    depth_order,
    format_table,
)
from .networks import NETWORKS, PaperDepthNet, SmallDepthNet, build_network
from .protocols import PROTOCOLS, Protocol, protocol_metrics
from .training import (
    CheckpointError,
    DepthCollapseWarning,
    TrainConfig,
    Trainer,
    TrainingInterrupted,
)

__all__ = [
    "METRIC_NAMES",
    "NETWORKS",
    "PROTOCOLS",
    "CheckpointError",
    "DefocusLoss",
    "DepthCollapseWarning",
    "MeanMetrics",
    "Method",
    "PaperDepthNet",
    "Protocol",
    "SmallDepthNet",
    "TrainConfig",
    "TrainedNetwork",
    "Trainer",
    "TrainingInterrupted",
    "best_constant_depth",
    "depth_order",
    "build_network",
    "compare_on_scene",
    "depth_metrics",
    "estimate_depth",
    "evaluate",
    "format_table",
    "is_weights_file",
    "label_free_method",
    "load_depth_model",
    "load_weights",
    "loss_at_depths",
    "network_method",
    "protocol_metrics",
    "save_weights",
    "supervised_depth_loss",
    "train_and_evaluate",
]
