r"""Per-pixel PSF rendering: blur an image with a point spread function that varies per pixel.

Every pixel has its own circle of confusion (CoC, diameter in pixels, from `Camera.coc_px`) and
the aperture gives the PSF shape for it. Three semantics:

| mode | output pixel `p` | handles |
|---|---|---|
| `gather` | `sum_q I(q) k(p-q; c_p) / sum_q k(p-q; c_p)`: the output pixel's own PSF | spatial variation; sharp pixels never blur |
| `scatter` | `sum_q I(q) w_q(p-q) / sum_q w_q(p-q)`, `w_q = k(.; c_q) / Z_q`: each source spreads its own PSF, normalised per output | spatial variation (the paper's layer); the default |
| `layered` | depth layers (soft, in inverse depth) each scattered with its own CoCs and composited front to back with alpha | spatial variation and occlusion: no blurred background over a sharp foreground edge |

`Z_q` is the discrete sum of the source's profile over its whole window, so each source spreads
unit energy over the pixel grid (not a continuous formula). Taps outside the image are skipped
and every mode divides by the weight an output actually receives, so a constant image stays
constant up to the borders.

Cost: `O(B C H W K^2)` time and `O(B C H W)` extra memory (`L` times that for `L` layers; no
`K^2` copies of the image: the window offsets are visited in a loop and the weights recomputed
in the backward pass).

Speed: the Gaussian (a separable per-source table) and the disk and polygons (a clamped distance,
`clamp(edge_radius(c_q) + 1/2 - D(u), 0, 1)` with the distance `D` tabulated once per call) run
as `torch.library` custom operators (`optics.render.ops`) backed, on CPU, by a compiled C++
kernel when a compiler is available (`optics.render.cpp`), on CUDA by Triton kernels for the
default scatter mode (`optics.render.triton_kernels`, where Triton is installed), and by PyTorch
loops elsewhere; `optics.render.backends` registers them and says which runs where.
`torch.compile(render_defocus, fullgraph=True)` traces those apertures forward and backward
without graph breaks. Other apertures (`Mask`, user subclasses with their own `profile`) run in
PyTorch, their `profile` tabulated in the CoC and interpolated (`optics.render.profile`).
"""

from __future__ import annotations

import math
import warnings

import torch
from torch import Tensor, nn

from ..aperture import MIN_SIGMA_PX, Aperture, Disk, Gaussian
from ..checks import check_finite, check_tensor, is_tracing, require
from . import backends, layer_ops, ops, triton_kernels
from .profile import ProfileFilter

MODES = ("gather", "scatter", "layered")
PRESETS = ("gur_wolf_2019",)
#: Gur & Wolf (2019): CoC range in pixels and the fixed window half-width (7x7).
PAPER_COC_RANGE = (1.0, 7.0)
PAPER_HALF_WIDTH = 3
#: The dimensions of an image.
IMAGE_DIMS = ("B", "C", "H", "W")


def render_defocus(
    image: Tensor,
    coc_px: Tensor,
    psf: Aperture | None = None,
    mode: str = "scatter",
    depth: Tensor | None = None,
    max_kernel_size: int = 63,
    preset: str | None = None,
    n_layers: int = 8,
) -> Tensor:
    r"""Render defocus blur with a per-pixel PSF.

    The window is `K x K` pixels with `K = psf.kernel_size(max CoC)` (`2 ceil(3 sigma) + 1`
    for a Gaussian), capped at `max_kernel_size`. **Beyond the cap the PSFs are truncated** to the
    `max_kernel_size` window and renormalised over it (scatter: each source's weights sum to one
    over the truncated window), so the blur is narrower than the optics say; a `UserWarning`
    says so.

    Args:
        image: `(B, C, H, W)` image, linear intensity.
        coc_px: `(B, 1, H, W)` (or `(1, 1, H, W)`) CoC *diameter* in pixels, finite, >= 0. For the
            Gaussian, `sigma_px = psf.scale * coc_px` (0.5 by default: sigma = CoC radius). For
            an `oriented` aperture (a `Mask`) the signed CoC, negative nearer than the focus
            plane, where the PSF is the mask point-reflected (`Camera.render` passes it).
        psf: aperture shape (`Gaussian`, `Disk`, `Polygon`, `Mask`, ...); `Gaussian()` by default.
        mode: `"scatter"` (default, the paper's), `"gather"` or `"layered"` (see the module
            table).
        depth: `(B, 1, H, W)` depth in metres; needed by `"layered"` only (orders the layers).
        max_kernel_size: largest window width in pixels, a positive odd integer.
        preset: `"gur_wolf_2019"` reproduces the paper's layer exactly: Gaussian with sigma =
            CoC/2, weight of source `q` on output `p` equal to `c_q^-2 exp(-2 |p-q|^2 /
            c_q^2)` with `c` clamped to [1, 7] px, a 7x7 window, pixels with CoC <= 1 copied
            unchanged and left out of their neighbours' sums, out-of-image taps skipped, division
            by the total weight each output receives. It fixes the PSF, window and semantics, so
            `psf` must be `None` or `Gaussian(0.5)` and `mode` `"scatter"`.
        n_layers: number of depth layers of the `"layered"` mode, spread evenly in inverse depth
            between the nearest and farthest pixel of each image; a pixel between two layer depths
            is shared between them linearly (so the result is differentiable in the depth).

    Returns:
        `(B, C, H, W)` rendered image, dtype and device of `image`. Differentiable in
        `image`, `coc_px`, `depth` (layered) and the aperture's parameters.

    Raises:
        TypeError: if `image`, `coc_px` or `depth` is not a floating-point tensor, or `psf`
            is not an `Aperture`.
        ValueError: on wrong shapes, a negative, NaN or infinite CoC, an unknown `mode` or
            `preset`, an invalid `max_kernel_size` or `n_layers`, or `"layered"` without `depth`.

    Under `torch.compile(render_defocus, fullgraph=True)` (Gaussian, disk and polygon PSFs) the
    window is computed inside the graph, the truncation warning is not given and invalid CoC or
    depth values fail in an in-graph assertion instead of a `ValueError`.

    Example:
        >>> image = torch.zeros(1, 1, 7, 7)
        >>> image[..., 3, 3] = 1.0
        >>> out = render_defocus(image, torch.full((1, 1, 7, 7), 2.0))
        >>> out[0, 0, 3, 2:5]
        tensor([0.0970, 0.1592, 0.0970])
    """
    check_tensor("image", image, IMAGE_DIMS, floating=True)
    coc_px = per_pixel_map("coc_px", coc_px, image)
    if mode == "layered":
        if depth is None:
            raise ValueError("mode='layered' needs depth, a (B, 1, H, W) tensor in metres")
        depth = per_pixel_map("depth", depth, image)
    return render_trusted(image, coc_px, psf, mode, depth, max_kernel_size, preset, n_layers)


def render_trusted(image: Tensor, coc_px: Tensor, psf: Aperture | None = None,
                   mode: str = "scatter", depth: Tensor | None = None, max_kernel_size: int = 63,
                   preset: str | None = None, n_layers: int = 8,
                   depth_checked: bool = False) -> Tensor:
    """`render_defocus` behind its door: `image` and `coc_px` `(B, 1, H, W)` checked and
    broadcast (`per_pixel_map`), `depth` too in the layered mode, its values checked already
    where `depth_checked` (`Camera.render`). The options are checked here; the image's and the
    CoC's values in the one read that gives the window's size."""
    _check_options(psf, mode, max_kernel_size, preset, n_layers)
    depth = depth if mode == "layered" else None
    psf = Gaussian() if psf is None else psf
    on_device = preset is None and _window_on_device(psf, image)
    largest_coc = _read_checked(image, coc_px, None if depth_checked else depth,
                                need_largest=not on_device, signed=psf.oriented)
    if preset is not None:
        return _render_paper(image, coc_px)
    half = _window_half(psf, coc_px, max_kernel_size, largest_coc, on_device)
    if mode == "layered":
        return _render_layered(image, coc_px, psf, half, depth, n_layers, max_kernel_size // 2)
    kind = _fast_kind(psf)
    if mode == "scatter" and kind == "gaussian":  # fused: spread, normalisation, division
        return ops.gaussian_render(image, psf.sigma_px(coc_px), _half_tensor(half))[0]
    if mode == "scatter" and kind == "clamp":
        rho = psf.edge_radius(coc_px) + 0.5  # profile = clamp(rho - distance, 0, 1)
        dist = _distance_table(psf, half, max_kernel_size // 2, image)
        return ops.clamp_render(image, rho, dist, _half_tensor(half))[0]
    ones = torch.ones_like(image[:, :1])
    spread = _linear_filter(
        torch.cat([image, ones], 1), coc_px, psf, half, mode == "scatter", max_kernel_size // 2
    )
    return spread[:, :-1] / spread[:, -1:]


def _compiling() -> bool:
    return torch.compiler.is_compiling()


def _fast_kind(psf: Aperture) -> str | None:
    """Which custom operators render `psf`: "gaussian", "clamp" (disk, polygons) or None."""
    if type(psf) is Gaussian:
        return "gaussian"
    if isinstance(psf, Disk) and type(psf).profile is Disk.profile:
        return "clamp"
    return None


def _window_on_device(psf: Aperture, image: Tensor) -> bool:
    """Whether the window's half-width is computed on the image's device and handed to the
    kernels as a tensor, never read by the host: under `torch.compile` (a graph cannot read it)
    and, on a GPU with the Triton kernels, inside `values_checked` (a training step: a read
    would wait for every queued kernel). For the Gaussian, the disk and polygons."""
    if _fast_kind(psf) is None or type(psf).half_width not in (Gaussian.half_width,
                                                                Disk.half_width):
        return False
    return _compiling() or (is_tracing() and image.is_cuda and triton_kernels.available())


def _window_half(psf: Aperture, coc_px: Tensor, max_kernel_size: int,
                 largest_coc: float | None, on_device: bool = False) -> int | Tensor:
    """Window half-width: a Python int for the `largest_coc` in pixels, or (`on_device`, see
    `_window_on_device`) a 0-d tensor computed on the device.

    The tensor form repeats `half_width` in float64, which is what the Python floats are, so both
    give the same window.
    """
    cap = max_kernel_size // 2
    kind = _fast_kind(psf)
    if on_device:
        largest = coc_px.detach().amax().double()
        if kind == "gaussian":
            sigma = (psf.scale.detach().double() * largest).clamp_min(MIN_SIGMA_PX)
            half = torch.where(
                sigma > MIN_SIGMA_PX, torch.ceil(3 * sigma - 1e-9), torch.zeros_like(sigma)
            )
        else:
            half = torch.ceil(largest / 2 - 0.5 - 1e-9)
        return half.clamp(0, cap).to(torch.int64)
    max_coc = float(coc_px.detach().max()) if largest_coc is None else largest_coc
    half = min(psf.half_width(max_coc), cap)
    if psf.half_width(max_coc) > half:
        warnings.warn(
            f"render_defocus: the largest CoC ({max_coc:.3g} px) needs a "
            f"{psf.kernel_size(max_coc)}-pixel window; PSFs are truncated to "
            f"max_kernel_size={max_kernel_size}",
            stacklevel=3,
        )
    return half


def _check_options(psf, mode, max_kernel_size, preset, n_layers) -> None:
    """`render_defocus`'s options, checked (also by `DefocusRenderer` when it is built)."""
    for name, value, allowed in (("mode", mode, MODES), ("preset", preset, (None, *PRESETS))):
        if value not in allowed:
            none = "None or " if name == "preset" else ""
            raise ValueError(f"{name} must be {none}one of {tuple(filter(None, allowed))}, "
                             f"got {value!r}")
    if psf is not None and not isinstance(psf, Aperture):
        raise TypeError(f"psf must be an Aperture (Gaussian, Disk, ...), got {type(psf).__name__}")
    for name, value, odd in (("max_kernel_size", max_kernel_size, True),
                             ("n_layers", n_layers, False)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1 or \
                (odd and value % 2 == 0):
            raise ValueError(f"{name} must be a positive {'odd ' if odd else ''}integer, "
                             f"got {value!r}")
    if preset is not None and (mode != "scatter" or not (psf is None or (
            type(psf) is Gaussian and math.isclose(float(psf.scale), 0.5)))):
        raise ValueError(f"preset={preset!r} fixes a Gaussian PSF (scale 0.5) in scatter "
                         f"mode, got psf={psf!r} and mode={mode!r}")


def per_pixel_map(name: str, values: Tensor, image: Tensor) -> Tensor:
    """A `(B or 1, 1, H, W)` floating-point map of `image`'s pixels (shape and type checked;
    its values by `_read_checked`), on its device, in its dtype and broadcast to its batch.

    Example:
        >>> per_pixel_map("depth", torch.ones(2, 1, 4, 4), torch.zeros(1, 3, 4, 4))
        Traceback (most recent call last):
        ...
        ValueError: depth must have shape (1, 1, 4, 4) to match image (1, 3, 4, 4), got (2, 1, 4, 4)
    """
    check_tensor(name, values, ["B", "1", "H", "W"], floating=True)
    b, _, h, w = image.shape
    if values.shape[2:] != image.shape[2:] or values.shape[0] not in (1, b):
        batch = "1" if b == 1 else f"{b} or 1"
        raise ValueError(f"{name} must have shape ({batch}, 1, {h}, {w}) to match image "
                         f"{tuple(image.shape)}, got {tuple(values.shape)}")
    if values.device != image.device:
        raise ValueError(f"{name} is on {values.device} but image on {image.device}; use one device")
    return values.to(image.dtype).expand(b, 1, h, w)


def _read_checked(image: Tensor, coc_px: Tensor, depth: Tensor | None,
                  need_largest: bool = True, signed: bool = False) -> float | None:
    """The largest CoC in pixels, once the image is checked finite, the CoC finite and >= 0
    (`signed`, an oriented aperture's: finite, the largest of its magnitude) and
    `depth` (layered mode) > 0 metres and not NaN: one read from the device for all (on a GPU
    each read waits for every queued kernel). Under `torch.compile`: None, the checks asserted
    in the graph; under `values_checked`: the largest CoC alone, or nothing (None) unless
    `need_largest`."""
    coc_message = f"coc_px must be finite{'' if signed else ' and >= 0 px'} everywhere (no NaN/inf)"
    depth_message = "depth must be > 0 metres and not NaN everywhere"
    if _compiling():
        torch._assert_async(_all_valid_coc(coc_px, signed), coc_message)
        if depth is not None:
            torch._assert_async(_all_valid_depth(depth), depth_message)
        return None
    checking = not is_tracing()  # `values_checked`: the window's size alone, if it is needed
    if not (checking or need_largest):
        return None
    coc = coc_px.detach()
    largest = (coc.abs() if signed else coc).amax() if coc.numel() else coc.new_zeros(())
    if not checking:
        return float(largest)
    # a NaN or an infinity in the image makes its sum not finite (see `check_finite`)
    read = [largest, _all_valid_coc(coc, signed),
            image.detach().sum(dtype=torch.promote_types(image.dtype, torch.float32))]
    if depth is not None:
        read.append(_all_valid_depth(depth))
    largest, coc_valid, image_sum, *depth_valid = torch.stack(
        [v.to(torch.float64) for v in read]).tolist()
    if not math.isfinite(image_sum):
        check_finite("image", image)  # names the bad values (a sum that overflowed passes)
    if not coc_valid:
        require("coc_px", coc, "signed coc" if signed else "coc", "pixels")  # raises, describing
    if depth_valid and not depth_valid[0]:
        check_tensor("depth", depth, values="depth")  # raises, describing the values
    return largest


def _all_valid_coc(coc: Tensor, signed: bool = False) -> Tensor:
    """True (a 0-d tensor) where every CoC is finite and >= 0 pixels (`signed`: finite)."""
    finite = torch.isfinite(coc)
    return torch.all(finite if signed else finite & (coc >= 0))


def _all_valid_depth(depth: Tensor) -> Tensor:
    """True (a 0-d tensor) where every depth is > 0 metres and not NaN."""
    return torch.all(~torch.isnan(depth) & (depth > 0))


def _half_tensor(half: int | Tensor) -> Tensor:
    return half if isinstance(half, Tensor) else torch.tensor(half, dtype=torch.int64)


def _distance_table(psf: Disk, half: int | Tensor, cap: int, like: Tensor) -> Tensor:
    """The aperture's distance on a square window: `2 half + 1` wide, or `2 cap + 1` in a graph."""
    size = cap if isinstance(half, Tensor) else half
    offsets = torch.arange(-size, size + 1, device=like.device, dtype=like.dtype)
    return psf.distance(offsets.view(-1, 1), offsets.view(1, -1)).detach()


def _linear_filter(
    x: Tensor, coc_px: Tensor, psf: Aperture, half: int | Tensor, scatter: bool, cap: int = 0
) -> Tensor:
    """Unnormalised spread of `x` (scatter: unit energy per source; gather: raw profile)."""
    kind = _fast_kind(psf)
    if kind == "gaussian":
        sigma = psf.sigma_px(coc_px)
        half_t = _half_tensor(half)
        if not scatter:
            return ops.gaussian_gather(x, sigma, half_t)
        return ops.gaussian_scatter(x, sigma, ops.gaussian_norm(sigma, half_t), half_t)
    if kind == "clamp":
        rho = psf.edge_radius(coc_px) + 0.5  # profile = clamp(rho - distance, 0, 1)
        dist = _distance_table(psf, half, cap, x)
        half_t = _half_tensor(half)
        if not scatter:
            return ops.clamp_gather(x, rho, dist, half_t)
        return ops.clamp_scatter(x, rho, ops.clamp_norm(rho, dist, half_t), dist, half_t)
    params = [p for p in psf.parameters() if p.requires_grad]
    return ProfileFilter.apply(x, coc_px, psf, scatter, int(half), *params)


def _render_paper(image: Tensor, coc_px: Tensor) -> Tensor:
    low, high = PAPER_COC_RANGE
    coc = coc_px.clamp(low, high)
    active = coc_px > low
    norm = torch.where(active, coc.pow(-2), torch.zeros_like(coc))
    ones = torch.ones_like(image[:, :1])
    spread = ops.gaussian_scatter(
        torch.cat([image, ones], 1), coc / 2, norm, _half_tensor(PAPER_HALF_WIDTH)
    )
    total = torch.where(active, spread[:, -1:], torch.ones_like(coc))
    return torch.where(active, spread[:, :-1] / total, image)


def layer_weights(depth: Tensor, n_layers: int) -> Tensor:
    """Soft assignment of each pixel to `n_layers` depth layers, front (nearest) first.

    Layers sit evenly in inverse depth between each image's nearest and farthest pixel; a pixel
    between two layers is split linearly between them. Returns `(B, L, H, W)` weights summing
    to 1 per pixel.

    Example:
        >>> layer_weights(torch.tensor([1.0, 2.0, 4.0]).view(1, 1, 1, 3), 2)[0, :, 0]
        tensor([[1.0000, 0.3333, 0.0000],
                [0.0000, 0.6667, 1.0000]])
    """
    position = _layer_position(depth, n_layers)
    centres = torch.arange(n_layers, device=depth.device, dtype=depth.dtype).view(1, -1, 1, 1)
    return (1 - (position - centres).abs()).clamp_min(0)


def _layer_position(depth: Tensor, n_layers: int) -> Tensor:
    """Continuous layer index in `[0, n_layers - 1]` per pixel, `(B, 1, H, W)`: 0 is the nearest."""
    inverse = 1.0 / depth
    near = inverse.amax(dim=(1, 2, 3), keepdim=True)
    far = inverse.amin(dim=(1, 2, 3), keepdim=True)
    step = ((near - far) / max(n_layers - 1, 1)).clamp_min(torch.finfo(depth.dtype).tiny)
    return ((near - inverse) / step).clamp(0, n_layers - 1)


def _render_layered(image, coc_px, psf, half, depth, n_layers, cap) -> Tensor:
    """The layered mode on inputs checked by `render_defocus`."""
    if image.numel() == 0:  # H or W = 0: no depth range to split into layers, nothing to blur
        return image.clone()
    kind = _fast_kind(psf)
    if kind is not None and n_layers <= 32 and backends.compiled_cpu(image):
        # One fused pass each way: layers present nowhere near a pixel cost nothing there.
        pos = _layer_position(depth, n_layers)
        half_t = _half_tensor(half)
        if kind == "gaussian":
            param, dist = psf.sigma_px(coc_px), image.new_zeros(1, 1)
        else:
            param, dist = psf.edge_radius(coc_px) + 0.5, _distance_table(psf, half, cap, image)
        return layer_ops.layered_render(image, pos, param, dist, half_t, n_layers, kind)[0]
    layers = split_layers(image, depth, n_layers)
    return composite_layers(_linear_filter(layers, coc_px, psf, half, True, cap), n_layers)


def split_layers(image: Tensor, depth: Tensor, n_layers: int) -> Tensor:
    """The layered mode's input: per depth layer (front first) the image premultiplied by the
    layer's weight, then the weight: `(B, n_layers * (C + 1), H, W)`."""
    b, _, h, w = image.shape
    alpha = layer_weights(depth, n_layers)  # (B, L, H, W), front first
    layers = torch.cat([alpha.unsqueeze(2) * image.unsqueeze(1), alpha.unsqueeze(2)], 2)
    return layers.reshape(b, -1, h, w)


def composite_layers(spread: Tensor, n_layers: int) -> Tensor:
    """Composite blurred layers (`split_layers` layout) front to back: each layer's colour is
    seen through the transmittance left by the layers in front; normalised by the coverage.

    The backward pass is written out (`_CompositeLayers`): about 25 operations for any number
    of layers, where autograd through the product over layers issues over 100 (on a GPU each is
    a launch the host must issue).

    Example:
        >>> front = torch.tensor([1.0, 1.0]).view(1, 2, 1, 1)  # colour 1, full coverage
        >>> back = torch.tensor([5.0, 1.0]).view(1, 2, 1, 1)  # hidden behind it
        >>> composite_layers(torch.cat([front, back], 1), 2).flatten()
        tensor([1.])
    """
    if spread.shape[1] % n_layers:
        raise ValueError(f"spread has {spread.shape[1]} channels, not a multiple of "
                         f"n_layers={n_layers}")
    return _CompositeLayers.apply(spread, n_layers)


class _CompositeLayers(torch.autograd.Function):
    """`composite_layers` with its gradient in closed form.

    With `clear_l = 1 - min(coverage_l, 1)` and `seen_l = prod_{k<l} clear_k`, the total is
    `T = sum_l seen_l spread_l`; a layer's coverage also dims every layer behind it:
    `dL/dclear_l = seen_l R_l`, `R_l = g_{l+1} + clear_{l+1} R_{l+1}` (`R_{L-1} = 0`), where
    `g_m = <dL/dT, spread_m>`, a recursion with no division (a fully covering layer is exact).
    """

    @staticmethod
    def forward(ctx, spread: Tensor, n_layers: int) -> Tensor:
        b, _, h, w = spread.shape
        layers = spread.view(b, n_layers, -1, h, w)
        clear = 1 - layers[:, :, -1:].clamp(max=1.0)  # (B, L, 1, H, W): what each layer lets by
        seen = torch.cumprod(torch.cat([torch.ones_like(clear[:, :1]), clear[:, :-1]], 1), 1)
        total = (seen * layers).sum(1)  # colour, then coverage
        out = total[:, :-1] / total[:, -1:].clamp_min(torch.finfo(spread.dtype).tiny)
        ctx.save_for_backward(layers, clear, seen, total, out)
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor, None]:
        layers, clear, seen, total, out = ctx.saved_tensors
        b, n_layers, _, h, w = layers.shape
        tiny = torch.finfo(layers.dtype).tiny
        coverage = total[:, -1:]
        grad_colour = grad_out / coverage.clamp_min(tiny)
        grad_coverage = -(grad_colour * out).sum(1, keepdim=True) * (coverage >= tiny)
        grad_total = torch.cat([grad_colour, grad_coverage], 1)[:, None]  # (B, 1, C + 1, H, W)
        grad_layers = seen * grad_total
        through = (grad_total * layers).sum(2, keepdim=True)  # dL/dseen, (B, L, 1, H, W)
        behind = [torch.zeros_like(through[:, 0])]  # R_l, from the back layer forward
        for layer in range(n_layers - 2, -1, -1):
            behind.append(torch.addcmul(through[:, layer + 1], clear[:, layer + 1], behind[-1]))
        grad_clear = seen * torch.stack(behind[::-1], 1)
        grad_layers[:, :, -1:] -= grad_clear * (layers[:, :, -1:] <= 1)
        return grad_layers.view(b, -1, h, w), None


class DefocusRenderer(nn.Module):
    """Module form of `render_defocus`: stores the PSF and the options.

    Args:
        psf: aperture shape, `Gaussian()` by default.
        mode: `"scatter"`, `"gather"` or `"layered"`.
        max_kernel_size: largest window width in pixels (odd).
        preset: `None` or `"gur_wolf_2019"`.
        n_layers: depth layers of the layered mode.

    Example:
        >>> renderer = DefocusRenderer(Disk(), mode="gather")
        >>> renderer(torch.rand(2, 3, 16, 16), torch.full((2, 1, 16, 16), 3.0)).shape
        torch.Size([2, 3, 16, 16])
    """

    def __init__(
        self,
        psf: Aperture | None = None,
        mode: str = "scatter",
        max_kernel_size: int = 63,
        preset: str | None = None,
        n_layers: int = 8,
    ):
        super().__init__()
        _check_options(psf, mode, max_kernel_size, preset, n_layers)
        self.psf = Gaussian() if psf is None and preset is None else psf
        self.mode, self.max_kernel_size = mode, max_kernel_size
        self.preset, self.n_layers = preset, n_layers

    def extra_repr(self) -> str:
        return (f"mode={self.mode!r}, max_kernel_size={self.max_kernel_size}, "
                f"preset={self.preset!r}, n_layers={self.n_layers}")

    def forward(self, image: Tensor, coc_px: Tensor, depth: Tensor | None = None) -> Tensor:
        return render_defocus(
            image, coc_px, self.psf, self.mode, depth, self.max_kernel_size, self.preset,
            self.n_layers,
        )
