"""The devices a run may name: `check_device` (refuse one this machine lacks) and
`select_device` (resolve `"auto"`). Training and `defocus predict` both take a device name."""

from __future__ import annotations

import os

import torch


def _available(device: torch.device) -> bool | None:
    """Whether this machine has `device` (None: not a kind of device we run on)."""
    if device.type == "cuda":
        return torch.cuda.is_available() and (device.index or 0) < torch.cuda.device_count()
    if device.type == "mps":
        return torch.backends.mps.is_available()
    if device.type == "xpu":
        return hasattr(torch, "xpu") and torch.xpu.is_available()
    return True if device.type == "cpu" else None


def check_device(name: str) -> None:
    """Raise `ValueError` unless `name` is "auto" or a device this machine has.

    Example:
        >>> check_device("cpu")
        >>> check_device("gpu")
        Traceback (most recent call last):
        ...
        ValueError: device must be 'auto' or a torch device such as 'cpu' or 'cuda:0', got 'gpu'
    """
    if name == "auto":
        return
    try:
        available = _available(torch.device(name))
    except (RuntimeError, ValueError):
        available = None
    if available is None:
        raise ValueError(f"device must be 'auto' or a torch device such as 'cpu' or 'cuda:0', "
                         f"got {name!r}")
    if not available:
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        have = f": this machine has {count} CUDA device(s)" if name.startswith("cuda") else " here"
        raise ValueError(f"device {name!r} is not available{have}; use 'auto' or 'cpu'")


def select_device(name: str) -> torch.device:
    """`name`, or for `"auto"` this process's GPU when CUDA is available, else the CPU.

    Example:
        >>> select_device("cpu")
        device(type='cpu')
    """
    if name == "auto":
        available = torch.cuda.is_available()
        name = f"cuda:{int(os.environ.get('LOCAL_RANK', 0))}" if available else "cpu"
    return torch.device(name)
