"""Test helper: render defocused photos of a textured plane and write them as Bayer DNG files.

The mosaic is RGGB, 14-bit data in 16-bit containers (black level 512, white level 16383), with
shot noise (Poisson in electrons) and Gaussian read noise, written uncompressed with pidng.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from optics import Camera, Disk, Sensor, ThinLens

BLACK, WHITE = 512, 16383
#: as-shot white-balance multipliers (R, G, B): the raw response is the scene divided by these.
WB = (1.8, 1.0, 1.4)


def texture(size: int, seed: int = 0, smooth_px: float = 1.2) -> torch.Tensor:
    """A colour texture ``(1,3,size,size)`` in [0.1, 0.8], float64, smoothed by a Gaussian."""
    generator = torch.Generator().manual_seed(seed)
    noise = torch.rand(1, 3, size, size, generator=generator, dtype=torch.float64)
    radius = int(np.ceil(3 * smooth_px))
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    g = torch.exp(-(x**2) / (2 * smooth_px**2))
    g = g / g.sum()
    noise = F.conv2d(F.pad(noise, (radius,) * 4, mode="circular"), g.view(1, 1, 1, -1).expand(3, 1, 1, -1), groups=3)
    noise = F.conv2d(noise, g.view(1, 1, -1, 1).expand(3, 1, -1, 1), groups=3)
    noise = (noise - noise.amin()) / (noise.amax() - noise.amin())
    return 0.1 + 0.7 * noise


def render_plane(scene: torch.Tensor, camera: Camera, distance: float, crop: int) -> torch.Tensor:
    """Render ``scene`` as a plane at ``distance`` metres, then crop ``crop`` pixels per side (so
    the border of the photo holds blur from outside the frame, as in a real photo)."""
    depth = torch.full_like(scene[:, :1], distance)
    with torch.no_grad():
        out = camera.render(scene, depth)
    return out[..., crop:-crop, crop:-crop] if crop else out


def mosaic_with_noise(
    rgb: torch.Tensor, seed: int, full_well: float = 20000.0, read_noise_dn: float = 2.0
) -> np.ndarray:
    """RGGB raw values (uint16) of a linear image ``(1,3,H,W)`` in [0,1] (after white balance)."""
    rng = np.random.default_rng(seed)
    image = rgb[0].numpy() / np.array(WB)[:, None, None]
    h, w = image.shape[-2:]
    raw = np.empty((h, w))
    raw[0::2, 0::2] = image[0, 0::2, 0::2]
    raw[0::2, 1::2] = image[1, 0::2, 1::2]
    raw[1::2, 0::2] = image[1, 1::2, 0::2]
    raw[1::2, 1::2] = image[2, 1::2, 1::2]
    electrons = rng.poisson(np.clip(raw, 0, None) * full_well)
    dn = BLACK + electrons * (WHITE - BLACK) / full_well + rng.normal(0, read_noise_dn, raw.shape)
    return np.clip(np.round(dn), 0, WHITE).astype(np.uint16)


def write_dng(
    path: Path, raw: np.ndarray, f_number: float | None = 4.0, focal_length_mm: float = 25.0,
    pixel_pitch: float | None = 5e-6, lens: str = "Synthetic 25mm", noise_free: bool = False,
    orientation: int = 1,
) -> Path:
    """Write an RGGB mosaic (uint16) as an uncompressed 16-bit DNG with lens metadata."""
    from pidng.core import RAW2DNG, DNGTags, Tag
    from pidng.defs import CalibrationIlluminant, CFAPattern, DNGVersion, PhotometricInterpretation

    h, w = raw.shape
    t = DNGTags()
    t.set(Tag.ImageWidth, w)
    t.set(Tag.ImageLength, h)
    t.set(Tag.TileWidth, w)
    t.set(Tag.TileLength, h)
    t.set(Tag.Orientation, orientation)
    t.set(Tag.PhotometricInterpretation, PhotometricInterpretation.Color_Filter_Array)
    t.set(Tag.SamplesPerPixel, 1)
    t.set(Tag.BitsPerSample, 16)
    t.set(Tag.CFARepeatPatternDim, [2, 2])
    t.set(Tag.CFAPattern, CFAPattern.RGGB)
    t.set(Tag.BlackLevel, BLACK)
    t.set(Tag.WhiteLevel, WHITE)
    one, zero = [10000, 10000], [0, 10000]
    t.set(Tag.ColorMatrix1, [one, zero, zero, zero, one, zero, zero, zero, one])
    t.set(Tag.CalibrationIlluminant1, CalibrationIlluminant.D65)
    t.set(Tag.AsShotNeutral, [[int(10000 / m), 10000] for m in WB])
    t.set(Tag.Make, "Defocus")
    t.set(Tag.Model, "Synthetic Bayer")
    t.set(Tag.UniqueCameraModel, "Defocus Synthetic Bayer")
    t.set(Tag.FocalLength, [[int(round(focal_length_mm * 100)), 100]])
    if f_number is not None:
        t.set(Tag.FNumber, [[int(round(f_number * 100)), 100]])
    t.set(Tag.ExposureTime, [[1, 100]])
    t.set(Tag.PhotographicSensitivity, 400)
    t.set(Tag.EXIFPhotoLensModel, lens)
    if pixel_pitch is not None:
        per_cm = int(round(0.01 / pixel_pitch))
        t.set(Tag.FocalPlaneXResolution, [[per_cm, 1]])
        t.set(Tag.FocalPlaneYResolution, [[per_cm, 1]])
        t.set(Tag.FocalPlaneResolutionUnit, 3)
    t.set(Tag.DNGVersion, DNGVersion.V1_4)
    t.set(Tag.DNGBackwardVersion, DNGVersion.V1_2)
    writer = RAW2DNG()
    writer.options(t, path="", compress=False)
    path = Path(path)
    writer.convert(raw, filename=str(path.with_suffix("")))
    return path.with_suffix(".dng")


def write_pairs(
    folder: Path,
    camera: Camera,
    distances: tuple[float, ...],
    size: int = 96,
    f_number_tag: float | None = 4.0,
    seed: int = 0,
) -> list[tuple[Path, Path, float]]:
    """Sharp and defocused DNGs of a textured plane at each distance; returns (sharp, blurred, d).

    Each distance gets its own texture; the sharp shot is the texture itself (a pinhole-like
    reference), the defocused one is rendered by ``camera`` on a larger canvas and cropped.
    """
    crop = 12
    out = []
    for i, distance in enumerate(distances):
        scene = texture(size + 2 * crop, seed=seed + i)
        sharp = scene[..., crop:-crop, crop:-crop]
        blurred = render_plane(scene, camera, distance, crop)
        sharp_path = write_dng(folder / f"sharp_{i}.dng", mosaic_with_noise(sharp, 100 + i),
                               f_number=22.0)
        blurred_path = write_dng(folder / f"blurred_{i}.dng", mosaic_with_noise(blurred, 200 + i),
                                 f_number=f_number_tag)
        out.append((sharp_path, blurred_path, distance))
    return out


def synthetic_camera(psf=None, f_number: float = 4.0, focus: float = 2.0) -> Camera:
    """The camera the tests calibrate: 25 mm, pitch 5 um (full-resolution mosaic)."""
    return Camera(ThinLens(0.025, f_number, focus), Sensor(5e-6), psf or Disk())
