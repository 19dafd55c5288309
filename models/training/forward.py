"""A training step's forward pass: the predicted depth and the loss terms of a batch, the network
and the loss compiled into one graph when the run asks for it (`TrainConfig.compile`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor, nn
from torch.profiler import record_function

from ..losses import DefocusLoss, supervised_depth_loss
from .config import TrainConfig

_log = logging.getLogger("models.training")

#: what a forward pass returns: the depth `(B, 1, H, W)` metres and the loss terms
Forward = tuple[Tensor, dict[str, Tensor]]


class NetworkAndLoss:
    """`(depth, terms)` of a collated batch: the network (under bfloat16 autocast when
    `config.precision` says so; the renderer and the loss in float32), then the self-supervised
    `DefocusLoss` or, with `supervision="depth"`, the relative depth error on the labels.

    With `config.compile` both run through one `torch.compile` graph (`config.compile_mode`),
    made at the first call, so that their ~1000 small operations are fused: otherwise each is a
    kernel launch and a GPU step waits for the host to issue them.

    Args:
        config: the run's config.
        network: the module the step runs (wrapped for distributed training where it is).
        loss: the self-supervised loss, on the training device.
        device: the training device.

    Example:
        >>> from models.networks import build_network
        >>> cfg = TrainConfig(input_mode="aif", supervision="depth", width=4)
        >>> net = build_network("small", "aif", 0, cfg.depth_min, cfg.depth_max, width=4)
        >>> forward = NetworkAndLoss(cfg, net, DefocusLoss(), torch.device("cpu"))
        >>> batch = {"image": torch.rand(1, 3, 8, 8), "depth": torch.full((1, 1, 8, 8), 2.0)}
        >>> depth, terms = forward(batch)
        >>> tuple(depth.shape), sorted(terms)
        ((1, 1, 8, 8), ['loss'])
    """

    def __init__(self, config: TrainConfig, network: nn.Module, loss: DefocusLoss,
                 device: torch.device):
        self.config, self.network, self.loss, self.device = config, network, loss, device
        self._compiled: Callable[[Mapping[str, Any]], Forward] | None = None

    def __call__(self, batch: Mapping[str, Any]) -> Forward:
        if self._compiled is None and self.config.compile:
            _log.info("compiling the network and the loss (mode %s): the first step takes a "
                      "minute or two", self.config.compile_mode)
            self._compiled = torch.compile(self.eager, mode=self.config.compile_mode)
        if self._compiled is not None:
            with record_function("network and loss"):
                return self._compiled(batch)
        return self.eager(batch)

    def eager(self, batch: Mapping[str, Any]) -> Forward:
        """The forward pass as plain PyTorch (what the compiled graph is traced from)."""
        image = batch["image"]
        with record_function("network"), torch.autocast(
                self.device.type, torch.bfloat16, enabled=self.config.precision == "bfloat16"):
            depth = self.network(image, batch.get("focused"), batch.get("camera"))
        depth = depth.float()  # the renderer and the loss in float32
        if self.config.supervision == "self":
            with record_function("loss"):
                return depth, self.loss(depth, image, batch["focused"], batch["camera"])
        target, mask = batch["depth"], batch.get("mask")
        if mask is not None:  # masked-out labels may be anything (inf, nan): keep them out
            target = torch.where(mask.bool(), target, torch.ones_like(target))
        return depth, {"loss": supervised_depth_loss(depth, target, mask)}
