"""Realistic focal stacks: random cameras, and photos as a camera takes them.

What separates a renderer's output from a photo, simulated here for training and evaluating models
that must work on real photos from any camera:

- the PSF shape: a disk or an iris polygon (5-9 blades), not only a Gaussian;
- occlusion at depth edges (the layered renderer: blurred background does not leak over a sharp
  foreground);
- shot (Poisson-like) and read noise, then 8-bit sRGB quantisation (and, optionally, JPEG
  compression);
- small exposure and white-balance differences between shots, and a pixel or so of misalignment.

`random_camera` draws camera settings whose largest CoC over a scene hits a target in pixels;
`capture` takes the photos; `RandomCameraScenes` serves random crops of procedural scenes under
random cameras, with their true signed CoC maps (for the depth-supervised twin and evaluation).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from kornia.color import linear_rgb_to_rgb, rgb_to_linear_rgb
from torch import Tensor

from optics import CameraSettings, noise_std, render_focal_stack
from optics.alignment import translate

from .io import require_args

#: PSF specs drawn for training renders (physical apertures; a Gaussian of about the disk's spread).
TRAINING_APERTURES = ("disk", "polygon:5", "polygon:6", "polygon:7", "polygon:8", "polygon:9",
                      "gaussian:0.3")


@dataclass(frozen=True)
class CaptureNoise:
    """Photo imperfections (all relative to full scale 1.0 of linear intensity).

    Args:
        read: standard deviation of the read noise.
        shot: shot noise: standard deviation `sqrt(shot * intensity)`.
        exposure: largest relative exposure difference between shots.
        white_balance: largest relative difference of one channel's gain between shots.
        shift_px: largest misalignment between shots, pixels.
        bits: quantisation of the sRGB-encoded photo (0: none).
        jpeg_quality: the photos saved as JPEGs of this quality (1-95, Pillow's scale, 4:2:0
            chroma as cameras save them) and read back; 0: not compressed. Needs `bits=8`.
    """

    read: float = 0.004
    shot: float = 0.0004
    exposure: float = 0.03
    white_balance: float = 0.02
    shift_px: float = 1.0
    bits: int = 8
    jpeg_quality: int = 0

    def __post_init__(self):
        quality = self.jpeg_quality
        require_args(("jpeg_quality", quality, not isinstance(quality, bool) and
                      isinstance(quality, int) and 0 <= quality <= 95,
                      "an integer in 1-95 (0: no JPEG)"),
                     ("bits", self.bits, not quality or self.bits == 8,
                      f"8 for jpeg_quality={quality} (JPEGs hold 8 bits)"))

    @staticmethod
    def none() -> CaptureNoise:
        """A perfect camera (no noise, no differences between shots, no quantisation)."""
        return CaptureNoise(0.0, 0.0, 0.0, 0.0, 0.0, 0)


def random_camera(
    rng: np.random.Generator, near: float, far: float, n_shots: int = 2,
    max_coc_px: tuple[float, float] = (1.0, 14.0), aperture: str | None = None,
) -> CameraSettings:
    """Random camera settings for a scene spanning `[near, far]` metres.

    Focal length log-uniform in 18-200 mm, f-number log-uniform in f/1.2-f/8, focus distances
    spread over (and a little beyond) the scene, and the effective pixel pitch chosen so that the
    largest CoC over the scene is log-uniform in `max_coc_px` (what a working resolution does).

    Example:
        >>> s = random_camera(np.random.default_rng(0), 2.0, 6.0)
        >>> s.n_shots, 1.0 <= s.largest_coc_px(2.0, 6.0) <= 14.0
        (2, True)
    """
    f = math.exp(rng.uniform(math.log(0.018), math.log(0.2)))
    n = math.exp(rng.uniform(math.log(1.2), math.log(8.0)))
    hi = math.log(max(far * 1.5, f * 2.0))
    lo = min(math.log(max(near * 0.8, f * 1.5)), hi - 0.1)
    focus = sorted(math.exp(v) for v in rng.uniform(lo, hi, size=n_shots))
    for i in range(1, n_shots):  # keep shots apart: two equal focus settings say little
        focus[i] = max(focus[i], focus[i - 1] * 1.15)
    spec = aperture or TRAINING_APERTURES[int(rng.integers(len(TRAINING_APERTURES)))]
    unit = CameraSettings(f, n, focus, 1.0, aperture=spec)
    target = math.exp(rng.uniform(math.log(max_coc_px[0]), math.log(max_coc_px[1])))
    pitch = unit.largest_coc_px(near, far) / target
    return unit.replace(pixel_pitch=pitch)


def _srgb_quantise(linear: Tensor, bits: int, jpeg_quality: int = 0) -> Tensor:
    """`linear` `(3,H,W)` as a photo stores it: sRGB-encoded to `bits` (0: not quantised) and,
    with `jpeg_quality`, those 8-bit levels saved as a JPEG and read back; linear again."""
    if bits <= 0:
        return linear.clamp(0, 1)
    levels = 2**bits - 1
    encoded = torch.round(linear_rgb_to_rgb(linear.clamp(0, 1)) * levels)
    if jpeg_quality:
        encoded = _jpeg(encoded, jpeg_quality)
    return rgb_to_linear_rgb(encoded / levels)


def _jpeg(levels: Tensor, quality: int) -> Tensor:
    """8-bit sRGB `levels` `(3,H,W)` (0-255) saved as a JPEG of `quality`, as decoded."""
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(levels.permute(1, 2, 0).to(torch.uint8).numpy()).save(buffer, "JPEG",
                                                                           quality=quality)
    buffer.seek(0)
    with Image.open(buffer) as decoded:
        array = np.asarray(decoded.convert("RGB"))
    return torch.from_numpy(array.copy()).permute(2, 0, 1).to(levels.dtype)


def _shift(image: Tensor, dy: float, dx: float) -> Tensor:
    """Translate `(C,H,W)` by a sub-pixel amount without blurring it (a camera that moves does
    not blur; bilinear resampling would add up to half a pixel of blur the depth does not cause)."""
    return translate(image[None], torch.tensor([[dy, dx]], dtype=image.dtype))[0]


def capture(
    image: Tensor, depth: Tensor, settings: CameraSettings, generator: np.random.Generator,
    noise: CaptureNoise = CaptureNoise(), mode: str = "layered",
) -> tuple[Tensor, Tensor]:
    """Photograph a scene: the all-in-focus photo and one photo per shot of `settings`.

    Args:
        image: `(3,H,W)` linear scene radiance in [0, 1].
        depth: `(1,H,W)` metres.
        settings: `(F,)` settings; their aperture is the PSF (use `"disk"` or polygons for
            real lenses).
        generator: NumPy generator of the imperfections.
        noise: the imperfections.
        mode: renderer semantics (`"layered"`: occlusion-aware).

    Returns:
        `(aif (3,H,W), focused (F,3,H,W))`, linear intensity as decoded from the photos.
    """
    return take_photos(image, _render_stack(image, depth, settings, mode), generator, noise)


def _render_stack(image: Tensor, depth: Tensor, settings: CameraSettings, mode: str) -> Tensor:
    """The focal stack `(F,3,H,W)` of the scene `image` `(3,H,W)`, `depth` `(1,H,W)`."""
    with torch.no_grad():
        return render_focal_stack(image[None], depth[None], settings.to(image.dtype),
                                  mode=mode)[0]


def take_photos(
    image: Tensor, stack: Tensor, generator: np.random.Generator,
    noise: CaptureNoise = CaptureNoise(),
) -> tuple[Tensor, Tensor]:
    """The photos a camera records of the all-in-focus `image` `(3,H,W)` and the rendered focal
    `stack` `(F,3,H,W)` (linear): `noise`'s imperfections applied, as `capture` does.

    Example:
        >>> image = torch.rand(3, 8, 8)
        >>> aif, focused = take_photos(image, image[None], np.random.default_rng(0))
        >>> aif.shape, focused.shape
        (torch.Size([3, 8, 8]), torch.Size([1, 3, 8, 8]))
    """
    shots = [image, *stack]
    out = []
    for i, shot in enumerate(shots):
        if i > 0 and (noise.exposure or noise.white_balance):
            gain = 1 + noise.exposure * generator.uniform(-1, 1)
            wb = 1 + noise.white_balance * generator.uniform(-1, 1, size=3)
            shot = shot * torch.tensor(gain * wb, dtype=shot.dtype)[:, None, None]
        if i > 0 and noise.shift_px:
            dy, dx = noise.shift_px * generator.uniform(-1, 1, size=2)
            shot = _shift(shot, float(dy), float(dx))
        if noise.read or noise.shot:
            sigma = noise_std(shot, noise.read, noise.shot)
            gaussian = torch.from_numpy(generator.standard_normal(shot.shape)).to(shot.dtype)
            shot = shot + sigma * gaussian
        out.append(_srgb_quantise(shot, noise.bits, noise.jpeg_quality))
    return out[0], torch.stack(out[1:])


class RandomCameraScenes(torch.utils.data.IterableDataset):
    """Endless training samples: random crops of procedural scenes under random cameras.

    A pool of `pool_size` scenes (`datasets.synthetic.generate_scene`) is made once; each sample
    takes a random crop of one, draws a camera (`random_camera`) and photographs it (`capture`).
    Samples hold `image`, `focused` `(F,3,h,w)`, `camera` (`CameraSettings`), `depth`,
    `coc_px` (`(F,1,h,w)` true signed CoC diameters in pixels, for supervision and tests only),
    and `clean_image`, `clean_focused`: the same views before the camera's imperfections (the
    targets of the self-supervised loss; no depth in them).

    Args:
        pool_size: number of scenes generated up front.
        scene_size: `(H, W)` of the pooled scenes.
        crop: `(h, w)` of the samples.
        n_shots: shots per sample (an int, or a `(low, high)` range drawn per sample).
        max_coc_px: range of the largest CoC over a sample's scene, pixels.
        noise: the photo imperfections.
        seed: seed of the pool and of the sample stream.
    """

    def __init__(self, pool_size: int = 256, scene_size: tuple[int, int] = (96, 96),
                 crop: tuple[int, int] = (64, 64), n_shots: int | Sequence[int] = 2,
                 max_coc_px: tuple[float, float] = (1.0, 14.0),
                 noise: CaptureNoise = CaptureNoise(), seed: int = 0):
        super().__init__()
        from .synthetic import generate_scene

        if crop[0] > scene_size[0] or crop[1] > scene_size[1]:
            raise ValueError(f"crop {crop} must fit in scene_size {scene_size}")
        self.crop, self.max_coc_px, self.noise, self.seed = crop, max_coc_px, noise, seed
        self.n_shots = (n_shots, n_shots) if isinstance(n_shots, int) else tuple(n_shots)
        rng = np.random.default_rng([seed, 1])
        self.pool = [generate_scene(scene_size, rng, (1.0, 10.0)) for _ in range(pool_size)]

    def sample(self, rng: np.random.Generator) -> dict:
        """One sample drawn with `rng`."""
        image, depth = self.pool[int(rng.integers(len(self.pool)))]
        (h, w), (H, W) = self.crop, image.shape[-2:]
        top, left = int(rng.integers(H - h + 1)), int(rng.integers(W - w + 1))
        image = image[:, top:top + h, left:left + w]
        depth = depth[:, top:top + h, left:left + w]
        if rng.random() < 0.5:
            image, depth = image.flip(-1), depth.flip(-1)
        # A random world scale and exposure: blur depends on depth only through D_f / D.
        depth = depth * math.exp(rng.uniform(math.log(0.3), math.log(5.0)))
        image = (image * rng.uniform(0.5, 1.3)).clamp(0, 1)
        near, far = float(depth.min()), float(depth.max())
        n = int(rng.integers(self.n_shots[0], self.n_shots[1] + 1))
        settings = random_camera(rng, near, far, n, self.max_coc_px)
        stack = _render_stack(image, depth, settings, "layered")
        aif, focused = take_photos(image, stack, rng, self.noise)
        coc = settings.to(depth.dtype).camera().signed_coc_px(depth[None].expand(n, 1, h, w))
        return {"image": aif, "focused": focused, "camera": settings.to(torch.float32),
                "depth": depth, "coc_px": coc.to(torch.float32),
                "clean_image": image, "clean_focused": stack}

    def __iter__(self):
        info = torch.utils.data.get_worker_info()
        worker = 0 if info is None else info.id
        rng = np.random.default_rng([self.seed, 2, worker])
        while True:
            yield self.sample(rng)
