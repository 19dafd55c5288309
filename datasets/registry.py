"""The dataset registry: every dataset by the name the command line and configs use."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .base import DepthDataset


def dataset_classes() -> dict[str, type]:
    """Name -> class of every dataset (`synthetic` is the embedded default; the others read a
    folder in the dataset's real format)."""
    from .dslr import DSLR
    from .kitti import KITTI
    from .lightfield import LightField
    from .make3d import Make3D
    from .middlebury import Middlebury
    from .nyu import NYUv2
    from .photo_folder import PhotoFolder
    from .rgbd import RGBD
    from .synthetic import SyntheticScenes

    return {"synthetic": SyntheticScenes, "dslr": DSLR, "nyu": NYUv2, "kitti": KITTI,
            "make3d": Make3D, "middlebury": Middlebury, "lightfield": LightField,
            "folder": PhotoFolder, "rgbd": RGBD,
            **stack_dataset_classes()}


def stack_dataset_classes() -> dict[str, type]:
    """Name -> class of the focal-stack benchmarks (real shots, each with its settings)."""
    from .ddff12 import DDFF12
    from .fod500 import FoD500
    from .mobile_depth import MobileDepth
    from .zedd import ZEDD

    return {"ddff12": DDFF12, "fod500": FoD500, "zedd": ZEDD, "mobile_depth": MobileDepth}


#: Names of the focal-stack benchmarks (`defocus evaluate --data NAME`).
STACK_DATASET_NAMES = ("ddff12", "fod500", "zedd", "mobile_depth")


#: Names accepted by `build_dataset`.
DATASET_NAMES = ("synthetic", "dslr", "nyu", "kitti", "make3d", "middlebury", "lightfield",
                 "folder", "rgbd")

#: How each dataset's focused images come (`build_dataset(focus=...)`): `"real"` photos,
#: `"synthesized"` from the all-in-focus image and depth, or either (the first is the default).
FOCUS = {"synthetic": ("synthesized",), "nyu": ("synthesized",), "kitti": ("synthesized",),
         "make3d": ("synthesized",), "middlebury": ("synthesized",),
         "rgbd": ("synthesized",), "dslr": ("real", "synthesized"), "lightfield": ("real",),
         "folder": ("real",)}


def focus_of(name: str, focus: str | None = None) -> str:
    """How the focused images of dataset `name` come: `focus` where the dataset has it, its
    default for None.

    Raises:
        ValueError: `focus` is not one of the dataset's (`FOCUS`).

    Example:
        >>> focus_of("dslr"), focus_of("dslr", "synthesized"), focus_of("nyu")
        ('real', 'synthesized', 'synthesized')
        >>> focus_of("folder", "synthesized")
        Traceback (most recent call last):
        ...
        ValueError: --focus synthesized: the folder dataset has real focused photos only (no depth to render them from); it takes --focus real
    """
    modes = FOCUS[name]
    if focus is None:
        return modes[0]
    if focus not in modes:
        why = "real focused photos only (no depth to render them from)" if modes == ("real",) \
            else "no real focused photos: its focused images are synthesised from its depth"
        raise ValueError(f"--focus {focus}: the {name} dataset has {why}; it takes --focus "
                         f"{' or '.join(modes)}")
    return focus


def build_dataset(name: str, root: str | Path | None = None, split: str = "train",
                  size: tuple[int, int] | None = (48, 48), scenes: int = 256, seed: int = 0,
                  focus: str | None = None, **kwargs: Any) -> DepthDataset | Any:
    """The dataset called `name`.

    Args:
        name: one of `DATASET_NAMES`.
        root: the dataset folder (all but `synthetic`).
        split: the split of a folder dataset.
        size: `(height, width)` pixels: the synthetic scenes' size, the resize of real data
            (None: real data at its own size).
        scenes: number of synthetic scenes.
        seed: seed of the synthetic scenes.
        focus: `"real"` or `"synthesized"` focused images where the dataset has both
            (`dslr`); None: the dataset's own (`FOCUS`, `focus_of`).
        **kwargs: passed to the dataset class.

    Example:
        >>> len(build_dataset("synthetic", scenes=3, size=(16, 16)))
        3
    """
    if name not in DATASET_NAMES:
        raise ValueError(f"unknown dataset {name!r}; expected one of {', '.join(DATASET_NAMES)}")
    focus = focus_of(name, focus)
    if len(FOCUS[name]) > 1:
        kwargs["focus"] = focus
    cls = dataset_classes()[name]
    if name == "synthetic":
        return cls(scenes, tuple(size), seed=seed, **kwargs)
    if root is None:
        raise ValueError(f"dataset {name!r} needs root, the dataset folder")
    return cls(root, split=split, size=None if size is None else tuple(size), **kwargs)


def build_stack_dataset(name: str, root: str | Path, split: str | None = None,
                        **kwargs: Any) -> DepthDataset:
    """The focal-stack benchmark called `name` (one of `STACK_DATASET_NAMES`) read from `root`.

    Args:
        name: `"ddff12"`, `"fod500"`, `"zedd"` or `"mobile_depth"`.
        root: the dataset folder in its release layout.
        split: the benchmark's evaluation split when None (DDFF-12 `val`, FoD500 `test`,
            ZEDD `val`); Mobile Depth has none.
        **kwargs: passed to the dataset class.

    Example:
        >>> build_stack_dataset("kitti", "data")
        Traceback (most recent call last):
        ...
        ValueError: unknown focal-stack benchmark 'kitti'; expected one of ddff12, fod500, zedd, mobile_depth
    """
    if name not in STACK_DATASET_NAMES:
        raise ValueError(f"unknown focal-stack benchmark {name!r}; expected one of "
                         f"{', '.join(STACK_DATASET_NAMES)}")
    cls = stack_dataset_classes()[name]
    if name == "mobile_depth":
        if split not in (None, "all"):
            raise ValueError(f"mobile_depth has no splits (got split {split!r})")
        return cls(root, **kwargs)
    return cls(root, **kwargs) if split is None else cls(root, split=split, **kwargs)
