"""Pretrained weights that ship in the package, loaded safely.

No weights ship yet: `defocus pretrain --config models/weights/dfd_general.yaml` trains the
camera-general `DepthFromDefocus(BlurNet(width))` (procedural scenes under random cameras,
`datasets.capture`, no depth labels) and writes a weights file that `load_weights` and
`defocus predict WEIGHTS.pt` read. Shipped weights will be listed in `PRETRAINED`.

A weights file holds tensors and plain numbers only; it is checked against its recorded sha256
before loading and read with `torch.load(..., weights_only=True)`, so opening it runs no code.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import torch

from .depth_from_photos.blur_net import BlurNet, DepthFromDefocus

WEIGHTS_DIR = Path(__file__).with_name("weights")
#: name -> (file under `WEIGHTS_DIR`, sha256 of the file)
PRETRAINED: dict[str, tuple[str, str]] = {}


def sha256(path: str | Path) -> str:
    """Hex sha256 of a file."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def save_weights(model: DepthFromDefocus, path: str | Path, **metadata: float | int | str) -> str:
    """Write `model`'s weights as a safe file (tensors and plain values); returns its sha256."""
    net = model.blur_net
    state = {"format": 1, "kind": "DepthFromDefocus", "width": net.width,
             "blur_net": {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()},
             "metadata": dict(metadata)}
    torch.save(state, path)
    return sha256(path)


def is_weights_file(path: str | Path) -> bool:
    """Whether `path` holds `save_weights` output (read safely; False for anything else).

    The file is memory-mapped: its tensors are not read, so asking about a large training
    checkpoint costs nothing before the caller loads it for real.
    """
    try:
        state = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception:  # not a weights file: the caller tries other formats
        return False
    return isinstance(state, dict) and state.get("kind") == "DepthFromDefocus"


def load_weights(path: str | Path, expected_sha256: str | None = None) -> DepthFromDefocus:
    """Load a `DepthFromDefocus` written by `save_weights`, checking the file's sha256 first
    when given; `weights_only=True` (nothing in the file runs)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such weights file")
    if expected_sha256 is not None:
        actual = sha256(path)
        if actual != expected_sha256:
            raise ValueError(f"{path}: sha256 {actual} does not match the recorded "
                             f"{expected_sha256}; the file is damaged or was replaced")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # pickle and zip errors of many kinds: one clear line
        raise ValueError(f"{path}: not a Defocus weights file ({type(error).__name__})") from None
    if not isinstance(state, dict) or state.get("kind") != "DepthFromDefocus":
        raise ValueError(f"{path}: not a Defocus DepthFromDefocus weights file")
    model = DepthFromDefocus(BlurNet(int(state["width"])))
    model.blur_net.load_state_dict(state["blur_net"])
    return model.eval()


def load_pretrained(name: str = "dfd-general") -> DepthFromDefocus:
    """A shipped model by name (see the module table), sha256-checked.

    Example:
        >>> model = load_pretrained()  # doctest: +SKIP
    """
    if name not in PRETRAINED:
        raise ValueError(f"no shipped weights named {name!r} (available: {sorted(PRETRAINED)}); "
                         "train them with `defocus pretrain` and load the file with load_weights")
    file, digest = PRETRAINED[name]
    return load_weights(WEIGHTS_DIR / file, digest)
