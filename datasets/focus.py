"""Focus synthesis: render the focused images of a scene from its all-in-focus image and depth."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from optics import DEFAULT_APERTURE, Aperture, CameraSettings, add_noise, render_focal_stack
from optics.checks import check_depth_bounds


class CameraPreset:
    """A dataset's camera and the depths its scenes lie within: the `CameraSettings` of its
    focused images (one lens and sensor, several focus settings) and a depth range (metres).

    Args:
        focal_length: metres.
        pixel_pitch: *effective* pixel pitch of the dataset's images, metres (sensor pitch times
            the downsampling from sensor to image).
        focus_distances: focus distance of each focused image, metres.
        f_numbers: f-number of each focused image (one value is repeated).
        depth_cap: largest valid depth in metres (evaluation cap).
        min_depth: smallest valid depth in metres.
        aperture: PSF spec of the focused images (`optics.aperture_spec`), Gaussian by default.

    Example:
        >>> preset = CameraPreset(0.035, 22.4e-6, focus_distances=(2.0, 8.0), f_numbers=(2.8,))
        >>> preset.camera.n_shots, preset.focus_distances, preset.depth_range
        (2, (2.0, 8.0), (0.001, 10.0))
    """

    def __init__(self, focal_length: float, pixel_pitch: float, focus_distances: Sequence[float],
                 f_numbers: Sequence[float] = (2.8,), depth_cap: float = 10.0,
                 min_depth: float = 1e-3, aperture: str = DEFAULT_APERTURE) -> None:
        n = len(focus_distances)
        numbers = list(f_numbers) * n if len(f_numbers) == 1 else list(f_numbers)
        #: the settings of the focused images, float64
        self.camera = CameraSettings(focal_length, numbers, list(focus_distances), pixel_pitch,
                                     aperture=aperture)
        check_depth_bounds(min_depth, depth_cap, names=("min_depth", "depth_cap"))
        self.depth_cap = float(depth_cap)
        self.min_depth = float(min_depth)

    @property
    def depth_range(self) -> tuple[float, float]:
        """`(min_depth, depth_cap)`, metres: the depths the dataset's scenes lie within."""
        return (self.min_depth, self.depth_cap)

    @property
    def focal_length(self) -> float:
        """Focal length, metres."""
        return float(self.camera.focal_length.reshape(-1)[0])

    @property
    def pixel_pitch(self) -> float:
        """Effective pixel pitch, metres."""
        return float(self.camera.pixel_pitch.reshape(-1)[0])

    @property
    def focus_distances(self) -> tuple[float, ...]:
        """Focus distance of each focused image, metres."""
        return tuple(self.camera.focus_distance.reshape(-1).tolist())

    @property
    def aperture(self) -> str:
        """PSF spec of the focused images."""
        return self.camera.aperture

    def settings(self, dtype: torch.dtype = torch.float32) -> CameraSettings:
        """The `(F,)` `CameraSettings` of the focused images (the samples' `camera` entry)."""
        return self.camera.to(dtype)

    def __repr__(self) -> str:
        return (f"CameraPreset({self.focal_length}, {self.pixel_pitch}, focus_distances="
                f"{self.focus_distances}, depth_cap={self.depth_cap}, min_depth={self.min_depth})")


def default_cache_dir() -> Path | None:
    """The per-user folder for synthesised focal stacks, `optics.cache.user_cache_dir("focal_stacks")`,
    or None when it cannot be created or written (then nothing is cached on disk).

    Example:
        >>> folder = default_cache_dir()
        >>> folder is None or folder.name == "focal_stacks"
        True
    """
    from optics.cache import user_cache_dir

    try:
        folder = user_cache_dir("focal_stacks", create=True)
        probe = folder / f".probe.{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError:
        return None
    return folder


def resolve_cache_dir(cache_dir: str | Path | None) -> Path | None:
    """`cache_dir` as a folder: `"auto"` is `default_cache_dir()`, None stays None."""
    if cache_dir is None:
        return None
    if isinstance(cache_dir, str) and cache_dir == "auto":
        return default_cache_dir()
    return Path(cache_dir)


#: Bumped when the synthesis changes in a way the cache key cannot see (e.g. a renderer fix).
CACHE_VERSION = 3


def focal_stack_key(
    image: Tensor,
    depth: Tensor,
    settings: CameraSettings,
    aperture: Aperture | None = None,
    **render_kwargs: Any,
) -> str:
    """Content hash of everything a synthesised focal stack depends on (hex string).

    The pixels themselves are hashed, so any change to loading, cropping or resizing gives a new
    key and a stale stack is never reused.
    """
    digest = hashlib.sha1(f"v{CACHE_VERSION}".encode())
    # the aperture's own tensors too: a Mask's repr names its shape, not its pixels
    state = {} if aperture is None else aperture.state_dict()
    for tensor in (image, depth, *settings.tensors().values(), *state.values()):
        tensor = tensor.detach().cpu().contiguous()
        digest.update(f"{tensor.dtype}{tuple(tensor.shape)}".encode())
        digest.update(tensor.reshape(-1).view(torch.uint8).numpy().tobytes())  # any dtype
    digest.update(f"{settings.aperture}|{aperture!r}|{sorted(state)}".encode())
    digest.update(repr(sorted(render_kwargs.items())).encode())
    return digest.hexdigest()


def cached_focal_stack(
    image: Tensor,
    depth: Tensor,
    settings: CameraSettings,
    aperture: Aperture | None = None,
    cache_dir: str | Path | None = None,
    **render_kwargs: Any,
) -> Tensor:
    """`optics.render_focal_stack` of one scene under `torch.no_grad()`, reusing stacks saved in `cache_dir`.

    Stacks are stored as `<cache_dir>/<key>.pt` (key from `focal_stack_key`) and written
    atomically, so several DataLoader workers may share one cache folder. With `cache_dir=None`
    nothing is stored.

    Args:
        image: all-in-focus image `(3,H,W)`, linear in [0, 1].
        depth: depth `(1,H,W)` in metres, > 0.
        settings: `(F,)` settings, e.g. from `CameraPreset.settings`.
        aperture: PSF override (the settings' aperture by default).
        cache_dir: folder for cached stacks (created on first use), `"auto"` for the per-user
            `default_cache_dir()`, or None.
        **render_kwargs: passed to `optics.render_defocus`.

    Returns:
        `(F,3,H,W)` focused images, in `image`'s dtype.

    Example:
        >>> import tempfile
        >>> preset = CameraPreset(0.035, 22.4e-6, focus_distances=(2.0, 8.0))
        >>> image, depth = torch.rand(3, 8, 8), torch.full((1, 8, 8), 3.0)
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     first = cached_focal_stack(image, depth, preset.settings(), cache_dir=folder)
        ...     again = cached_focal_stack(image, depth, preset.settings(), cache_dir=folder)
        ...     n_files = len(list(Path(folder).glob("*.pt")))
        >>> torch.equal(first, again), n_files
        (True, 1)
    """
    path = None
    cache_dir = resolve_cache_dir(cache_dir)
    if cache_dir is not None:
        key = focal_stack_key(image, depth, settings, aperture, **render_kwargs)
        path = Path(cache_dir) / f"{key}.pt"
        if path.is_file():
            try:
                cached = torch.load(path, weights_only=True)
                if isinstance(cached, Tensor) and cached.shape == (settings.n_shots, *image.shape):
                    return cached.to(image)
            except Exception:  # a half-written or corrupt entry: render again and overwrite
                pass
            # an entry of another shape or type (damaged or stale) is rendered again too
    with torch.no_grad():
        stack = render_focal_stack(image[None], depth[None], settings, aperture,
                                   **render_kwargs)[0]
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        torch.save(stack.cpu(), tmp)
        os.replace(tmp, path)
    return stack


#: The paper's focus settings (Gur & Wolf 2019): two focused images, at these fractions of the
#: far end of the depth range (2 m and 8 m of NYU's 10 m).
PAPER_FOCUS_FRACTIONS = (0.2, 0.8)


def paper_focus(settings: CameraSettings, depth_cap: float,
                fractions: Sequence[float] = PAPER_FOCUS_FRACTIONS) -> CameraSettings:
    """The camera of `settings` (its first shot's focal length, f-number, pixel pitch and
    aperture) focused at each of `fractions` of `depth_cap` metres: the paper's two focus
    settings, from which the focused images of an RGB-D scene are synthesised.

    Example:
        >>> camera = CameraSettings(0.035, 2.8, 1.7, 55.7e-6)
        >>> paper_focus(camera, 10.0).focus_distance.tolist()
        [2.0, 8.0]
    """
    first = settings.select_shots([0] * len(fractions))
    distances = torch.tensor([float(f) * float(depth_cap) for f in fractions],
                             dtype=first.focus_distance.dtype)
    return first.replace(focus_distance=distances.expand_as(first.focus_distance).clone())


class SynthesizedFocus(torch.utils.data.Dataset):
    """`samples` with their focused images rendered anew from their all-in-focus `image` and
    `depth` through `settings` (`cached_focal_stack`): a data set scored with the camera a
    network was trained for (the blur it learned is that camera's), whatever camera its own
    focused images had.

    Args:
        samples: unbatched samples with `image` `(3,H,W)` and `depth` `(1,H,W)` metres.
        settings: `(F,)` settings of the focused images; the pixel pitch is the effective one
            at the samples' resolution, taken as it is.
        min_depth: depths below it are rendered at it, metres.
        cache_dir: folder of cached focal stacks (`cached_focal_stack`), or None.
        keep: keep the rendered samples in memory (a small set scored several times).
        aperture: the PSF, overriding the settings' spec (e.g. a learned mask as an
            `optics.Mask`).
        read_noise: the sensor's read noise on the rendered images (`optics.noise_std`),
            drawn with the sample's index as seed: the same draws every time; 0: none.
        shot_noise: its shot noise, the same way.
        light: the light each shot gathers relative to the exposure of that noise, a number or
            `(F,)` (a camera stopped down from the one a network learned gathers less).

    Example:
        >>> from datasets.synthetic import SyntheticScenes
        >>> scenes = SyntheticScenes(num_scenes=1, size=(16, 16))
        >>> camera = CameraSettings(0.035, 2.8, [2.0, 8.0, 9.0], 1e-4)
        >>> sample = SynthesizedFocus(scenes, camera)[0]
        >>> sample["focused"].shape
        torch.Size([3, 3, 16, 16])
    """

    def __init__(self, samples: Sequence[Any], settings: CameraSettings, min_depth: float = 1e-3,
                 cache_dir: str | Path | None = None, keep: bool = False,
                 aperture: Aperture | None = None, read_noise: float = 0.0,
                 shot_noise: float = 0.0, light: float | Tensor = 1.0) -> None:
        self.samples, self.settings, self.aperture = samples, settings, aperture
        self.noise = (float(read_noise), float(shot_noise), torch.as_tensor(light).reshape(-1))
        self.min_depth, self.cache_dir = float(min_depth), cache_dir
        self._kept: dict[int, dict[str, Any]] | None = {} if keep else None

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, index: int) -> dict[str, Any]:
        if self._kept is not None and index in self._kept:
            return dict(self._kept[index])
        sample = dict(self.samples[index])
        settings = self.settings.to(sample["image"].dtype)
        stack = cached_focal_stack(
            sample["image"], sample["depth"].clamp_min(self.min_depth), settings,
            None if self.aperture is None else self.aperture.to(sample["image"].dtype),
            cache_dir=self.cache_dir)
        read, shot, light = self.noise
        if read or shot:
            stack = add_noise(stack, read, shot, light.to(stack).view(-1, 1, 1, 1),
                              torch.Generator().manual_seed(index))
        sample["focused"] = stack.clamp(0, 1)
        sample["camera"] = settings
        if self._kept is not None:
            self._kept[index] = dict(sample)
        return sample
