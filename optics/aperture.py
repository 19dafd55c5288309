"""Aperture shapes: the point spread function (PSF) of a defocused point, as a function of its CoC.

Every aperture is a small `nn.Module` with one primitive, `Aperture.profile`: the
unnormalised PSF value at an integer pixel offset `(dy, dx)` for a CoC *diameter* in pixels. It
broadcasts, so the renderer evaluates it for a whole CoC map at one offset at a time and
`Aperture.kernel` evaluates it on a grid of offsets for one CoC per batch item. Profiles are
differentiable in the CoC (the disk and polygon have an anti-aliased edge one pixel wide for this).

An `oriented` aperture (`Mask`, `optics.LearnableMask`: any code that is not point-symmetric)
takes the *signed* CoC: a point beyond the focus plane (CoC > 0) sees the mask as given, a
nearer one (CoC < 0) sees it point-reflected, as a thin lens images the aperture on either side
of focus. So a depth and its mirror across the focus plane blur alike only through a symmetric
aperture; `Camera.render` hands an oriented aperture the signed CoC.

=============  ===========================================  =================================
aperture       profile at distance `r` (pixels)          window half-width (pixels)
=============  ===========================================  =================================
`Gaussian`   `exp(-r^2 / (2 sigma^2))`,                 `ceil(3 sigma)`
               `sigma = scale * coc`
`Disk`       `clamp(coc/2 - r + 1/2, 0, 1)`             `ceil(coc/2 - 1/2)`
`Polygon`    as the disk, with a polygonal norm           `ceil(coc/2 - 1/2)`
`Mask`       the mask image stretched to `coc` across   `ceil(coc/2)`
=============  ===========================================  =================================
"""

from __future__ import annotations

import abc
import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .checks import is_real_number, require

#: The most blades of a `Polygon` (real irises have 5-20; a polygon of many more is a disk, and
#: its kernel would cost memory in proportion).
MAX_BLADES = 64
#: The largest `Gaussian` scale (sigma per CoC diameter; the paper's is 0.5, fitted lenses
#: 0.25-1): beyond it the kernel holds far more than the blur.
MAX_GAUSSIAN_SCALE = 5.0

#: Smallest Gaussian sigma in pixels: below it the PSF is a delta to working precision.
MIN_SIGMA_PX = 1e-2
#: Smallest disk radius in pixels used as a divisor.
MIN_RADIUS_PX = 1e-6


def _as_coc_tensor(coc_px: float | Tensor, like: Tensor | None = None,
                   signed: bool = False) -> Tensor:
    if isinstance(coc_px, Tensor):
        coc = coc_px
    else:
        coc = torch.tensor(float(coc_px))
        if like is not None:
            coc = coc.to(like)
    if not coc.is_floating_point():
        coc = coc.to(torch.get_default_dtype())
    require("coc_px", coc, "signed coc" if signed else "nonnegative", "pixels")  # a few values
    return coc


class Aperture(nn.Module, abc.ABC):
    """Base class of PSF shapes. Subclasses implement `profile` and `half_width` (a subclass
    without them cannot be built)."""

    #: Whether `profile` takes the signed CoC and point-reflects the PSF for a negative one
    #: (nearer than the focus plane); False: the CoC is a diameter, >= 0.
    oriented = False

    @abc.abstractmethod
    def profile(self, dy: Tensor, dx: Tensor, coc_px: Tensor) -> Tensor:
        """Unnormalised PSF value at offset `(dy, dx)` pixels for CoC diameter `coc_px` pixels.

        All three arguments broadcast against each other.
        """

    @abc.abstractmethod
    def half_width(self, coc_px: float) -> int:
        """Largest offset (pixels, along an axis) where `profile` is non-negligible."""

    def kernel_size(self, max_coc_px: float | Tensor) -> int:
        """Odd window width (pixels) that holds the PSF of the largest CoC `max_coc_px`."""
        coc = float(_as_coc_tensor(max_coc_px, signed=self.oriented).detach().abs().max())
        return 2 * max(self.half_width(coc), 0) + 1

    def kernel(self, coc_px: float | Tensor, kernel_size: int | None = None) -> Tensor:
        """Normalised PSF kernels on a pixel grid.

        Args:
            coc_px: CoC diameter(s) in pixels: a float, a 0-d or a `(B,)` tensor, >= 0
                (signed for an `oriented` aperture: negative gives the point-reflected PSF).
            kernel_size: odd window width in pixels; by default `kernel_size` of the
                largest CoC.

        Returns:
            `(B, K, K)` kernels (`B = 1` for a scalar) that each sum to 1, centred on the
            middle pixel. A kernel whose profile is zero everywhere in the window becomes a delta.

        Example:
            >>> k = Disk().kernel(4.0)
            >>> k.shape, round(k.sum().item(), 6)
            (torch.Size([1, 5, 5]), 1.0)
        """
        coc = _as_coc_tensor(coc_px, signed=self.oriented).reshape(-1)
        size = self.kernel_size(coc.detach()) if kernel_size is None else int(kernel_size)
        if size < 1 or size % 2 == 0:
            raise ValueError(f"kernel_size must be a positive odd integer, got {kernel_size!r}")
        half = size // 2
        offsets = torch.arange(-half, half + 1, device=coc.device, dtype=coc.dtype)
        dy, dx = offsets.view(1, -1, 1), offsets.view(1, 1, -1)
        weights = self.profile(dy, dx, coc.view(-1, 1, 1))
        weights = weights.expand(coc.shape[0], size, size)
        total = weights.sum(dim=(-2, -1), keepdim=True)
        delta = torch.zeros_like(weights)
        delta[:, half, half] = 1.0
        return torch.where(total > 0, weights / total.clamp_min(torch.finfo(total.dtype).tiny), delta)


class Gaussian(Aperture):
    """Gaussian PSF with `sigma_px = scale * coc_px` (`coc_px` is the CoC diameter).

    The paper's choice is `scale = 0.5`: sigma equals the CoC radius.

    Args:
        scale: sigma per CoC diameter, > 0 and at most `MAX_GAUSSIAN_SCALE`: one number, a
            0-d tensor or an `nn.Parameter` (for calibration).

    Example:
        >>> Gaussian().kernel(2.0, kernel_size=3)
        tensor([[[0.0751, 0.1238, 0.0751],
                 [0.1238, 0.2042, 0.1238],
                 [0.0751, 0.1238, 0.0751]]])
    """

    scale: Tensor

    def __init__(self, scale: float | Tensor = 0.5):
        super().__init__()
        value = scale if isinstance(scale, Tensor) else \
            torch.tensor(float(scale)) if is_real_number(scale) else None
        if value is None:
            raise TypeError(f"scale must be a number (sigma per CoC diameter), got "
                            f"{type(scale).__name__} {scale!r}")
        one = value.numel() == 1 and value.is_floating_point()
        if not one or not 0 < float(value.detach()) <= MAX_GAUSSIAN_SCALE:  # NaN too
            got = f"{float(value.detach()):g}" if one else \
                f"a {value.dtype} tensor of shape {tuple(value.shape)}"
            raise ValueError(f"scale must be one floating-point number > 0 and at most "
                             f"{MAX_GAUSSIAN_SCALE:g} (sigma per CoC diameter; the paper's is "
                             f"0.5), got {got}; one Gaussian serves every image of a batch")
        if isinstance(scale, nn.Parameter):
            self.register_parameter("scale", scale)
        else:
            self.register_buffer("scale", value)

    def extra_repr(self) -> str:
        return f"scale={self.scale.tolist()}"

    def sigma_px(self, coc_px: Tensor) -> Tensor:
        """Standard deviation in pixels for CoC diameter `coc_px`, at least `MIN_SIGMA_PX`."""
        return (self.scale.to(coc_px) * coc_px).clamp_min(MIN_SIGMA_PX)

    def profile(self, dy: Tensor, dx: Tensor, coc_px: Tensor) -> Tensor:
        sigma = self.sigma_px(coc_px)
        return torch.exp(-(dy * dy + dx * dx) / (2 * sigma * sigma))

    def half_width(self, coc_px: float) -> int:
        sigma = max(float(self.scale.detach()) * coc_px, MIN_SIGMA_PX)
        return math.ceil(3 * sigma - 1e-9) if sigma > MIN_SIGMA_PX else 0


class Disk(Aperture):
    """Uniform disk (pillbox) of diameter `coc_px` with an anti-aliased edge one pixel wide.

    The edge makes the PSF, and the rendered image, differentiable in the radius.

    Example:
        >>> Disk().kernel(3.0)[0]
        tensor([[0.0798, 0.1362, 0.0798],
                [0.1362, 0.1362, 0.1362],
                [0.0798, 0.1362, 0.0798]])
    """

    def distance(self, dy: Tensor, dx: Tensor) -> Tensor:
        """The norm whose unit ball is the aperture shape (Euclidean for the disk)."""
        return torch.sqrt(dy * dy + dx * dx)

    def edge_radius(self, coc_px: Tensor) -> Tensor:
        """Distance of the edge from the centre along the norm of `distance`, in pixels."""
        return coc_px / 2

    def profile(self, dy: Tensor, dx: Tensor, coc_px: Tensor) -> Tensor:
        return (self.edge_radius(coc_px) - self.distance(dy, dx) + 0.5).clamp(0.0, 1.0)

    def half_width(self, coc_px: float) -> int:
        # The profile is non-zero strictly inside distance coc/2 + 1/2.
        return math.ceil(coc_px / 2 - 0.5 - 1e-9)


class Polygon(Disk):
    """Regular polygon inscribed in the CoC circle: the bokeh of an `n_blades` iris.

    Args:
        n_blades: number of sides, from 3 to `MAX_BLADES`.
        rotation: rotation of the first vertex from the +x axis, in radians.

    Example:
        >>> k = Polygon(6).kernel(6.0)
        >>> k.shape, round(k.sum().item(), 6)
        (torch.Size([1, 7, 7]), 1.0)
    """

    def __init__(self, n_blades: int = 6, rotation: float = 0.0):
        super().__init__()
        if isinstance(n_blades, bool) or not isinstance(n_blades, int) \
                or not 3 <= n_blades <= MAX_BLADES \
                or not (is_real_number(rotation) and math.isfinite(rotation)):
            raise ValueError(f"n_blades must be an integer from 3 to {MAX_BLADES} and rotation a "
                             f"finite angle in radians, got {n_blades!r} and {rotation!r}")
        self.n_blades = n_blades
        self.rotation = float(rotation)
        steps = torch.arange(n_blades, dtype=torch.float64)
        normals = self.rotation + math.pi / n_blades + 2 * math.pi * steps / n_blades
        self.register_buffer("_normals", torch.stack([normals.sin(), normals.cos()], -1))

    def extra_repr(self) -> str:
        return f"n_blades={self.n_blades}, rotation={self.rotation}"

    def distance(self, dy: Tensor, dx: Tensor) -> Tensor:
        normals = self._normals.to(dx if dx.is_floating_point() else dy)
        dy, dx = torch.broadcast_tensors(dy, dx)
        projections = dy.unsqueeze(-1) * normals[:, 0] + dx.unsqueeze(-1) * normals[:, 1]
        return projections.amax(dim=-1)

    def edge_radius(self, coc_px: Tensor) -> Tensor:
        return coc_px / 2 * math.cos(math.pi / self.n_blades)


class Mask(Aperture):
    """A user-supplied PSF image (e.g. a measured one), stretched so its width is the CoC diameter:
    the PSF of a point beyond the focus plane, point-reflected for a nearer one (`oriented`: the
    CoC is signed, negative nearer than the focus plane).

    Each kernel pixel gets the mask's mean over the pixel's footprint (exact box integration of
    the bilinearly interpolated summed-area table), so the kernel is anti-aliased at any size and
    differentiable in the CoC, like the disk's soft edge.

    Args:
        image: `(h, w)` non-negative tensor, the PSF at any resolution; it is normalised per use.

    Example:
        >>> yy, xx = torch.meshgrid(torch.linspace(-1, 1, 33), torch.linspace(-1, 1, 33), indexing="ij")
        >>> ring = Mask(((xx**2 + yy**2) < 1).float())
        >>> round(ring.kernel(8.0).sum().item(), 6)
        1.0
        >>> corner = Mask(torch.tensor([[1.0, 0.0], [0.0, 0.0]]))  # the upper left quarter
        >>> torch.allclose(corner.kernel(-4.0), corner.kernel(4.0).flip(-2, -1), atol=1e-6)  # nearer
        True
    """

    oriented = True
    image: Tensor
    _table: Tensor

    def __init__(self, image: Tensor):
        super().__init__()
        if not isinstance(image, Tensor):
            raise TypeError(f"image must be a torch.Tensor of shape (h, w), got {type(image)}")
        if not image.is_floating_point():
            image = image.to(torch.get_default_dtype())
        if image.ndim != 2 or min(image.shape) < 1 or not bool(image.sum() > 0) \
                or bool(torch.any(~torch.isfinite(image) | (image < 0))):
            raise ValueError(f"image must have shape (h, w) and be finite, >= 0 everywhere and "
                             f"not all zero, got shape {tuple(image.shape)}")
        self.register_buffer("image", image)
        self.register_buffer("_table", summed_area_table(image), persistent=False)

    def extra_repr(self) -> str:
        return f"image shape={tuple(self.image.shape)}"

    def profile(self, dy: Tensor, dx: Tensor, coc_px: Tensor) -> Tensor:
        return footprint_mean(self._table, dy, dx, coc_px)

    def half_width(self, coc_px: float) -> int:
        return math.ceil(coc_px / 2 + 0.5 - 1e-9) if coc_px > 0 else 0


def summed_area_table(image: Tensor) -> Tensor:
    """The `(h + 1, w + 1)` summed-area table of a mask image `(h, w)` (a zero row and column
    first), summed in float64 and returned in `image`'s dtype; differentiable in `image`.

    Example:
        >>> summed_area_table(torch.ones(2, 2))
        tensor([[0., 0., 0.],
                [0., 1., 2.],
                [0., 2., 4.]])
    """
    return F.pad(image.double().cumsum(0).cumsum(1), (1, 0, 1, 0)).to(image.dtype)


def footprint_mean(table: Tensor, dy: Tensor, dx: Tensor, coc_px: Tensor) -> Tensor:
    """The mean value of a mask image, stretched over `[-coc/2, coc/2]^2` pixels, over the
    footprint of the pixel at offset `(dy, dx)`: the profile of `Mask` (and of
    `optics.LearnableMask`), from the image's `summed_area_table` `table`. A negative `coc_px`
    stretches the image by a negative factor: its point reflection.

    Exact box integration of the bilinearly interpolated table, so the profile is anti-aliased
    at any size and differentiable in the CoC and in the table (the mask's values).
    """
    half = coc_px / 2
    radius = torch.where(half < 0, half.clamp_max(-MIN_RADIUS_PX), half.clamp_min(MIN_RADIUS_PX))
    dy, dx, radius = torch.broadcast_tensors(dy, dx, radius)
    u0, u1 = (dx - 0.5) / radius, (dx + 0.5) / radius
    v0, v1 = (dy - 0.5) / radius, (dy + 0.5) / radius
    table = table.to(radius)[None, None]

    def cumulative(u: Tensor, v: Tensor) -> Tensor:  # mass in [-1, u] x [-1, v], saturating
        grid = torch.stack([u, v], dim=-1).reshape(1, 1, -1, 2)
        mass = F.grid_sample(table, grid, mode="bilinear", padding_mode="border",
                             align_corners=True)
        return mass.reshape(u.shape)

    mass = cumulative(u1, v1) - cumulative(u0, v1) - cumulative(u1, v0) + cumulative(u0, v0)
    h, w = table.shape[-2] - 1, table.shape[-1] - 1
    # Mean mask value over the footprint: the footprint covers (w/2R) x (h/2R) mask pixels.
    return mass.clamp_min(0) * (4 * radius * radius / (h * w))
