"""Exposure matching and the noise model (models.depth_from_photos.photometry)."""

import torch

from models.depth_from_photos.photometry import (
    _local_noise,
    _quantile_of_pure_noise,
    match_exposure,
    noise_model,
)


def _noise_model_by_masks(image, bins=12):
    """The noise model with a boolean mask and `torch.quantile` per intensity band."""
    out = []
    for photo in image:  # the operator in the photo's dtype, the statistics in float64
        variance, level = (t.flatten().double() for t in _local_noise(photo[:, None]))
        edges = torch.quantile(level, torch.linspace(0, 1, bins + 1, dtype=level.dtype))
        xs, ys = [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            band = (level >= lo) & (level <= hi)
            if int(band.sum()) < 50:
                continue
            xs.append(float(level[band].median()))
            ys.append(float(torch.quantile(variance[band], 0.1)) / _quantile_of_pure_noise())
        x, y = torch.tensor(xs, dtype=torch.float64), torch.tensor(ys, dtype=torch.float64)
        design = torch.stack([torch.ones_like(x), x], 1)
        a, b = torch.linalg.lstsq(design, y[:, None]).solution.flatten().tolist()
        out.append([a, b])
    return torch.tensor(out, dtype=image.dtype)


def test_noise_model_bands_match_masks_and_quantiles_exactly():
    """Bands read from one sort give the values of masks and torch.quantile, ties included
    (8-bit levels)."""
    g = torch.Generator().manual_seed(0)
    flat = torch.linspace(0.1, 0.9, 96).expand(2, 3, 96, 96)
    noisy = flat + torch.randn(2, 3, 96, 96, generator=g) * (1e-4 + 1e-3 * flat).sqrt()
    quantised = (noisy.clamp(0, 1) * 255).round() / 255
    for image in (noisy, quantised):
        expected = _noise_model_by_masks(image)
        assert (expected[:, 1] > 0).all()  # the lstsq line kept: the clamps do not apply
        torch.testing.assert_close(noise_model(image), expected, rtol=1e-12, atol=0)


def test_match_exposure_scales_each_channel_to_the_reference_means():
    image = torch.rand(1, 3, 8, 8) + 0.1
    gains = torch.tensor([0.5, 2.0, 1.5]).view(1, 3, 1, 1)
    torch.testing.assert_close(match_exposure(image, image * gains), image)
