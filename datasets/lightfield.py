"""Lytro light fields (e.g. the Flowers set of Srinivasan et al. 2017): real refocusing.

A Lytro light field is stored as one PNG *mosaic* of `n x n` sub-aperture views (14x14 for the
Lytro Illum). Two layouts exist:

- `"interleaved"` (Lytro ESLF, the Flowers `*_eslf.png` files): each `n x n` block of the
  mosaic is one micro-lens, so view `(s, t)` is `mosaic[s::n, t::n]`;
- `"tiled"`: the views are laid side by side, view `(s, t)` is the `(s, t)`-th tile.

Refocusing is shift-and-add: a scene point at *disparity* `d` (pixels per view step) seen at
`(y, x)` in the centre view appears at `(y + d*ds, x + d*dt)` in the view at offset
`(ds, dt)`. Averaging the views sampled at those positions for `d = d_f` brings the plane at
`d_f` into focus; a point at `d` is spread over the aperture's view offsets scaled by
`d - d_f`: a disk of diameter `2 * radius * |d - d_f|` pixels for a circular aperture mask of
`radius` view steps. The centre view is the all-in-focus image.

Folder layout (`root`)::

    <name>.png            one mosaic per light field (8 or 16 bit, sRGB)
    <split>.txt           optional: the file names of a split, one per line

Light fields carry no depth: samples have `mask` all False and depth filled with the
calibration's zero-disparity distance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from optics import CameraSettings
from optics.checks import check_shape

from .base import DepthDataset
from .focus import CameraPreset
from .io import DataFormatError, read_list, require_args, require_file, require_root
from .photos import read_photo

LAYOUT = (
    "  <root>/<name>.png   light-field mosaics of n x n views (interleaved ESLF or tiled)\n"
    "  <root>/<split>.txt  optional list of mosaic file names for a split"
)

LAYOUTS = ("interleaved", "tiled")


def mosaic_to_views(mosaic: Tensor, n_views: int = 14, layout: str = "interleaved",
                    name: str = "mosaic") -> Tensor:
    """Split a light-field mosaic `(C, n*H, n*W)` into views `(n, n, C, H, W)`.

    Args:
        mosaic: the mosaic image.
        n_views: views per side (14 for the Lytro Illum).
        layout: `"interleaved"` (micro-lens blocks, Lytro ESLF) or `"tiled"`.
        name: what the refusal calls the mosaic (e.g. its file).

    Raises:
        DataFormatError: naming `name`, the mosaic size is not a multiple of `n_views`, or an
            unknown layout.

    Example:
        >>> mosaic = torch.arange(16.0).reshape(1, 4, 4)
        >>> mosaic_to_views(mosaic, 2, "interleaved")[0, 1, 0]
        tensor([[ 1.,  3.],
                [ 9., 11.]])
        >>> mosaic_to_views(mosaic, 2, "tiled")[0, 1, 0]
        tensor([[2., 3.],
                [6., 7.]])
    """
    check_shape("mosaic", mosaic, ["C", "H", "W"])
    c, h, w = mosaic.shape
    if layout not in LAYOUTS or h % n_views or w % n_views:
        raise DataFormatError(f"{name} of {h}x{w} pixels is not a grid of {n_views}x{n_views} "
                              f"views in layout {layout!r} (both sizes must be multiples of "
                              f"{n_views}; layouts: {LAYOUTS})")
    hh, ww = h // n_views, w // n_views
    if layout == "interleaved":
        views = mosaic.reshape(c, hh, n_views, ww, n_views).permute(2, 4, 0, 1, 3)
    else:
        views = mosaic.reshape(c, n_views, hh, n_views, ww).permute(1, 3, 0, 2, 4)
    return views.contiguous()


def aperture_offsets(n_views: int, radius: float) -> list[tuple[int, int, int, int]]:
    """`(s, t, ds, dt)` of the views inside a circular aperture of `radius` view steps.

    Offsets are relative to the centre view `(n_views // 2, n_views // 2)`.

    Example:
        >>> len(aperture_offsets(5, 1.0)), len(aperture_offsets(5, 1.5))
        (5, 9)
    """
    c = n_views // 2
    return [
        (s, t, s - c, t - c)
        for s in range(n_views)
        for t in range(n_views)
        if math.hypot(s - c, t - c) <= radius + 1e-9
    ]


def refocus(views: Tensor, disparity: float | Sequence[float] | Tensor, radius: float) -> Tensor:
    """Shift-and-add refocus at `disparity` pixels per view step under a circular aperture.

    `out(y, x) = mean_{(ds,dt) in mask} view[ds,dt](y + d*ds, x + d*dt)` with bilinear
    sampling (exact for integer shifts; border pixels repeated outside the view). Differentiable
    with respect to the views.

    Args:
        views: `(n, n, C, H, W)` sub-aperture views.
        disparity: one disparity or `F` of them, pixels per view step.
        radius: aperture radius in view steps (views with `hypot(ds, dt) <= radius` are used).

    Returns:
        `(C,H,W)` for one disparity, `(F,C,H,W)` for several.

    Example:
        >>> views = torch.rand(3, 3, 1, 8, 8)
        >>> torch.allclose(refocus(views, 0.0, 0.0), views[1, 1])
        True
    """
    check_shape("views", views, ["N", "N", "C", "H", "W"])
    if views.shape[0] != views.shape[1] or not radius >= 0:
        raise ValueError(f"views must be a square grid (n, n, C, H, W) and radius >= 0 view steps, "
                         f"got {tuple(views.shape)} and {radius}")
    d = torch.as_tensor(disparity, dtype=views.dtype, device=views.device)
    single = d.ndim == 0
    d = d.reshape(-1)
    offsets = aperture_offsets(views.shape[0], radius)
    out = []
    for value in d.tolist():
        total = sum(
            _sample_shifted(_sample_shifted(views[s, t], value * ds, -2), value * dt, -1)
            for s, t, ds, dt in offsets
        )
        out.append(total / len(offsets))
    stack = torch.stack(out)
    return stack[0] if single else stack


def _sample_shifted(image: Tensor, shift: float, dim: int) -> Tensor:
    """`out[i] = image[i + shift]` along `dim`, linear between pixels, edges repeated.

    Exact (no resampling) for integer shifts.
    """
    n = image.shape[dim]
    base = math.floor(shift)
    frac = shift - base
    index = torch.arange(n, device=image.device) + base
    lower = image.index_select(dim, index.clamp(0, n - 1))
    if frac == 0:
        return lower
    upper = image.index_select(dim, (index + 1).clamp(0, n - 1))
    return lower * (1 - frac) + upper * frac


class LightFieldCalibration:
    """An equivalent thin-lens camera for a light field (lengths in metres).

    A scene point at depth `D` has disparity `d = baseline * f_px * (1/D0 - 1/D)` pixels per
    view step (`f_px = focal_length / pixel_pitch`, `D0` the zero-disparity distance).
    Refocusing at `d_f` with an aperture of `radius` views blurs it into a disk of
    `2 * radius * |d - d_f|` pixels, which is the thin-lens CoC of a lens of aperture diameter
    `2 * radius * baseline` focused at `1/D_f = 1/D0 - d_f / (baseline * f_px)` (up to the
    factor `D_f / (D_f - f)`, under 1% for `D_f > 100 f`). The defaults are nominal Lytro
    Illum values; replace them with your calibration.

    The main lens is held as `camera`, an `optics.CameraSettings`: focused at the
    zero-disparity distance, with the f-number of an aperture one view step wide
    (`focal_length / baseline`).

    Args:
        focal_length: main-lens focal length, metres.
        pixel_pitch: pitch of the sub-aperture images (the micro-lens pitch), metres.
        baseline: distance between adjacent views on the main-lens aperture, metres.
        zero_disparity_distance: depth at which disparity is zero, metres.

    Example:
        >>> calib = LightFieldCalibration()
        >>> d = calib.disparity(torch.tensor([0.5, 2.0]))
        >>> calib.depth(d)
        tensor([0.5000, 2.0000])
    """

    def __init__(self, focal_length: float = 0.03, pixel_pitch: float = 20e-6,
                 baseline: float = 1.07e-3, zero_disparity_distance: float = 1.0) -> None:
        #: the main lens focused at the zero-disparity distance, one view step of aperture
        self.camera = CameraSettings(focal_length, focal_length / baseline,
                                     zero_disparity_distance, pixel_pitch)
        #: distance between adjacent views on the main-lens aperture, metres
        self.baseline = float(baseline)

    @property
    def focal_length(self) -> float:
        """Main-lens focal length, metres."""
        return float(self.camera.focal_length[0])

    @property
    def pixel_pitch(self) -> float:
        """Pitch of the sub-aperture images, metres."""
        return float(self.camera.pixel_pitch[0])

    @property
    def zero_disparity_distance(self) -> float:
        """Depth at which disparity is zero, metres."""
        return float(self.camera.focus_distance[0])

    def __eq__(self, other: object) -> bool:
        return isinstance(other, LightFieldCalibration) and self.camera == other.camera \
            and self.baseline == other.baseline

    def __repr__(self) -> str:
        return (f"LightFieldCalibration(focal_length={self.focal_length}, pixel_pitch="
                f"{self.pixel_pitch}, baseline={self.baseline}, zero_disparity_distance="
                f"{self.zero_disparity_distance})")

    @property
    def focal_length_px(self) -> float:
        return self.focal_length / self.pixel_pitch

    def disparity(self, depth: Tensor) -> Tensor:
        """Disparity in pixels per view step of depths in metres."""
        return self.baseline * self.focal_length_px * (1 / self.zero_disparity_distance - 1 / depth)

    def depth(self, disparity: Tensor) -> Tensor:
        """Depth in metres of disparities in pixels per view step (inverse of `disparity`)."""
        inverse = 1 / self.zero_disparity_distance - disparity / (self.baseline * self.focal_length_px)
        if bool((inverse <= 0).any()):
            raise ValueError(
                f"disparity {disparity.tolist()} lies beyond infinity for this calibration "
                f"(largest finite disparity {self.baseline * self.focal_length_px / self.zero_disparity_distance:.4g} px)"
            )
        return 1 / inverse

    def preset(self, focus_disparities: Sequence[float], radius: float) -> CameraPreset:
        """The thin-lens `CameraPreset` of refocusing at each disparity."""
        if not radius > 0:
            raise ValueError(f"radius must be > 0 view steps for a finite f-number, got {radius}")
        focus = self.depth(torch.tensor(list(focus_disparities), dtype=torch.float64))
        return CameraPreset(
            self.focal_length,
            self.pixel_pitch,
            focus_distances=tuple(focus.tolist()),
            f_numbers=(self.focal_length / (2 * radius * self.baseline),),
            depth_cap=float(focus.max()) * 10,
        )


class LightField(DepthDataset):
    """Lytro light fields: centre view as all-in-focus image, real refocused images as focused.

    Args:
        root: folder of `*.png` mosaics.
        split: `"all"` (every PNG in `root`) or the name of a list `<root>/<split>.txt`.
        n_views: views per side of the stored mosaic (14 for the Lytro Illum).
        layout: `"interleaved"` (Lytro ESLF) or `"tiled"`.
        views: odd number of central views per side to keep (the outer Lytro views are
            vignetted); `n_views` keeps all.
        radius: aperture radius in view steps for refocusing.
        focus_disparities: disparities (pixels per view step) of the focused images.
        calibration: the equivalent camera, for each focused image's settings.
        **kwargs: `size`, `crop`, `augment`, `dtype` of
            `DepthDataset`.

    Raises:
        FileNotFoundError: `root`, the split list or a listed mosaic is missing.
        DataFormatError: a mosaic is unreadable or not a grid of `n_views x n_views` views.
    """

    name = "lightfield"

    def __init__(
        self,
        root: str | Path,
        split: str = "all",
        n_views: int = 14,
        layout: str = "interleaved",
        views: int = 7,
        radius: float = 3.0,
        focus_disparities: Sequence[float] = (-0.5, 0.5),
        calibration: LightFieldCalibration | None = None,
        **kwargs: Any,
    ):
        require_args(("layout", layout, layout in LAYOUTS, f"one of {LAYOUTS}"),
                     ("views", views, 0 < views <= n_views and (views % 2 == 1 or views == n_views),
                      f"odd and in 1..{n_views} (or {n_views})"),
                     ("radius", radius, radius > 0, "> 0 view steps for a finite f-number"))
        self.calibration = calibration or LightFieldCalibration()
        super().__init__(self.calibration.preset(focus_disparities, radius), **kwargs)
        self.root = require_root(root, "LightField", LAYOUT)
        self.n_views, self.layout, self.views, self.radius = n_views, layout, views, float(radius)
        self.focus_disparities = tuple(float(d) for d in focus_disparities)
        if split == "all":
            self.files = sorted(p for p in self.root.iterdir()
                                if p.suffix.lower() == ".png" and p.is_file())  # .PNG too
            if not self.files:
                raise FileNotFoundError(f"LightField: no *.png mosaics in {str(self.root)!r}")
        else:
            listing = require_file(self.root / f"{split}.txt", "a list of mosaic file names")
            names = read_list(listing, "a scene list")
            self.files = [require_file(self.root / n, f"a light-field mosaic listed in {listing.name}")
                          for n in names]
        self.ids = [p.stem for p in self.files]

    def load_views(self, index: int) -> Tensor:
        """The kept central views `(views, views, 3, H, W)` of light field `index`."""
        path = self.files[index]
        grid = mosaic_to_views(read_photo(path, dtype=self.dtype)[0], self.n_views, self.layout,
                               repr(str(path)))
        first = self.n_views // 2 - self.views // 2
        return grid[first : first + self.views, first : first + self.views]

    def load(self, index: int) -> dict[str, Any]:
        grid = self.load_views(index)
        centre = grid[self.views // 2, self.views // 2]
        h, w = centre.shape[-2:]
        depth = torch.full((1, h, w), self.calibration.zero_disparity_distance, dtype=self.dtype)
        return {
            "image": centre,
            "focused": refocus(grid, self.focus_disparities, self.radius).clamp(0, 1),
            "depth": depth,
            "mask": torch.zeros(1, h, w, dtype=torch.bool),
        }
