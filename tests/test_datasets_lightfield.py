"""Shift-and-add refocusing against a synthetic light field of a plane at a known disparity."""

from __future__ import annotations

import math

import pytest
import torch

from datasets import LightFieldCalibration, refocus
from datasets.lightfield import aperture_offsets, mosaic_to_views

N_VIEWS, PAD, SIZE = 7, 12, 24


def plane_light_field(texture: torch.Tensor, d0: int) -> torch.Tensor:
    """Views of a textured plane at integer disparity ``d0``: view (ds,dt) at (y,x) sees the texture
    at (y - d0*ds, x - d0*dt) (a point at the centre view's (y,x) appears at (y+d0 ds, x+d0 dt))."""
    c = N_VIEWS // 2
    views = torch.empty(N_VIEWS, N_VIEWS, texture.shape[0], SIZE, SIZE, dtype=texture.dtype)
    for s in range(N_VIEWS):
        for t in range(N_VIEWS):
            oy, ox = PAD - d0 * (s - c), PAD - d0 * (t - c)
            views[s, t] = texture[:, oy : oy + SIZE, ox : ox + SIZE]
    return views


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("d0", [-1, 2])
def test_refocus_at_plane_disparity_is_sharp(dtype, d0):
    texture = torch.rand(3, SIZE + 2 * PAD, SIZE + 2 * PAD, generator=torch.Generator().manual_seed(0)).to(dtype)
    views = plane_light_field(texture, d0)
    sharp = refocus(views, float(d0), radius=3.0)
    m = abs(d0) * (N_VIEWS // 2)  # beyond this margin the views' edge pixels are repeated
    expected = texture[:, PAD : PAD + SIZE, PAD : PAD + SIZE]
    torch.testing.assert_close(sharp[:, m:-m, m:-m], expected[:, m:-m, m:-m])
    assert not torch.allclose(refocus(views, d0 + 0.5, 3.0)[:, m:-m, m:-m], expected[:, m:-m, m:-m],
                              atol=0.05)


@pytest.mark.parametrize("delta", [1, -2])
def test_refocus_elsewhere_is_the_sheared_average(delta):
    """Off the plane, each view is displaced by delta*(ds, dt): the result is their mean."""
    d0, radius = 1, 2.5
    texture = torch.rand(3, SIZE + 2 * PAD, SIZE + 2 * PAD, generator=torch.Generator().manual_seed(1)).double()
    views = plane_light_field(texture, d0)
    c = N_VIEWS // 2
    shifted = [
        texture[:, PAD + delta * ds : PAD + delta * ds + SIZE, PAD + delta * dt : PAD + delta * dt + SIZE]
        for ds in range(-c, c + 1)
        for dt in range(-c, c + 1)
        if ds * ds + dt * dt <= radius * radius
    ]
    # Compare away from the border, where the edge-repeat of the sampling does not reach.
    m = abs(delta) * c * 2
    got = refocus(views, float(d0 + delta), radius)
    expected = torch.stack(shifted).mean(0)
    torch.testing.assert_close(got[:, m:-m, m:-m], expected[:, m:-m, m:-m])


def test_refocus_blur_width_matches_shear_and_thin_lens():
    """A step edge refocused delta px/view off its plane spreads like the view offsets times delta;
    the equivalent thin lens predicts a CoC of 2 * radius * |delta| pixels."""
    d0, delta, radius = 0, 2, 3.0
    x = torch.arange(SIZE + 2 * PAD, dtype=torch.float64)
    texture = (x >= (SIZE + 2 * PAD) // 2).double().expand(1, SIZE + 2 * PAD, -1).clone()
    views = plane_light_field(texture, d0)
    row = refocus(views, float(d0 + delta), radius)[0, SIZE // 2]
    profile = torch.diff(row)  # the line spread function of the blur
    assert float(profile.sum()) == pytest.approx(1.0)
    centre = (profile * torch.arange(len(profile))).sum()
    variance = float((profile * (torch.arange(len(profile)) - centre) ** 2).sum())
    # Shear prediction: horizontal offsets dt of the views in the disk, scaled by delta.
    dts = [dt for ds in range(-3, 4) for dt in range(-3, 4) if math.hypot(ds, dt) <= radius]
    assert variance == pytest.approx(delta**2 * sum(d * d for d in dts) / len(dts))
    spread = torch.nonzero(profile > 1e-12).flatten()
    assert int(spread[-1] - spread[0]) == 2 * radius * abs(delta)  # extreme views at dt = +-3

    # The calibration's thin lens gives the same CoC: 2 * radius * |d - d_f| pixels.
    # (times D_f / (D_f - f), the thin lens's own factor).
    calib, d_f = LightFieldCalibration(), -1.0
    preset = calib.preset([d_f], radius)
    camera = preset.settings(torch.float64).camera()
    depth = calib.depth(torch.tensor([d_f + delta / 2], dtype=torch.float64))
    focus = preset.focus_distances[0]
    expected = 2 * radius * abs(delta / 2) * focus / (focus - calib.focal_length)
    assert float(camera.coc_px(depth)) == pytest.approx(expected, rel=1e-9)


def test_aperture_offsets_and_mosaic_errors():
    offsets = aperture_offsets(7, 3.0)
    assert (3, 3, 0, 0) in offsets and all(ds * ds + dt * dt <= 9 for _, _, ds, dt in offsets)
    assert len(offsets) == 29
    with pytest.raises(ValueError, match="multiples of 14"):
        mosaic_to_views(torch.rand(3, 28, 30), 14)
    with pytest.raises(ValueError, match="layout"):
        mosaic_to_views(torch.rand(3, 28, 28), 14, "zigzag")


def test_refocus_gradcheck():
    views = torch.rand(3, 3, 1, 5, 5, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: refocus(v, 0.4, 1.0), (views,))
