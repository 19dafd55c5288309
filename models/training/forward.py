"""A training step's forward pass: the predicted depth and the loss terms of a batch, the network
and the loss compiled into one graph when the run asks for it (`TrainConfig.compile`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor, nn
from torch.profiler import record_function

from optics import LearnableCamera

from ..losses import DefocusLoss, supervised_depth_loss
from .config import TrainConfig
from .learned_camera import depth_contrast, render_batch

_log = logging.getLogger("models.training")

#: what a forward pass returns: the depth `(B, 1, H, W)` metres and the loss terms
Forward = tuple[Tensor, dict[str, Tensor]]


def network_precision(precision: str, device: torch.device) -> str:
    """The arithmetic of the network for `TrainConfig.precision` on `device`: "float32" or
    "bfloat16"; "auto" is "bfloat16" on a CPU with native bfloat16 arithmetic (oneDNN's
    AVX-512 BF16 or AMX kernels: its convolutions take about half the time of float32 ones),
    "float32" elsewhere (a CPU without it would emulate bfloat16, slower; GPUs keep float32).

    Example:
        >>> network_precision("float32", torch.device("cpu"))
        'float32'
        >>> network_precision("auto", torch.device("cpu")) in ("float32", "bfloat16")
        True
    """
    if precision != "auto":
        return precision
    native = device.type == "cpu" and torch.backends.mkldnn.is_available() \
        and bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    return "bfloat16" if native else "float32"


class NetworkAndLoss:
    """`(depth, terms)` of a collated batch: the network (under bfloat16 autocast when
    `config.precision` says so, `network_precision`; the renderer and the loss in float32), then the self-supervised
    `DefocusLoss` or, with `supervision="depth"`, the relative depth error on the labels.

    With `config.compile` both run through one `torch.compile` graph (`config.compile_mode`),
    made at the first call, so that their ~1000 small operations are fused: otherwise each is a
    kernel launch and a GPU step waits for the host to issue them.

    Args:
        config: the run's config.
        network: the module the step runs (wrapped for distributed training where it is).
        loss: the self-supervised loss, on the training device.
        device: the training device.
        camera: the camera learned with the network (`TrainConfig.learn_optics`), or None:
            then each batch's focused images are first rendered through it from its
            all-in-focus image and depth (`models.training.learned_camera.render_batch`), and
            the network, the loss and the labels' twin all see those.

    Each call leaves the host seconds of its phases in `phases` ("network" and "loss", or
    "network and loss" when compiled; `models.training.step_timing.PHASES`).

    Example:
        >>> from models.networks import build_network
        >>> cfg = TrainConfig(input_mode="aif", supervision="depth", width=4)
        >>> net = build_network("small", "aif", 0, cfg.depth_min, cfg.depth_max, width=4)
        >>> forward = NetworkAndLoss(cfg, net, DefocusLoss(), torch.device("cpu"))
        >>> batch = {"image": torch.rand(1, 3, 8, 8), "depth": torch.full((1, 1, 8, 8), 2.0)}
        >>> depth, terms = forward(batch)
        >>> tuple(depth.shape), sorted(terms)
        ((1, 1, 8, 8), ['loss'])
        >>> sorted(forward.phases)
        ['loss', 'network']
    """

    def __init__(self, config: TrainConfig, network: nn.Module, loss: DefocusLoss,
                 device: torch.device, camera: LearnableCamera | None = None):
        self.config, self.network, self.loss, self.device = config, network, loss, device
        self.camera = camera
        self._compiled: Callable[[Mapping[str, Any]], Forward] | None = None
        #: the network's arithmetic, "float32" or "bfloat16" (`network_precision`)
        self.precision = network_precision(config.precision, device)
        #: the host seconds of the last call's phases
        self.phases: dict[str, float] = {}

    def __call__(self, batch: Mapping[str, Any]) -> Forward:
        if self._compiled is None and self.config.compile:
            _log.info("compiling the network and the loss (mode %s): the first step takes a "
                      "minute or two", self.config.compile_mode)
            self._compiled = torch.compile(self.eager, mode=self.config.compile_mode)
        if self._compiled is not None:
            started = time.perf_counter()
            with record_function("network and loss"):
                out = self._compiled(batch)
            self.phases = {"network and loss": time.perf_counter() - started}
            return out
        started = time.perf_counter()
        batch = self.rendered(batch)  # timed with the network (nothing rendered: no time)
        depth = self.network_depth(batch)
        networked = time.perf_counter()
        terms = self.loss_terms(depth, batch)
        self.phases = {"network": networked - started, "loss": time.perf_counter() - networked}
        return depth, terms

    def eager(self, batch: Mapping[str, Any]) -> Forward:
        """The forward pass as plain PyTorch (what the compiled graph is traced from: no host
        timing inside)."""
        batch = self.rendered(batch)
        depth = self.network_depth(batch)
        return depth, self.loss_terms(depth, batch)

    def rendered(self, batch: Mapping[str, Any]) -> Mapping[str, Any]:
        """`batch` with its focused images rendered through the learned camera (the batch as
        it is without one)."""
        if self.camera is None:
            return batch
        with record_function("optics"):
            return render_batch(self.camera, batch, self.config)

    def network_depth(self, batch: Mapping[str, Any]) -> Tensor:
        """The network's depth `(B,1,H,W)` (computed in `precision`), float32."""
        with record_function("network"), torch.autocast(
                self.device.type, torch.bfloat16, enabled=self.precision == "bfloat16"):
            extra = {} if self.camera is None else {"aperture": self.camera.aperture}
            depth = self.network(batch["image"], batch.get("focused"), batch.get("camera"),
                                 **extra)
        return depth.float()  # the renderer and the loss in float32

    def loss_terms(self, depth: Tensor, batch: Mapping[str, Any]) -> dict[str, Tensor]:
        """The loss terms of `depth` on `batch` (self-supervised or against the labels)."""
        with record_function("loss"):
            if self.config.supervision == "self":
                terms = self.loss(depth, batch["image"], batch["focused"], batch["camera"],
                                  batch.get("hint"))
                if self.camera is not None and self.config.optics_objective == "contrast":
                    term, terms["contrast"] = depth_contrast(self.loss, depth, batch,
                                                             terms["loss"])
                    terms["loss"] = terms["loss"] + term
                return terms
            target, mask = batch["depth"], batch.get("mask")
            if mask is not None:  # masked-out labels may be anything (inf, nan): keep out
                target = torch.where(mask.bool(), target, torch.ones_like(target))
            return {"loss": supervised_depth_loss(depth, target, mask)}
