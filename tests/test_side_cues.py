"""Cues to the side of the focus plane: found where a rendered lens has them, absent where not."""

import math

import pytest
import torch

from optics import Camera, Disk, Gaussian, Sensor, ThinLens
from optics.calibration import CalibrationPair
from optics.calibration.side import SideCues, mirror_bin_edges, side_cues

FOCUS = 1.5
SIZE = 72


def _depth() -> torch.Tensor:
    """Bands at 1.0, 1.1 and 1.2 m in front of the plane and at their mirrors behind it (3.0,
    2.36 and 2.0 m: the same thin-lens blur), laid out symmetrically, so that a lens without a
    cue renders both sides alike, band edges included."""
    front = (1.0, 1.1, 1.2)
    mirrors = tuple(1 / (2 / FOCUS - 1 / d) for d in reversed(front))
    depth = torch.empty(1, 1, SIZE, SIZE, dtype=torch.float64)
    for i, d in enumerate(front + mirrors):
        depth[..., i * SIZE // 6:(i + 1) * SIZE // 6, :] = d
    return depth


def _camera(focus: float, aperture=None) -> Camera:
    return Camera(ThinLens(0.035, 2.8, focus), Sensor(4e-5), aperture or Gaussian(0.5))


def _pairs(render, count: int = 6) -> list[CalibrationPair]:
    """Random scenes, the defocused photo with a little noise (as a real photo has)."""
    g = torch.Generator().manual_seed(0)
    depth, pairs = _depth(), []
    for i in range(count):
        sharp = torch.rand(1, 3, SIZE, SIZE, generator=g, dtype=torch.float64)
        noise = 0.01 * torch.randn(sharp.shape, generator=g, dtype=torch.float64)
        pairs.append(CalibrationPair(sharp, render(sharp, depth) + noise, depth, f"scene {i}"))
    return pairs


def _cues(render) -> dict[str, dict[str, float]]:
    return side_cues(_pairs(render), FOCUS, min_pixels=200).contrast()


def _chromatic(sharp, depth):
    """Red focused at 1.4 m, green at 1.5 m, blue at 1.6 m (axial chromatic aberration)."""
    out = [_camera(f).render(sharp, depth)[:, c] for c, f in enumerate((1.4, 1.5, 1.6))]
    return torch.stack(out, 1)


def _asymmetric(sharp, depth):
    """A Gaussian spot in front of the focus plane, a disk behind it (spherical aberration)."""
    front = _camera(FOCUS, Gaussian(0.5)).render(sharp, depth)
    back = _camera(FOCUS, Disk()).render(sharp, depth)
    return torch.where(depth < FOCUS, front, back)


def test_one_focus_for_every_colour_shows_no_colour_cue():
    spread = _cues(_camera(FOCUS).render)["colour spread px"]
    assert spread["pairs"] == 6
    assert abs(spread["mean"]) < 0.05 and abs(spread["z"]) < 4


def test_axial_chromatic_aberration_is_found_with_its_sign():
    spread = _cues(_chromatic)["colour spread px"]
    # in front of the plane red (focused nearer) is the sharper, behind it the blurrier:
    # red minus blue is negative in front, positive behind
    assert spread["mean"] < -1.0 and spread["z"] < -20


def test_an_asymmetric_psf_is_found_and_a_symmetric_one_is_not():
    asymmetric = _cues(_asymmetric)["shape log ratio"]
    symmetric = _cues(_camera(FOCUS).render)["shape log ratio"]
    # the Gaussian fits better in front (ratio above 0), the disk behind (below 0)
    assert asymmetric["mean"] > 0.5 and asymmetric["z"] > 20
    assert abs(symmetric["mean"]) < 0.1 * asymmetric["mean"]


def test_by_bin_rows_name_the_sides():
    cues = side_cues(_pairs(_chromatic, 3), FOCUS, min_pixels=200)
    rows = cues.by_bin()
    assert {r["side"] for r in rows} == {-1.0, 1.0}
    front = [r for r in rows if r["side"] == -1.0]
    assert front and all(r["depth_m"] < FOCUS for r in front)
    assert all(r["colour spread px"] < 0 for r in front)
    assert cues.channel_px.shape[:2] == (3, 3) and cues.names[0] == "scene 0"


def test_mirror_bins_have_the_same_blur_on_both_sides():
    edges = mirror_bin_edges(FOCUS, bins_per_side=4, nearest=0.9)
    defocus = 1 / edges - 1 / FOCUS
    torch.testing.assert_close(defocus, -defocus.flip(0))
    assert float(edges[0]) == pytest.approx(0.9) and bool((edges[1:] > edges[:-1]).all())


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"bins_per_side": 0}, "bins_per_side must be >= 1, got 0"),
    ({"nearest": 2.0}, "nearest must lie between 0 and the focus distance 1.5 m, got 2.0"),
])
def test_bad_bins_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        side_cues(_pairs(_camera(FOCUS).render, 1), FOCUS, **kwargs)


def test_contrast_needs_both_sides():
    cues = side_cues(_pairs(_camera(FOCUS).render, 2), FOCUS, min_pixels=200)
    only_far = SideCues(cues.edges, 0.6, cues.channel_px, cues.shape_log_ratio, cues.pixels,
                        cues.names)  # every bin behind the plane: nothing to compare
    assert math.isnan(only_far.contrast()["colour spread px"]["mean"])
    assert only_far.contrast()["colour spread px"]["pairs"] == 0


@pytest.mark.parametrize("focus", [0.0, -1.0, float("nan"), "1.5"])
def test_bad_focus_distance_is_refused_by_name(focus):
    with pytest.raises(ValueError, match="focus_distance must be a positive number of metres"):
        side_cues(_pairs(_camera(FOCUS).render, 1), focus)


def test_no_pairs_are_refused():
    with pytest.raises(ValueError, match="pairs must hold at least one"):
        side_cues([], FOCUS)
