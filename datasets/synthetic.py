"""Procedural synthetic scenes: the embedded default training data.

Each scene is a layout of textured surfaces with ground-truth depth in metres: a background plane
(fronto-parallel or slanted), optionally a ground plane seen in perspective, and a few occluding
objects (rectangles and ellipses, fronto-parallel or slanted). Textures are random crops of the
images shipped with scikit-image (never the Middlebury motorcycle, which is kept for evaluation).
The focused images are rendered through the renderer with a configurable
`CameraPreset`. Everything is deterministic given `(seed, index)`.

The default camera, `SYNTHETIC_PRESET`, is a 50 mm f/1.4 lens focused at 2 m and 6 m with an
effective pixel pitch of 180 micrometres (a 4.5 um sensor downsampled 40 times, e.g. a 6000x4000
photo shrunk to 150x100 pixels). Its CoC diameters stay at or below 5 pixels over the default
depth range of 1.5-6 m, so rendering is cheap on a CPU.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from kornia.color import rgb_to_linear_rgb
from torch import Tensor
from torch.utils.data import Dataset

from optics import Aperture, render_focal_stack

from .focus import CameraPreset
from .io import require_args

#: The default camera of the synthetic scenes and of the demo (lengths in metres).
SYNTHETIC_PRESET = CameraPreset(
    focal_length=0.05,
    pixel_pitch=180e-6,
    focus_distances=(2.0, 6.0),
    f_numbers=(1.4,),
    depth_cap=6.0,
    min_depth=1.5,
)

#: scikit-image images used as textures (all shipped with scikit-image, no download).
TEXTURE_NAMES = (
    "astronaut", "coffee", "chelsea", "rocket", "brick", "grass", "gravel", "camera", "moon",
    "text", "page", "coins", "immunohistochemistry", "hubble_deep_field", "colorwheel", "cell",
)


@lru_cache(maxsize=1)
def load_textures() -> tuple[Tensor, ...]:
    """The texture images as `(3, h, w)` float32 linear tensors in [0, 1] (cached)."""
    from skimage import data

    textures = []
    for name in TEXTURE_NAMES:
        array = np.asarray(getattr(data, name)(), dtype=np.float32) / 255.0
        if array.ndim == 2:
            array = np.repeat(array[..., None], 3, axis=-1)
        tensor = torch.from_numpy(np.ascontiguousarray(array[..., :3])).permute(2, 0, 1)
        textures.append(rgb_to_linear_rgb(tensor).contiguous())
    return tuple(textures)


def _uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


def _texture_patch(
    rng: np.random.Generator, size: tuple[int, int], textures: Sequence[Tensor]
) -> Tensor:
    """A random crop of a random texture, rescaled to `size` with a random colour gain."""
    h, w = size
    texture = textures[int(rng.integers(len(textures)))]
    th, tw = texture.shape[-2:]
    # Texture pixels per output pixel: 2-6 keeps fine detail everywhere, where defocus shows.
    zoom = _uniform(rng, 2.0, 6.0)
    ch, cw = min(th, max(4, round(h * zoom))), min(tw, max(4, round(w * zoom)))
    y0, x0 = int(rng.integers(th - ch + 1)), int(rng.integers(tw - cw + 1))
    patch = texture[:, y0 : y0 + ch, x0 : x0 + cw]
    if rng.random() < 0.5:
        patch = patch.flip(-1)
    patch = F.interpolate(patch[None], size=(h, w), mode="area")[0]
    gain = torch.from_numpy(rng.uniform(0.6, 1.3, size=(3, 1, 1)).astype(np.float32))
    return (patch * gain).clamp(0, 1)


def _plane(rng: np.random.Generator, grid: tuple[Tensor, Tensor], near: float, far: float,
           slant: bool) -> Tensor:
    """Depth of a fronto-parallel or slanted plane between `near` and `far` metres."""
    yy, xx = grid
    centre = _uniform(rng, near, far)
    if not slant:
        return torch.full_like(xx, centre)
    angle = _uniform(rng, 0, 2 * math.pi)
    span = _uniform(rng, 0.1, 0.5) * (far - near)
    ramp = (math.cos(angle) * xx + math.sin(angle) * yy) * span
    return (centre + ramp).clamp(near, far)


def generate_scene(
    size: tuple[int, int],
    rng: np.random.Generator,
    depth_range: tuple[float, float] = (1.5, 6.0),
    textures: Sequence[Tensor] | None = None,
    max_objects: int = 4,
) -> tuple[Tensor, Tensor]:
    """One random scene: an all-in-focus image and its depth.

    Args:
        size: `(height, width)` in pixels.
        rng: NumPy random generator (the scene is a function of its state).
        depth_range: `(near, far)` limits of the scene depth in metres.
        textures: `(3,h,w)` linear texture images; `load_textures` by default.
        max_objects: largest number of occluding objects.

    Returns:
        `image` `(3,H,W)` linear in [0, 1] and `depth` `(1,H,W)` in metres within
        `depth_range`.

    Example:
        >>> image, depth = generate_scene((32, 48), np.random.default_rng(0))
        >>> image.shape, depth.shape, bool(depth.min() >= 1.5), bool(depth.max() <= 6.0)
        (torch.Size([3, 32, 48]), torch.Size([1, 32, 48]), True, True)
    """
    near, far = depth_range
    if not 0 < near < far:
        raise ValueError(f"depth_range must be (near, far) metres with 0 < near < far, got "
                         f"{depth_range!r}")
    h, w = size
    textures = load_textures() if textures is None else textures
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    grid = (yy, xx)

    # Background: a far plane, sometimes slanted.
    mid = near + 0.4 * (far - near)
    depth = _plane(rng, grid, mid, far, slant=rng.random() < 0.5)
    image = _texture_patch(rng, size, textures)

    # Ground plane in perspective: depth ~ 1 / (rows below the horizon), texture foreshortened.
    if rng.random() < 0.5:
        horizon = _uniform(rng, -0.6, 0.2)
        bottom_depth = _uniform(rng, near, near + 0.3 * (far - near))
        below = (yy - horizon).clamp_min(1e-3)
        ground = bottom_depth * (1 - horizon) / below
        is_ground = (yy > horizon) & (ground < depth)
        tex = _texture_patch(rng, (2 * h, 2 * w), textures)
        # Texture coordinates on the ground: lateral position scales with depth, rows with 1/depth.
        u = (xx * ground / (bottom_depth * 2)).clamp(-1, 1)
        v = (1 - 2 * (ground - bottom_depth) / (far - bottom_depth + 1e-6)).clamp(-1, 1)
        warped = F.grid_sample(tex[None], torch.stack([u, v], -1)[None], mode="bilinear",
                               align_corners=False)[0]
        image = torch.where(is_ground, warped, image)
        depth = torch.where(is_ground, ground, depth)

    # Occluding objects, drawn far to near with a depth test.
    for _ in range(int(rng.integers(1, max_objects + 1))):
        obj_depth = _plane(rng, grid, near, mid + 0.3 * (far - mid), slant=rng.random() < 0.4)
        cy, cx = _uniform(rng, -0.9, 0.9), _uniform(rng, -0.9, 0.9)
        ry, rx = _uniform(rng, 0.1, 0.6), _uniform(rng, 0.1, 0.6)
        if rng.random() < 0.5:
            inside = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1
        else:
            inside = ((yy - cy).abs() <= ry) & ((xx - cx).abs() <= rx)
        inside = inside & (obj_depth < depth)
        image = torch.where(inside, _texture_patch(rng, size, textures), image)
        depth = torch.where(inside, obj_depth, depth)
    return image.contiguous(), depth[None].clamp(near, far).contiguous()


class SyntheticScenes(Dataset):
    """Procedural scenes with ground-truth depth and focused images, in the sample format.

    Sample `i` depends only on `(seed, i)`; samples are rendered on first access and cached.

    Args:
        num_scenes: number of scenes (the dataset length).
        size: `(height, width)` in pixels.
        preset: camera of the focused images, `SYNTHETIC_PRESET` by default.
        seed: random seed.
        depth_range: `(near, far)` scene depth limits in metres; by default the preset's
            `(min_depth, depth_cap)`.
        aperture: PSF shape of the renders (Gaussian, `sigma = CoC/2`, by default).
        cache: keep rendered samples in memory.
        **render_kwargs: passed to `optics.render_defocus` (`mode`, ...).

    Example:
        >>> scenes = SyntheticScenes(num_scenes=2, size=(24, 32))
        >>> sample = scenes[0]
        >>> camera = sample["camera"]
        >>> sample["image"].shape, sample["focused"].shape, camera.focus_distance
        (torch.Size([3, 24, 32]), torch.Size([2, 3, 24, 32]), tensor([2., 6.]))
    """

    def __init__(
        self,
        num_scenes: int = 256,
        size: tuple[int, int] = (64, 64),
        preset: CameraPreset = SYNTHETIC_PRESET,
        seed: int = 0,
        depth_range: tuple[float, float] | None = None,
        aperture: Aperture | None = None,
        cache: bool = True,
        **render_kwargs: Any,
    ):
        require_args(("num_scenes", num_scenes, int(num_scenes) > 0, "> 0"),
                     ("size", size, len(size) == 2 and min(size) >= 4,
                      "(height, width) pixels, each >= 4"))
        self.num_scenes = int(num_scenes)
        self.size = (int(size[0]), int(size[1]))
        self.preset = preset
        self.seed = int(seed)
        self.depth_range = depth_range or (preset.min_depth, preset.depth_cap)
        self.aperture = aperture
        self.render_kwargs = render_kwargs
        self._cache: dict[int, dict] | None = {} if cache else None

    def __len__(self) -> int:
        return self.num_scenes

    def __getitem__(self, index: int) -> dict:
        if not -self.num_scenes <= index < self.num_scenes:
            raise IndexError(f"index {index} out of range for {self.num_scenes} scenes")
        index %= self.num_scenes
        if self._cache is not None and index in self._cache:
            return self._cache[index]
        rng = np.random.default_rng([self.seed, index])
        image, depth = generate_scene(self.size, rng, self.depth_range)
        settings = self.preset.settings()
        with torch.no_grad():
            focused = render_focal_stack(image[None], depth[None], settings, self.aperture,
                                         **self.render_kwargs)[0]
        sample = {
            "image": image,
            "focused": focused.clamp(0, 1),
            "camera": settings,
            "depth": depth,
            "mask": torch.ones_like(depth, dtype=torch.bool),
            "dataset": "synthetic",
            "id": f"{self.seed}-{index}",
        }
        if self._cache is not None:
            self._cache[index] = sample
        return sample
