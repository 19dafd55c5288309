"""Depth networks: a small encoder-decoder for CPUs and the paper-sized DeepLabV3+ network.

Both take the all-in-focus image and, in depth-from-defocus mode, the focused images with their
camera settings, and end in a sigmoid head that maps to depth in metres between `depth_min` and
`depth_max`:

============  ==================================================================  ==========
network       architecture                                                        parameters
============  ==================================================================  ==========
`small`     U-Net-style encoder-decoder, 3 scales (`scales`)                   ~0.5 M
              (5 scales: ~1.9 M), optionally each pixel's row as an input
`paper`     ResNet-50 at output stride 16, dense ASPP, self-attention,           ~40 M
              DeepLabV3+ decoder (Gur & Wolf 2019; no pretrained weights)
============  ==================================================================  ==========

Input modes (`input_mode`):

- `"aif"`: the all-in-focus image alone (the paper: monocular at test time).
- `"aif+focused"`: the all-in-focus image, the `F` focused images, their differences to the
  all-in-focus image, the defocus cues of `defocus_cues` (`F + 1` channels), and two
  constant channels per focus setting describing the camera: the focus distance divided by
  `depth_max` and the CoC scale `f^2 / (N (D_f - f) p)` in pixels / 10 (the CoC diameter of
  an object at infinity); with `sweep=K`, also the `K` cost channels of `sweep_channels`,
  and the network then refines the sweep's depth (its logits are added to those of the
  cheapest candidate's depth).
"""

from __future__ import annotations

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from optics import Aperture, CameraSettings
from optics.checks import check_shape

from .depth_from_photos.sweep import sweep_channels
from .depth_from_photos.thin_lens import candidate_inverse_depths
from .depth_head import DepthHead

INPUT_MODES = ("aif", "aif+focused")


def camera_channels(settings: CameraSettings, depth_max: float) -> Tensor:
    """Per-shot camera descriptors `(B, F, 2)` from `(B, F)` settings.

    The two descriptors are `focus_distance / depth_max` and the CoC diameter at infinity in
    pixels divided by 10 (`CameraSettings.coc_at_infinity_px`, from `ThinLens`).
    """
    return torch.stack([settings.focus_distance / depth_max,
                        settings.coc_at_infinity_px() / 10.0], dim=-1)


def defocus_cues(image: Tensor, focused: Tensor, window: int = 7) -> Tensor:
    """Local blur cues `(B, F + 1, H, W)`: per focused image, the log ratio of its local
    high-frequency energy to the all-in-focus image's (about `-c * sigma^2` for a Gaussian blur
    of `sigma` pixels), and the log energy of the all-in-focus image (how reliable the ratios
    are). Energy: squared Laplacian of the channel mean, box-averaged over `window` pixels.

    Example:
        >>> image = torch.rand(1, 3, 16, 16)
        >>> cues = defocus_cues(image, image[:, None].expand(1, 2, 3, 16, 16))
        >>> cues.shape, float(cues[:, :2].abs().max())
        (torch.Size([1, 3, 16, 16]), 0.0)
    """
    b, n, c, h, w = focused.shape
    stack = torch.cat([image[:, None], focused], 1).reshape(b * (n + 1), c, h, w)
    energy = kornia.filters.laplacian(stack.mean(1, keepdim=True), 3) ** 2
    energy = kornia.filters.box_blur(energy, (window, window)).reshape(b, n + 1, h, w)
    eps = 1e-8 + 1e-2 * energy[:, :1].mean((2, 3), keepdim=True)
    log_energy = torch.log(energy + eps)
    return torch.cat([log_energy[:, 1:] - log_energy[:, :1], log_energy[:, :1] / 10], 1)


class _DepthNetwork(nn.Module):
    """Shared input assembly and checks; subclasses implement `_logits(x)`."""

    def __init__(self, input_mode: str, n_focus: int, depth_min: float, depth_max: float,
                 depth_spacing: str = "depth", side: str = "both",
                 focus_distance: float | None = None, sweep: int = 0):
        super().__init__()
        refused = f"input_mode must be one of {INPUT_MODES}, got {input_mode!r}" \
            if input_mode not in INPUT_MODES else \
            f"n_focus must be >= 1 in 'aif+focused' mode, got {n_focus!r}" \
            if input_mode == "aif+focused" and int(n_focus) < 1 else \
            f"sweep={sweep!r} needs side 'both' (the sweep finds each depth's side), got " \
            f"{side!r}" if int(sweep) and side != "both" else None
        if refused:
            raise ValueError(refused)
        self.input_mode = input_mode
        self.n_focus = int(n_focus) if input_mode == "aif+focused" else 0
        self.head = DepthHead(depth_min, depth_max, depth_spacing, side, focus_distance)
        self.sweep = int(sweep) if self.n_focus else 0

    @property
    def in_channels(self) -> int:
        return 3 + 8 * self.n_focus + (self.n_focus + 1 if self.n_focus else 0) + self.sweep

    def assemble_input(
        self, image: Tensor, focused: Tensor | None = None,
        settings: CameraSettings | None = None, aperture: Aperture | None = None,
    ) -> Tensor:
        """Stack the network input `(B, in_channels, H, W)` (see the module docstring);
        `aperture`: the PSF the `sweep` channels render (the settings' by default)."""
        check_shape("image", image, ["B", "3", "H", "W"])
        if self.input_mode == "aif":
            return image
        if focused is None or settings is None:
            raise ValueError("input_mode 'aif+focused' needs focused (B,F,3,H,W) and their "
                             "CameraSettings")
        check_shape("focused", focused, ["B", str(self.n_focus), "3", "H", "W"])
        b, n, _, h, w = focused.shape
        diff = focused - image[:, None]
        settings = settings.batched(b).to(device=image.device, dtype=image.dtype)
        cam = camera_channels(settings, self.head.depth_max).reshape(b, 2 * n, 1, 1)
        parts = [image, focused.reshape(b, 3 * n, h, w), diff.reshape(b, 3 * n, h, w),
                 defocus_cues(image, focused), cam.expand(b, 2 * n, h, w)]
        if self.sweep:
            parts.append(sweep_channels(image, focused, settings, self.head.depth_min,
                                        self.head.depth_max, self.sweep, aperture))
        return torch.cat(parts, dim=1)

    def forward(
        self, image: Tensor, focused: Tensor | None = None,
        settings: CameraSettings | None = None, rows: Tensor | None = None,
        aperture: Aperture | None = None,
    ) -> Tensor:
        """Depth `(B,1,H,W)` in metres from `image` `(B,3,H,W)` (and the focused images
        `(B,F,3,H,W)` with their `(B,F)` camera settings in `"aif+focused"` mode); `rows`
        `(1,1,H,W)`: where the pixels lie in the whole photo, for a network that reads its
        rows (`SmallDepthNet(position=True)`) given a part of it (None: `image` is whole);
        `aperture`: the photos' PSF where it has no spec (a coded aperture), for the `sweep`
        channels."""
        x = self.assemble_input(image, focused, settings, aperture)
        logits = self._logits(self.with_rows(x, rows))
        if self.sweep:  # a refinement of the depth of the sweep's cheapest candidate
            candidates = self.head.logits(1 / candidate_inverse_depths(
                self.head.depth_min, self.head.depth_max, self.sweep, x))  # (K,), then gathered
            logits = logits + candidates[x[:, -self.sweep:].argmax(1, True)]
        return self.head(logits)

    def with_rows(self, x: Tensor, rows: Tensor | None = None) -> Tensor:
        """The network input `x` with what a network reads of the pixels' place (nothing
        here; `SmallDepthNet(position=True)`: their rows)."""
        return x

    def _logits(self, x: Tensor) -> Tensor:
        raise NotImplementedError


def _conv_block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.GroupNorm(min(8, cout), cout),
        nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, 1, 1, bias=False), nn.GroupNorm(min(8, cout), cout),
        nn.ReLU(inplace=True),
    )


class SmallDepthNet(_DepthNetwork):
    """A small encoder-decoder (U-Net style) that trains in minutes on a CPU.

    Each scale halves the resolution; the channels double from `width` up to `4 * width`. Three
    scales see about 40 pixels around each pixel; each further scale adds little work (its
    pixels are a quarter of the last's) and doubles that reach, which a network needs where depth
    comes from the scene's layout (the all-in-focus image alone) or must cross textureless
    regions. Works on any image size (inputs are padded to a multiple of `2 ** (scales - 1)`
    internally).

    Args:
        input_mode: `"aif"` or `"aif+focused"`.
        n_focus: number of focused images `F` in `"aif+focused"` mode.
        depth_min: nearest depth the head can output, metres.
        depth_max: farthest depth the head can output, metres.
        width: channels of the first scale.
        depth_spacing: `"depth"` or `"inverse"`: how the head spaces its output (`DepthHead`).
        scales: resolutions of the encoder, >= 2 (the full one included).
        position: also input each pixel's row in the image (-1 at the top, 1 at the bottom), so
            the network can learn where in a photo things tend to be near (a floor at the
            bottom). Rows of the network's input: train on whole images, not crops;
            `run_network` gives each tile of a large photo its rows in the whole photo.
        sweep: in `"aif+focused"` mode, also input the cost of this many candidate depths
            (`sweep_channels`: the all-in-focus image blurred through the aperture at each
            candidate's blur, against the focused images; 0: none), and refine the depth of
            the cheapest candidate: the network's logits are added to its logits. Through a
            coded aperture the blur is signed: the channels tell the sides of a single focus
            plane apart. Needs `side="both"`.

    Example:
        >>> net = SmallDepthNet("aif", depth_min=1.0, depth_max=10.0, width=8, scales=5,
        ...                     position=True)
        >>> depth = net(torch.rand(2, 3, 30, 40))
        >>> depth.shape, bool(depth.min() > 1.0), bool(depth.max() < 10.0)
        (torch.Size([2, 1, 30, 40]), True, True)
    """

    def __init__(self, input_mode: str = "aif+focused", n_focus: int = 2,
                 depth_min: float = 1.0, depth_max: float = 10.0, width: int = 32,
                 depth_spacing: str = "depth", side: str = "both",
                 focus_distance: float | None = None, scales: int = 3, position: bool = False,
                 sweep: int = 0):
        super().__init__(input_mode, n_focus, depth_min, depth_max, depth_spacing, side,
                         focus_distance, sweep)
        self.scales, self.position = int(scales), bool(position)
        channels = [self.in_channels] + [int(width) * min(2 ** i, 4) for i in range(scales)]
        # named enc1.., then ..dec1: the names (and order) of the three-scale network's weights
        for i in range(1, scales + 1):
            self.add_module(f"enc{i}", _conv_block(channels[i - 1], channels[i], 1 + (i > 1)))
        for i in range(scales - 1, 0, -1):
            self.add_module(f"dec{i}", _conv_block(channels[i + 1] + channels[i], channels[i]))
        self.out = nn.Conv2d(channels[1], 1, 3, padding=1)

    @property
    def in_channels(self) -> int:
        return super().in_channels + int(self.position)

    @staticmethod
    def row_map(h: int, w: int, device: torch.device | str | None = None,
                dtype: torch.dtype | None = None) -> Tensor:
        """`(1,1,h,w)`: each pixel's row in an `h` x `w` photo, -1 at the top, 1 at the bottom
        (an expanded view: crop it with the photo)."""
        rows = torch.linspace(-1.0, 1.0, h, device=device, dtype=dtype)
        return rows.view(1, 1, h, 1).expand(1, 1, h, w)

    def with_rows(self, x: Tensor, rows: Tensor | None = None) -> Tensor:
        """`x` `(B,C,H,W)` with the row channel appended (`position`; else `x` as it is):
        `rows` `(1,1,H,W)`, or those of a whole photo of `x`'s size."""
        if not self.position:
            return x
        if rows is None:
            rows = self.row_map(*x.shape[-2:], device=x.device, dtype=x.dtype)
        return torch.cat([x, rows.to(x).expand(x.shape[0], 1, *x.shape[-2:])], 1)

    def _logits(self, x: Tensor) -> Tensor:
        h, w = x.shape[-2:]
        multiple = 2 ** (self.scales - 1)
        x = F.pad(x, (0, (-w) % multiple, 0, (-h) % multiple), mode="replicate")
        skips = [self.get_submodule("enc1")(x)]
        for i in range(2, self.scales + 1):
            skips.append(self.get_submodule(f"enc{i}")(skips[-1]))
        d = skips.pop()
        for i in range(self.scales - 1, 0, -1):
            skip = skips.pop()
            up = F.interpolate(d, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            d = self.get_submodule(f"dec{i}")(torch.cat([up, skip], 1))
        with torch.autocast(x.device.type, enabled=False):  # the logits in the weights' dtype
            return self.out(d.to(self.out.weight.dtype))[..., :h, :w]


class _Bottleneck(nn.Module):
    expansion = 4

    def __init__(self, cin: int, planes: int, stride: int = 1, dilation: int = 1):
        super().__init__()
        cout = planes * self.expansion
        self.body = nn.Sequential(
            nn.Conv2d(cin, planes, 1, bias=False), nn.BatchNorm2d(planes), nn.ReLU(inplace=True),
            nn.Conv2d(planes, planes, 3, stride, dilation, dilation, bias=False),
            nn.BatchNorm2d(planes), nn.ReLU(inplace=True),
            nn.Conv2d(planes, cout, 1, bias=False), nn.BatchNorm2d(cout),
        )
        self.shortcut = (
            nn.Identity() if stride == 1 and cin == cout
            else nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
        )

    def forward(self, x: Tensor) -> Tensor:
        return F.relu(self.body(x) + self.shortcut(x))


class ResNet50OS16(nn.Module):
    """ResNet-50 backbone at output stride 16 (the last stage dilated instead of strided).

    Returns the stride-4 features (256 channels, for the decoder) and the stride-16 features
    (2048 channels).
    """

    def __init__(self, in_channels: int = 3):
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, 64, 7, 2, 3, bias=False), nn.BatchNorm2d(64),
            nn.ReLU(inplace=True), nn.MaxPool2d(3, 2, 1),
        )
        cin = 64
        stages = []
        for planes, blocks, stride, dilation in ((64, 3, 1, 1), (128, 4, 2, 1), (256, 6, 2, 1),
                                                 (512, 3, 1, 2)):
            layers = []
            for i in range(blocks):
                layers.append(_Bottleneck(cin, planes, stride if i == 0 else 1, dilation))
                cin = planes * _Bottleneck.expansion
            stages.append(nn.Sequential(*layers))
        self.layer1, self.layer2, self.layer3, self.layer4 = stages

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        low = self.layer1(self.stem(x))
        return low, self.layer4(self.layer3(self.layer2(low)))


class DenseASPP(nn.Module):
    """Dense atrous spatial pyramid pooling (Yang et al. 2018): cascaded dilated convolutions,
    each fed with the input and every earlier branch's output."""

    def __init__(self, cin: int, rates: tuple[int, ...] = (3, 6, 12, 18, 24), mid: int = 256,
                 growth: int = 64, cout: int = 256):
        super().__init__()
        self.branches = nn.ModuleList()
        channels = cin
        for rate in rates:
            self.branches.append(nn.Sequential(
                nn.Conv2d(channels, mid, 1, bias=False), nn.BatchNorm2d(mid), nn.ReLU(inplace=True),
                nn.Conv2d(mid, growth, 3, padding=rate, dilation=rate, bias=False),
                nn.BatchNorm2d(growth), nn.ReLU(inplace=True),
            ))
            channels += growth
        self.project = nn.Sequential(nn.Conv2d(channels, cout, 1, bias=False),
                                     nn.BatchNorm2d(cout), nn.ReLU(inplace=True))

    def forward(self, x: Tensor) -> Tensor:
        features = [x]
        for branch in self.branches:
            features.append(branch(torch.cat(features, 1)))
        return self.project(torch.cat(features, 1))


class SelfAttention2d(nn.Module):
    """Non-local self-attention over all positions, with a learnt residual gate (init 0)."""

    def __init__(self, channels: int, reduction: int = 8):
        super().__init__()
        inner = max(channels // reduction, 1)
        self.query = nn.Conv2d(channels, inner, 1)
        self.key = nn.Conv2d(channels, inner, 1)
        self.value = nn.Conv2d(channels, channels, 1)
        self.gamma = nn.Parameter(torch.zeros(()))

    def forward(self, x: Tensor) -> Tensor:
        b, c, h, w = x.shape
        q = self.query(x).flatten(2).transpose(1, 2)
        k = self.key(x).flatten(2).transpose(1, 2)
        v = self.value(x).flatten(2).transpose(1, 2)
        out = F.scaled_dot_product_attention(q, k, v)
        return x + self.gamma * out.transpose(1, 2).reshape(b, c, h, w)


class PaperDepthNet(_DepthNetwork):
    """The paper-sized network: ResNet-50 (output stride 16), dense ASPP, self-attention and a
    DeepLabV3+ decoder, with a sigmoid depth head. Randomly initialised (no pretrained weights).

    Args:
        input_mode: `"aif"` or `"aif+focused"`.
        n_focus: number of focused images `F` in `"aif+focused"` mode.
        depth_min: nearest depth the head can output, metres.
        depth_max: farthest depth the head can output, metres.
        depth_spacing: `"depth"` or `"inverse"`: how the head spaces its output (`DepthHead`).
        sweep: candidate depths of the cost channels (see `SmallDepthNet`).

    Example:
        >>> net = PaperDepthNet("aif", depth_min=1.0, depth_max=10.0).eval()
        >>> net(torch.rand(1, 3, 64, 64)).shape
        torch.Size([1, 1, 64, 64])
    """

    def __init__(self, input_mode: str = "aif", n_focus: int = 2, depth_min: float = 1.0,
                 depth_max: float = 10.0, depth_spacing: str = "depth", side: str = "both",
                 focus_distance: float | None = None, sweep: int = 0):
        super().__init__(input_mode, n_focus, depth_min, depth_max, depth_spacing, side,
                         focus_distance, sweep)
        self.backbone = ResNet50OS16(self.in_channels)
        self.aspp = DenseASPP(2048)
        self.attention = SelfAttention2d(256)
        self.low_project = nn.Sequential(nn.Conv2d(256, 48, 1, bias=False), nn.BatchNorm2d(48),
                                         nn.ReLU(inplace=True))
        self.decoder = nn.Sequential(
            nn.Conv2d(256 + 48, 256, 3, padding=1, bias=False), nn.BatchNorm2d(256),
            nn.ReLU(inplace=True),
            nn.Conv2d(256, 256, 3, padding=1, bias=False), nn.BatchNorm2d(256),
            nn.ReLU(inplace=True),
            nn.Conv2d(256, 1, 1),
        )

    def _logits(self, x: Tensor) -> Tensor:
        low, high = self.backbone(x)
        high = self.attention(self.aspp(high))
        high = F.interpolate(high, size=low.shape[-2:], mode="bilinear", align_corners=False)
        out = self.decoder(torch.cat([high, self.low_project(low)], 1))
        return F.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=False)


NETWORKS = {"small": SmallDepthNet, "paper": PaperDepthNet}


def build_network(name: str, input_mode: str, n_focus: int, depth_min: float, depth_max: float,
                  width: int = 32, depth_spacing: str = "depth", side: str = "both",
                  focus_distance: float | None = None, scales: int = 3,
                  position: bool = False, sweep: int = 0) -> _DepthNetwork:
    """Build a depth network by name (`"small"` or `"paper"`), its output spaced evenly in
    depth or in inverse depth, or on a stated side of the focus plane (`DepthHead`).

    Example:
        >>> build_network("small", "aif", 0, 1.0, 10.0, width=8).input_mode
        'aif'
    """
    if name not in NETWORKS:
        raise ValueError(f"network must be one of {sorted(NETWORKS)}, got {name!r}")
    if name == "small":
        return SmallDepthNet(input_mode, n_focus, depth_min, depth_max, width, depth_spacing,
                             side, focus_distance, scales, position, sweep)
    return PaperDepthNet(input_mode, n_focus, depth_min, depth_max, depth_spacing, side,
                         focus_distance, sweep)
