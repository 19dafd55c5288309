"""Self-supervised depth-from-defocus losses (Gur & Wolf 2019).

The depth predicted from the all-in-focus image is rendered, through each focused image's camera,
into a synthetic focused image that is compared with the real one:

- photometric: `ssim_weight * (1 - SSIM)/2 + (1 - ssim_weight) * L1` (paper: 0.85), Kornia's
  SSIM (`ssim_map`), averaged over the focus settings;
- sharpness: L1 between the sharpness maps (Sobel gradient magnitude) of the rendered and the real
  focused images (paper weight 0.1);
- smoothness: edge-aware first-order smoothness of the mean-normalised depth, down-weighted at
  image edges (paper weight 0.001);
- depth hints (optional; Watson et al., "Self-Supervised Monocular Depth Hints", ICCV 2019): a
  depth found without labels (the label-free estimator's, `models.depth_from_photos`) pulls
  the network's depth, in log depth, at the pixels where it renders the focused images better
  than the network's depth does. The photometric error stays the judge, so a wrong hint is
  ignored where the network does better; the hint only helps the network out of the loss's
  local minima (a blur that grows slowly with depth, flat regions). With the gate
  `"always"` the hint pulls at every pixel instead: for photos whose rendering the model
  explains imperfectly (real lenses), where a wrong depth can render better than the true one.
"""

from __future__ import annotations

import functools
import inspect
import math
import numbers
from typing import Any

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from optics import Aperture, CameraSettings, render_defocus, render_focal_stack
from optics.checks import check_shape

#: Keywords of `optics.render_defocus` that `DefocusLoss` may pass on (the others it sets).
RENDER_KEYWORDS = tuple(name for name in inspect.signature(render_defocus).parameters
                        if name not in ("image", "coc_px", "psf", "depth"))
#: Where a depth hint pulls: `"photometric"` where it renders the focused images better
#: than the network's depth (Watson et al.), `"always"` at every pixel.
HINT_GATES = ("photometric", "always")


def _check_weight(name: str, value: float, high: float = math.inf) -> float:
    """`value` as a float, refused unless a finite number in `[0, high]`."""
    try:
        number = math.nan if isinstance(value, bool | str | bytes) else float(value)
    except (TypeError, ValueError):
        number = math.nan
    if math.isnan(number) and not isinstance(value, float):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    if not (math.isfinite(number) and 0.0 <= number <= high):
        allowed = "in [0, 1]" if high == 1.0 else "finite and >= 0"
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return number


def _check_window_size(window_size: int) -> None:
    if isinstance(window_size, bool) or not isinstance(window_size, numbers.Integral) \
            or window_size < 1 or window_size % 2 == 0:
        raise ValueError(f"window_size must be an odd number of pixels >= 1, got {window_size!r}")


def _check_window_fits(names: str, tensor: Tensor, window_size: int) -> None:
    """Refuse images smaller than the SSIM window's reflected border needs (a shape check)."""
    _check_window_size(window_size)
    half = window_size // 2
    if min(tensor.shape[-2:]) <= half:
        raise ValueError(f"{names} must be at least {half + 1} x {half + 1} pixels for "
                         f"window_size={window_size} (reflected borders of {half} pixels), got "
                         f"H x W = {tensor.shape[-2]} x {tensor.shape[-1]}")


def _check_images(name: str, tensor: Tensor) -> None:
    """Refuse `(..., C, H, W)` images that hold no pixel (their mean would be NaN); a shape
    check only, no value is read."""
    if tensor.ndim < 3 or tensor.numel() == 0:
        raise ValueError(f"{name} must be non-empty (..., C, H, W) images, got shape "
                         f"{tuple(tensor.shape)}")


def _masked_mean(values: Tensor) -> Tensor:
    """Mean of `values`, 0 when there are none (e.g. horizontal differences of a 1-pixel-wide
    image): a shape test, no device sync."""
    return values.mean() if values.numel() else values.sum()


def photometric_loss(rendered: Tensor, target: Tensor, ssim_weight: float = 0.85,
                     window_size: int = 7) -> Tensor:
    """`ssim_weight * (1 - SSIM)/2 + (1 - ssim_weight) * L1`, averaged over pixels and images.

    Args:
        rendered: `(..., C, H, W)` images in [0, 1], at least one, each at least
            `window_size // 2 + 1` pixels high and wide (the SSIM's reflected border).
        target: same shape as `rendered`.
        ssim_weight: weight of the SSIM term in [0, 1] (paper: 0.85).
        window_size: odd SSIM window width in pixels.

    Raises:
        ValueError: for shapes that differ, no image, images too small for the window, or
            `ssim_weight` outside [0, 1] (shape and argument checks only: no value is read).

    Example:
        >>> x = torch.rand(2, 3, 16, 16)
        >>> round(float(photometric_loss(x, x)), 6)
        0.0
    """
    return photometric_error_map(rendered, target, ssim_weight, window_size).mean()


def photometric_error_map(rendered: Tensor, target: Tensor, ssim_weight: float = 0.85,
                          window_size: int = 7) -> Tensor:
    """The photometric error of each pixel, `(..., 1, H, W)`: `photometric_loss`'s terms
    averaged over the channels (their mean over pixels and images is `photometric_loss`).
    Arguments and refusals as `photometric_loss`'s.

    Example:
        >>> x = torch.rand(2, 3, 16, 16)
        >>> y = x.clone(); y[..., :8] = 0
        >>> error = photometric_error_map(x[None], y[None])
        >>> tuple(error.shape), bool(error[..., 11:].max() < 1e-6)  # beyond the window's reach
        ((1, 2, 1, 16, 16), True)
    """
    if rendered.shape != target.shape:
        raise ValueError(f"rendered and target must have the same shape, got "
                         f"{tuple(rendered.shape)} and {tuple(target.shape)}")
    _check_weight("ssim_weight", ssim_weight, 1.0)
    _check_images("rendered", rendered)
    _check_window_fits("rendered and target", rendered, window_size)
    r = rendered.reshape(-1, *rendered.shape[-3:])
    t = target.reshape(-1, *target.shape[-3:])
    ssim = ((1 - ssim_map(r, t, window_size)) / 2).clamp(0, 1)
    error = (ssim_weight * ssim + (1 - ssim_weight) * (r - t).abs()).mean(-3, keepdim=True)
    return error.reshape(*rendered.shape[:-3], 1, *rendered.shape[-2:])


def ssim_map(x: Tensor, y: Tensor, window_size: int = 7, max_val: float = 1.0) -> Tensor:
    """SSIM `(B, C, H, W)` of two image batches: Kornia's `kornia.metrics.ssim` (Gaussian window
    of sigma 1.5 px, reflected borders, `'same'` padding), its five local moments filtered in
    one pass.

    Kornia filters the five moments one after another: 65 operations for the forward pass (47
    for the backward). Filtered together as one stack they take 29 (`benchmarks/loss.py`),
    which a GPU training step, bound by the host issuing its operations, feels.

    Args:
        x: `(B, C, H, W)` images, `H` and `W` at least `window_size // 2 + 1` (reflected
            borders of `window_size // 2` pixels need that many).
        y: same shape as `x`.
        window_size: odd width of the Gaussian window, pixels.
        max_val: the images' dynamic range.

    Example:
        >>> import kornia
        >>> x, y = torch.rand(2, 3, 16, 16), torch.rand(2, 3, 16, 16)
        >>> bool(torch.allclose(ssim_map(x, y), kornia.metrics.ssim(x, y, 7), atol=1e-4))
        True
    """
    check_shape("x", x, ["B", "C", "H", "W"])
    if y.shape != x.shape:
        raise ValueError(f"x and y must have the same shape, got {tuple(x.shape)} and "
                         f"{tuple(y.shape)}")
    _check_window_fits("x and y", x, window_size)
    dtype = torch.promote_types(torch.promote_types(x.dtype, y.dtype), torch.float32)
    x, y = x.to(dtype), y.to(dtype)
    stack = torch.cat([x, y, x * x, y * y, x * y], 1)
    row = _gaussian_window(window_size, x.device, dtype).expand(stack.shape[1], 1, 1, window_size)
    half = window_size // 2
    with torch.autocast(device_type=x.device.type, enabled=False):
        rows = F.conv2d(F.pad(stack, [half] * 4, mode="reflect"), row, groups=stack.shape[1])
        moments = F.conv2d(rows, row.transpose(-1, -2), groups=stack.shape[1])
    mu_x, mu_y, xx, yy, xy = moments.chunk(5, 1)
    c1, c2 = (0.01 * max_val) ** 2, (0.03 * max_val) ** 2
    mu_xy = mu_x * mu_y
    mu_xx, mu_yy = mu_x * mu_x, mu_y * mu_y
    numerator = (2 * mu_xy + c1) * (2 * (xy - mu_xy) + c2)
    denominator = (mu_xx + mu_yy + c1) * (xx - mu_xx + yy - mu_yy + c2)
    return numerator / (denominator + 1e-12)


def _gaussian_window(window_size: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """Kornia's SSIM window `(1, 1, 1, window_size)` (sigma 1.5 px): made once per device in eager
    mode, a constant of the graph under `torch.compile`."""
    if torch.compiler.is_compiling():
        return _make_gaussian_window(window_size, device, dtype)
    return _cached_gaussian_window(window_size, device, dtype)


def _make_gaussian_window(window_size: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    kernel = kornia.filters.get_gaussian_kernel1d(window_size, 1.5, dtype=torch.float64)
    return kernel.to(device, dtype).reshape(1, 1, 1, window_size)


@functools.lru_cache(maxsize=32)
def _cached_gaussian_window(window_size: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    with torch.inference_mode(False):  # an inference tensor could not be saved for a backward
        return _make_gaussian_window(window_size, device, dtype)


def sharpness_map(image: Tensor) -> Tensor:
    """Local sharpness `(..., 1, H, W)`: Sobel gradient magnitude of the channel mean."""
    flat = image.reshape(-1, *image.shape[-3:]).mean(-3, keepdim=True)
    return kornia.filters.sobel(flat).reshape(*image.shape[:-3], 1, *image.shape[-2:])


def sharpness_loss(rendered: Tensor, target: Tensor) -> Tensor:
    """Mean L1 distance between the sharpness maps of `rendered` and `target`."""
    return (sharpness_map(rendered) - sharpness_map(target)).abs().mean()


def edge_aware_smoothness(depth: Tensor, image: Tensor) -> Tensor:
    """Edge-aware smoothness: `mean(|d_x d*| exp(-|d_x I|)) + mean(|d_y d*| exp(-|d_y I|))`.

    `d*` is the depth divided by its per-image mean (scale free) and `|d I|` the channel mean
    of the image's absolute differences. The mean is taken at least the dtype's machine epsilon
    (a depth of mean 0 or below stays finite; a mean depth above it is unchanged), and a
    direction without neighbours (`W = 1` or `H = 1`) adds 0.

    Args:
        depth: `(B,1,H,W)` metres, `B >= 1`.
        image: `(B,C,H,W)` of the depth's `B`, `H` and `W`.

    Raises:
        ValueError: for wrong or mismatched shapes or an empty batch (no value is read).

    Example:
        >>> float(edge_aware_smoothness(torch.full((1, 1, 8, 8), 3.0), torch.rand(1, 3, 8, 8)))
        0.0
    """
    check_shape("depth", depth, ["B", "1", "H", "W"])
    check_shape("image", image, ["B", "C", "H", "W"])
    if image.shape[0] != depth.shape[0] or image.shape[-2:] != depth.shape[-2:]:
        raise ValueError(f"image must have the depth's B, H and W, got {tuple(image.shape)} "
                         f"for depth {tuple(depth.shape)}")
    _check_images("depth", depth)
    mean = depth.mean((2, 3), keepdim=True).clamp_min(torch.finfo(depth.dtype).eps)
    d = depth / mean
    dx, dy = (d[..., :, 1:] - d[..., :, :-1]).abs(), (d[..., 1:, :] - d[..., :-1, :]).abs()
    ix = (image[..., :, 1:] - image[..., :, :-1]).abs().mean(1, keepdim=True)
    iy = (image[..., 1:, :] - image[..., :-1, :]).abs().mean(1, keepdim=True)
    return _masked_mean(dx * torch.exp(-ix)) + _masked_mean(dy * torch.exp(-iy))


class DefocusLoss(nn.Module):
    """The paper's self-supervised loss: photometric + sharpness + smoothness.

    Args:
        ssim_weight: SSIM share of the photometric term in [0, 1] (paper: 0.85).
        sharpness_weight: weight of the sharpness-map L1 term, finite and >= 0 (paper: 0.1).
        smoothness_weight: weight of the edge-aware depth smoothness, finite and >= 0
            (paper: 0.001).
        window_size: odd SSIM window width in pixels.
        hint_weight: weight of the depth-hint term, finite and >= 0 (0: off; used where
            `forward` gets a `hint`).
        hint_gate: where the hint pulls, one of `HINT_GATES`: `"photometric"` (where it
            renders the focused images better than the network's depth) or `"always"`.
        aperture: PSF shape used to render, overriding the settings' aperture (None: use the
            aperture of the `CameraSettings` passed to `forward`).
        **render_kwargs: passed to `optics.render_defocus`: `RENDER_KEYWORDS` (`mode`,
            `max_kernel_size`, ...).

    Raises:
        ValueError: at construction, for a weight out of its range, an even or non-positive
            `window_size`, an unknown `hint_gate`, or a keyword `optics.render_defocus` does
            not take.

    Example:
        >>> loss = DefocusLoss()
        >>> settings = CameraSettings(0.05, 2.0, [[2.0, 6.0]], 180e-6)
        >>> image, depth = torch.rand(1, 3, 16, 16), torch.full((1, 1, 16, 16), 3.0)
        >>> focused = render_focal_stack(image, depth, settings)
        >>> round(float(loss(depth, image, focused, settings)["loss"]), 6)
        0.0
    """

    def __init__(self, ssim_weight: float = 0.85, sharpness_weight: float = 0.1,
                 smoothness_weight: float = 0.001, window_size: int = 7,
                 aperture: Aperture | None = None, hint_weight: float = 0.0,
                 hint_gate: str = "photometric", **render_kwargs: Any):
        super().__init__()
        unknown = sorted(set(render_kwargs) - set(RENDER_KEYWORDS))
        if unknown:
            raise ValueError(f"DefocusLoss got unknown keyword argument(s) {unknown}; the "
                             f"renderer takes {list(RENDER_KEYWORDS)}")
        _check_window_size(window_size)
        self.ssim_weight = _check_weight("ssim_weight", ssim_weight, 1.0)
        self.sharpness_weight = _check_weight("sharpness_weight", sharpness_weight)
        self.smoothness_weight = _check_weight("smoothness_weight", smoothness_weight)
        self.hint_weight = _check_weight("hint_weight", hint_weight)
        if hint_gate not in HINT_GATES:
            raise ValueError(f"hint_gate must be one of {HINT_GATES}, got {hint_gate!r}")
        self.hint_gate = hint_gate
        self.window_size = int(window_size)
        self.aperture = aperture
        self.render_kwargs = render_kwargs

    def forward(self, depth: Tensor, image: Tensor, focused: Tensor,
                settings: CameraSettings, hint: Tensor | None = None) -> dict[str, Tensor]:
        """Loss terms for predicted `depth` `(B,1,H,W)` metres, all-in-focus `image`
        `(B,3,H,W)`, real `focused` images `(B,F,3,H,W)` and their `(B,F)` settings; `hint`
        `(B,1,H,W)` metres > 0, a depth found without labels (used when `hint_weight` > 0).

        Returns:
            dict with `loss` (the weighted total), `photometric`, `sharpness`, `smoothness`,
            and with a hint `hint` (the mean log-depth L1 to the hint over all pixels, 0 where
            the gate keeps the hint out) and `hint_share` (the share of pixels where it pulls:
            where the hint renders better, or 1 with the gate `"always"`).

        Example:
            >>> settings = CameraSettings(0.05, 2.0, [[2.0, 6.0]], 180e-6)
            >>> image, depth = torch.rand(1, 3, 16, 16), torch.full((1, 1, 16, 16), 3.0)
            >>> focused = render_focal_stack(image, depth, settings)
            >>> terms = DefocusLoss(hint_weight=1.0)(depth * 2, image, focused, settings, depth)
            >>> round(float(terms["hint"]), 4), float(terms["hint_share"])  # log 2
            (0.6931, 1.0)
        """
        check_shape("focused", focused, ["B", "F", "C", "H", "W"])
        rendered = render_focal_stack(image, depth, settings, self.aperture, **self.render_kwargs)
        error = photometric_error_map(rendered, focused, self.ssim_weight, self.window_size)
        photometric = error.mean()
        sharpness = sharpness_loss(rendered, focused)
        smoothness = edge_aware_smoothness(depth, image)
        terms = {"photometric": photometric, "sharpness": sharpness, "smoothness": smoothness}
        total = (photometric + self.sharpness_weight * sharpness
                 + self.smoothness_weight * smoothness)
        if hint is not None and self.hint_weight > 0:
            terms.update(self._hint_terms(depth, hint, error.mean(1), image, focused, settings))
            total = total + self.hint_weight * terms["hint"]
        return {"loss": total, **terms}

    def _hint_terms(self, depth: Tensor, hint: Tensor, error: Tensor, image: Tensor,
                    focused: Tensor, settings: CameraSettings) -> dict[str, Tensor]:
        """The depth-hint terms: `error` `(B,1,H,W)` is the network depth's photometric error
        per pixel, over the focus settings."""
        pull = (depth.log() - hint.log()).abs()
        if self.hint_gate == "always":
            return {"hint": pull.mean(), "hint_share": pull.new_ones(())}
        with torch.no_grad():
            hinted = render_focal_stack(image, hint, settings, self.aperture,
                                        **self.render_kwargs)
            better = photometric_error_map(hinted, focused, self.ssim_weight,
                                           self.window_size).mean(1) < error
        return {"hint": torch.where(better, pull, torch.zeros_like(pull)).mean(),
                "hint_share": better.float().mean()}

    def extra_repr(self) -> str:
        return (f"ssim_weight={self.ssim_weight}, sharpness_weight={self.sharpness_weight}, "
                f"smoothness_weight={self.smoothness_weight}, window_size={self.window_size}, "
                f"hint_weight={self.hint_weight}, hint_gate={self.hint_gate!r}")


def supervised_depth_loss(depth: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean relative L1 error `|depth - target| / target` over valid pixels (a baseline that
    uses depth labels; not part of the self-supervised recipe).

    Pixels outside `mask` add exactly 0 to the loss and get a gradient of 0, whatever `depth`
    and `target` hold there (0, infinity or NaN labels of missing measurements): they are
    replaced, not multiplied by 0. No value is read (no device sync).

    Args:
        depth: predicted depth, metres.
        target: ground truth of the same shape, metres, > 0 where `mask` is set.
        mask: optional mask of the same shape (boolean, or weights where non-zero counts).

    Raises:
        ValueError: for shapes that differ.

    Example:
        >>> float(supervised_depth_loss(torch.full((1, 1, 2, 2), 3.0), torch.full((1, 1, 2, 2), 2.0)))
        0.5
        >>> target = torch.tensor([[2.0, 0.0]])  # the second label is missing
        >>> float(supervised_depth_loss(torch.tensor([[3.0, 1.0]]), target, target > 0))
        0.5
    """
    refused = f"depth and target must have the same shape, got {tuple(depth.shape)} and " \
        f"{tuple(target.shape)}" if depth.shape != target.shape else \
        f"mask must have the target's shape {tuple(target.shape)}, got {tuple(mask.shape)}" \
        if mask is not None and mask.shape != target.shape else None
    if refused:
        raise ValueError(refused)
    if mask is None:
        return ((depth - target).abs() / target).mean()
    keep = mask if mask.dtype == torch.bool else mask != 0
    safe_target = torch.where(keep, target, torch.ones_like(target))
    safe_depth = torch.where(keep, depth, safe_target)  # outside: error 0, gradient 0
    error = (safe_depth - safe_target).abs() / safe_target
    weight = mask.to(error.dtype)
    return (error * weight).sum() / weight.sum().clamp_min(1.0)
