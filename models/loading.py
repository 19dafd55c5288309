"""Loading trained depth models, whatever file they come in.

Two kinds of file hold a model:

- a checkpoint of `defocus train` (`models.checkpoints`): a network trained for one camera,
  with its config (input mode, focused photos, depth range) and the optimiser's state;
- a weights file of the experimental camera-general network (`save_weights`): a
  `DepthFromDefocus` (`models.depth_from_photos.blur_net`), written by `examples/blur_net.py`.

Both are read by one loader, `models.checkpoints.load_checkpoint`: tensors and plain data only,
`torch.load(..., weights_only=True)`, so opening a file runs no code; a weights file can also
be checked against its recorded sha256 first (`load_weights`). `load_depth_model` reads either
and returns the method object that `models.depth_from_photos.estimate_depth(model=...)` runs;
`load_model` gives a checkpoint's network and config, `read_checkpoint` its state and config.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .checkpoints import WEIGHTS_KIND, CheckpointError, load_checkpoint, restore_weights
from .depth_from_photos.blur_net import BlurNet, DepthFromDefocus
from .depth_from_photos.trained_network import TrainedNetwork
from .training.config import TrainConfig
from .training.learned_camera import checkpoint_aperture


def config_from_state(state: Mapping[str, Any], path: str | Path, **changes: Any) -> TrainConfig:
    """The `TrainConfig` of a loaded checkpoint, with `changes`; a bad one (or a weights file,
    which has none) is a `CheckpointError` naming the file."""
    try:
        return TrainConfig.from_dict({**state["config"], **changes})
    except (KeyError, TypeError, ValueError) as error:
        reason = (f"holds an invalid config: {error}" if "config" in state else "is a weights "
                  "file of the camera-general network, not a `defocus train` checkpoint (open "
                  "it with models.load_depth_model)")
        raise CheckpointError(f"checkpoint {path} {reason}") from None


def sha256(path: str | Path) -> str:
    """Hex sha256 of a file.

    Example:
        >>> import tempfile
        >>> with tempfile.NamedTemporaryFile(delete=False) as handle:
        ...     _ = handle.write(b"abc")
        >>> sha256(handle.name)[:16]
        'ba7816bf8f01cfea'
    """
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def save_weights(model: DepthFromDefocus, path: str | Path, **metadata: float | int | str) -> str:
    """Write `model`'s weights as a safe file (tensors and plain values); returns its sha256.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "w.pt"
        >>> digest = save_weights(DepthFromDefocus(BlurNet(width=4)), path, steps=0)
        >>> digest == sha256(path), is_weights_file(path)
        (True, True)
    """
    net = model.blur_net
    state = {"format": 1, "kind": WEIGHTS_KIND, "width": net.width,
             "blur_net": {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()},
             "metadata": dict(metadata)}
    torch.save(state, path)
    return sha256(path)


def is_weights_file(path: str | Path) -> bool:
    """Whether `path` holds `save_weights` output (read safely; False for anything else).

    The file is memory-mapped: its tensors are not read, so asking about a large training
    checkpoint costs nothing before the caller loads it for real.

    Example:
        >>> is_weights_file("no/such/file.pt")
        False
    """
    try:
        return load_checkpoint(path, mmap=True).get("kind") == WEIGHTS_KIND
    except (OSError, ValueError):  # not a weights file: the caller tries other formats
        return False


def _weights_model(state: Mapping[str, Any]) -> DepthFromDefocus:
    """The `DepthFromDefocus` (in eval mode) of a loaded weights file."""
    model = DepthFromDefocus(BlurNet(int(state["width"])))
    model.blur_net.load_state_dict(state["blur_net"])
    return model.eval()


def load_weights(path: str | Path, expected_sha256: str | None = None) -> DepthFromDefocus:
    """Load a `DepthFromDefocus` written by `save_weights` (in eval mode), checking the file's
    sha256 first when given; `weights_only=True` (nothing in the file runs).

    Raises:
        FileNotFoundError: no such file.
        ValueError: the sha256 differs, or the file is not a weights file (`CheckpointError`).

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "w.pt"
        >>> digest = save_weights(DepthFromDefocus(BlurNet(width=4)), path)
        >>> load_weights(path, digest).blur_net.width
        4
    """
    digest = sha256(path) if expected_sha256 is not None else None  # before anything is read
    state = load_checkpoint(path)
    problem = (f"sha256 {digest} does not match the recorded {expected_sha256}; the file is "
               "damaged or was replaced" if digest != expected_sha256 else None
               if state.get("kind") == WEIGHTS_KIND else "not a Defocus DepthFromDefocus "
               "weights file")
    if problem is not None:
        raise CheckpointError(f"{path}: {problem}")
    return _weights_model(state)


def read_checkpoint(path: str | Path, map_location: Any = "cpu",
                    **changes: Any) -> tuple[dict[str, Any], TrainConfig]:
    """A `defocus train` checkpoint's state and its `TrainConfig` (with `changes`).

    Raises:
        FileNotFoundError: no such file.
        CheckpointError: the file is not a checkpoint, holds more than tensors and plain data
            (refused without running anything) or holds an invalid config.

    Example:
        >>> read_checkpoint("no/such/last.pt")
        Traceback (most recent call last):
        ...
        FileNotFoundError: checkpoint no/such/last.pt does not exist or is not a file
    """
    state = load_checkpoint(path, map_location=map_location)
    return state, config_from_state(state, path, **changes)


def _network(state: Mapping[str, Any], path: str | Path,
             device: str | torch.device) -> tuple[nn.Module, TrainConfig]:
    """The trained network (in eval mode, on `device`) and config of a loaded checkpoint."""
    cfg = config_from_state(state, path, device="auto")
    model = cfg.build_network()
    restore_weights(model, state["model"], path)
    return model.to(device).eval(), cfg


def load_model(checkpoint: str | Path, device: str | torch.device = "cpu") -> tuple[nn.Module,
                                                                                     TrainConfig]:
    """The trained network (in eval mode) and its config from a `defocus train` checkpoint.

    Raises:
        FileNotFoundError: no such file.
        CheckpointError: the file is not a checkpoint or holds more than tensors and plain data
            (refused without running anything).

    Example:
        >>> network, config = load_model("runs/train/checkpoints/last.pt")  # doctest: +SKIP
    """
    return _network(load_checkpoint(checkpoint, map_location=device), checkpoint, device)


def load_depth_model(path: str | Path, device: str | torch.device = "cpu") -> nn.Module:
    """The depth model in `path`, ready for `estimate_depth(model=...)`, on `device`.

    A weights file of `save_weights` gives the camera-general `DepthFromDefocus`; a checkpoint
    of `defocus train` gives its network wrapped as a `TrainedNetwork` (its input mode,
    focused photos and depth range from the checkpoint's config, and the camera it was trained
    for where the checkpoint records it).

    Args:
        path: a weights file or a training checkpoint.
        device: where the model goes, as for `torch.Tensor.to`.

    Raises:
        FileNotFoundError: no such file.
        CheckpointError: the file is neither a weights file nor a checkpoint, or holds more
            than tensors and plain data (refused without running anything).

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "w.pt"
        >>> _ = save_weights(DepthFromDefocus(BlurNet(width=4)), path)
        >>> type(load_depth_model(path)).__name__
        'DepthFromDefocus'
    """
    state = load_checkpoint(path, map_location=device)
    if state.get("kind") == WEIGHTS_KIND:  # the experimental camera-general network
        return _weights_model(state).to(device)
    network, config = _network(state, path, device)
    camera = state.get("camera")  # the camera it was trained for (older checkpoints: none)
    return TrainedNetwork(network, config.input_mode, config.n_focus,
                          (config.depth_min, config.depth_max),
                          camera=camera if isinstance(camera, Mapping) else None,
                          aperture=checkpoint_aperture(state)).to(device)


__all__ = ["config_from_state", "is_weights_file", "load_depth_model", "load_model", "load_weights",
           "read_checkpoint", "save_weights", "sha256"]
