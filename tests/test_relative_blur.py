"""Depth from focused shots alone (models.depth_from_photos): the relative blur between shots,
depth from focus, the all-in-focus image, and `defocus predict` without `--image`."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from PIL import Image

from datasets.capture import CaptureNoise, capture
from datasets.photos import read_photo
from datasets.synthetic import generate_scene
from defocus.cli import main
from models.depth_from_photos import (
    DepthFromFocus,
    RelativeBlurDepth,
    candidate_inverse_depths,
    estimate_depth,
    focus_peak,
    fuse_all_in_focus,
    relative_blur_cost,
    relative_blur_px,
)
from models.depth_from_photos.fourier_blur import psf_kernel
from optics import CameraSettings, Disk, Gaussian, render_defocus

REAL = Path(os.environ.get("DEFOCUS_REAL_DATA",
                          Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))


def _texture(size=(64, 80), dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    noise = torch.rand(1, 3, size[0] // 4, size[1] // 4, generator=g, dtype=dtype)
    return F.interpolate(noise, size=size, mode="bicubic", align_corners=False).clamp(0, 1)[0]


def _plane_shots(settings: CameraSettings, depth_m: float, dtype: torch.dtype):
    """A textured plane at `depth_m` photographed by every shot of `settings` (no noise)."""
    image = _texture(dtype=dtype)
    coc = settings.to(dtype).camera().coc_px(torch.full((settings.n_shots, 1, *image.shape[-2:]),
                                                        depth_m, dtype=dtype))
    psf = settings.aperture_module()
    shots = render_defocus(image[None].expand(settings.n_shots, -1, -1, -1), coc, psf=psf,
                           max_kernel_size=41)
    return image, shots


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("aperture", ["gaussian", "disk"])
def test_the_relative_blur_cost_is_least_at_the_true_depth(aperture, dtype):
    """For a plane, the cost of every candidate (an independent check: the candidates' own
    inverse depths) is least at the candidate nearest the plane's depth, for Gaussian PSFs (where
    the relative PSF is exact) and disks (where it keeps the second moment)."""
    settings = CameraSettings(0.05, 2.0, [1.5, 4.0], 1e-4, aperture=aperture)
    near, far, k = 1.0, 8.0, 48
    for depth_m in (1.2, 2.5, 6.0):
        _, shots = _plane_shots(settings, depth_m, dtype)
        cost = relative_blur_cost(shots[None], settings, near, far, k)[0]
        inner = cost[:, 12:-12, 12:-12].mean((-2, -1))  # away from the borders
        x = candidate_inverse_depths(near, far, k, inner)
        truth = int((x - 1 / depth_m).abs().argmin())
        assert abs(int(inner.argmin()) - truth) <= 1, (aperture, depth_m, inner.argmin(), truth)


def test_relative_blur_diameter_composes_gaussians_exactly():
    """`relative_blur_px`: a Gaussian of the sharper blur convolved with the Gaussian of the
    relative blur is the Gaussian of the blurrier one (variances add)."""
    gaussian, like = Gaussian(), torch.zeros(1, dtype=torch.float64)
    sharper, blurrier = 3.0, 7.0
    relative = float(relative_blur_px(torch.tensor(sharper), torch.tensor(blurrier)))
    a, b = psf_kernel(gaussian, sharper, like), psf_kernel(gaussian, relative, like)
    composed = F.conv2d(F.pad(a, (b.shape[-1] - 1,) * 4)[None, None], b.flip(-1, -2)[None, None])
    target = psf_kernel(gaussian, blurrier, like)
    pad = (composed.shape[-1] - target.shape[-1]) // 2
    assert torch.allclose(composed[0, 0], F.pad(target, (pad,) * 4), atol=2e-3)


def test_the_disk_relative_psf_matches_the_second_moment():
    """For disks, the sharper disk blurred by the relative disk has the blurrier disk's second
    moment (within the sampling of the kernels), while its shape differs by the documented L1."""
    disk, like = Disk(), torch.zeros(1, dtype=torch.float64)

    def moment(kernel):
        r = kernel.shape[-1] // 2
        yy, xx = torch.meshgrid(*(torch.arange(-r, r + 1, dtype=torch.float64),) * 2,
                                indexing="ij")
        return float((kernel * (xx**2 + yy**2)).sum() / kernel.sum())

    for sharper, l1 in ((2.0, 0.16), (4.0, 0.31), (6.0, 0.35)):
        relative = float(relative_blur_px(torch.tensor(sharper), torch.tensor(8.0)))
        a, b = psf_kernel(disk, sharper, like), psf_kernel(disk, relative, like)
        composed = F.conv2d(F.pad(a, (b.shape[-1] - 1,) * 4)[None, None],
                            b.flip(-1, -2)[None, None])[0, 0]
        target = psf_kernel(disk, 8.0, like)
        assert moment(composed) == pytest.approx(moment(target), rel=0.15)
        pad = (composed.shape[-1] - target.shape[-1]) // 2
        distance = float((composed - F.pad(target, (pad,) * 4)).abs().sum())
        assert distance == pytest.approx(l1, abs=0.01)


def test_relative_blur_reads_a_scene_without_an_all_in_focus_photo():
    """On a procedural scene photographed twice with a real sensor's imperfections, the
    relative blur is far better than the best constant depth."""
    rng = np.random.default_rng(3)
    image, depth = generate_scene((96, 128), rng, (1.5, 5.0))
    settings = CameraSettings(0.05, 2.0, [1.4, 4.5], 1e-4, aperture="disk")
    _, focused = capture(image, depth, settings, rng, CaptureNoise())
    out = estimate_depth(focused, settings, (1.0, 8.0))
    error = ((out["depth"] - depth).abs() / depth).mean()
    constant = ((depth.median() - depth).abs() / depth).mean()
    assert float(error) < 0.6 * float(constant)


def _stack_scene(seed=5):
    rng = np.random.default_rng(seed)
    image, depth = generate_scene((96, 128), rng, (1.2, 6.0))
    settings = CameraSettings(0.05, 1.8, [1.3, 2.2, 5.0], 1e-4, aperture="disk")
    _, focused = capture(image, depth, settings, rng, CaptureNoise.none())
    return image, depth, settings, focused


def _gradient_energy(image):
    gray = image.mean(0)
    return float((gray.diff(dim=0) ** 2).mean() + (gray.diff(dim=1) ** 2).mean())


def test_the_all_in_focus_image_is_sharper_than_every_shot_and_near_the_truth():
    """The fused all-in-focus image has more gradient energy than every shot, a PSNR of at
    least 33 dB against the true all-in-focus image, and 1 dB more than the best shot's."""
    image, _, settings, focused = _stack_scene()
    out = estimate_depth(focused, settings, (1.0, 8.0))
    fused = out["all_in_focus"]
    assert fused.shape == image.shape
    assert all(_gradient_energy(fused) > _gradient_energy(shot) for shot in focused)

    def psnr(a):
        return float(10 * torch.log10(1 / ((a - image) ** 2).mean()))

    assert psnr(fused) > 33 and psnr(fused) > max(psnr(shot) for shot in focused) + 1


def test_fusion_follows_the_sharper_shot_and_undoes_the_motion():
    sharp = torch.rand(3, 20, 24)
    flat = sharp.mean((-2, -1), keepdim=True).expand(3, 20, 24)  # same exposure, no detail
    moved = torch.roll(sharp, shifts=2, dims=-1)
    blur = torch.stack([torch.full((20, 24), 5.0), torch.zeros(20, 24)])
    motions = torch.tensor([[0.0, 0.0, 1.0, 0.0], [0.0, 2.0, 1.0, 0.0]])
    fused = fuse_all_in_focus(torch.stack([flat, moved]), blur, motions)
    assert torch.allclose(fused[:, :, 4:-4], sharp[:, :, 4:-4], atol=1e-3)


def test_depth_from_focus_finds_the_sharpest_shot():
    """A plane at the middle shot's focus distance is placed there (within a tenth of the gap
    to the neighbouring shots, in inverse depth); `focus_peak` interpolates between shots."""
    settings = CameraSettings(0.05, 2.0, [1.5, 2.5, 5.0], 1e-4, aperture="disk")
    _, shots = _plane_shots(settings, 2.5, torch.float64)
    out = DepthFromFocus(smoothing=0.0)(None, shots[None], settings, 1.0, 10.0)
    inverse = 1 / out["depth"][0, 0, 16:-16, 16:-16]
    gap = 1 / 1.5 - 1 / 2.5
    assert float((inverse - 1 / 2.5).abs().median()) < 0.1 * gap
    curve = torch.tensor([1.0, 4.0, 2.0]).reshape(1, 3, 1, 1)  # the peak leans to the third
    x = torch.tensor([[1 / 1.5, 1 / 2.5, 1 / 5.0]])
    assert 1 / 5.0 < float(focus_peak(curve, x)) < 1 / 2.5


def test_depth_from_focus_needs_a_stack_of_three():
    settings = CameraSettings(0.05, 2.0, [1.5, 4.0], 1e-4)
    with pytest.raises(ValueError, match="3 or more"):
        DepthFromFocus()(None, torch.rand(1, 2, 3, 16, 16), settings, 1.0, 10.0)


def test_relative_blur_gives_the_same_depth_in_float32_and_float64():
    image, depth, settings, focused = _stack_scene(seed=7)
    a = RelativeBlurDepth()(None, focused[None].float(), settings, 1.0, 8.0)["depth"]
    b = RelativeBlurDepth()(None, focused[None].double(), settings, 1.0, 8.0)["depth"]
    assert float(((a.double() - b).abs() / b).mean()) < 0.01


# -- defocus predict without --image ----------------------------------------------------------


def _write_pngs(folder: Path, settings: CameraSettings, seed=11) -> list[str]:
    rng = np.random.default_rng(seed)
    image, depth = generate_scene((96, 128), rng, (1.5, 5.0))
    _, focused = capture(image, depth, settings, rng, CaptureNoise.none())
    paths = []
    for i, shot in enumerate(focused):
        encoded = shot.clamp(0, 1) ** (1 / 2.2)  # near enough to sRGB for a fixture
        array = (encoded.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)
        paths.append(str(folder / f"shot{i}.png"))
        Image.fromarray(array).save(paths[-1])
    return paths


def test_predict_without_an_all_in_focus_photo(tmp_path, capsys):
    settings = CameraSettings(0.05, 2.0, [1.4, 4.5], 1e-4, aperture="disk")
    paths = _write_pngs(tmp_path, settings)
    out = tmp_path / "out"
    assert main(["predict", "--focused", *paths, "--focus-distance", "1.4", "4.5",
                 "--f-number", "2", "--focal-length", "0.05", "--pixel-pitch", "1e-4",
                 "--depth-range", "1", "8", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "method relative-blur" in printed
    for name in ("depth.npy", "depth_mm.png", "confidence.png", "all_in_focus.png", "figure.png"):
        assert (out / name).is_file(), name
    depth = np.load(out / "depth.npy")
    assert depth.shape == (96, 128) and np.isfinite(depth).all()
    fused, _ = read_photo(out / "all_in_focus.png")
    assert fused.shape == (3, 96, 128)


@pytest.mark.parametrize("case", ["one photo", "sizes", "same focus", "range", "sweep"])
def test_predict_without_image_refuses_bad_input_in_one_line(case, tmp_path, capsys):
    settings = CameraSettings(0.05, 2.0, [1.4, 4.5], 1e-4, aperture="disk")
    paths = _write_pngs(tmp_path, settings)
    camera = ["--f-number", "2", "--focal-length", "0.05", "--pixel-pitch", "1e-4"]
    focus, depth_range = ["--focus-distance", "1.4", "4.5"], ["--depth-range", "1", "8"]
    if case == "one photo":
        argv = ["--focused", paths[0], "--focus-distance", "1.4", *depth_range]
        expected = "2 or more --focused"
    elif case == "sizes":
        Image.open(paths[1]).crop((0, 0, 100, 90)).save(paths[1])
        argv = ["--focused", *paths, *focus, *depth_range]
        expected = "pixels but"
    elif case == "same focus":
        argv = ["--focused", *paths, "--focus-distance", "2", "2", *depth_range]
        expected = "same focus distance"
    elif case == "range":  # both focus planes far nearer than a narrow, distant range
        argv = ["--focused", *paths, *focus, "--depth-range", "400", "500"]
        expected = "cannot tell"
    else:
        argv = ["--focused", *paths, *focus, *depth_range, "--method", "sweep"]
        expected = "give --image"
    out = tmp_path / "out"
    assert main(["predict", *argv, *camera, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err, err
    assert not out.exists()


@pytest.mark.skipif(not (REAL / "breakfast" / "breakfast_near.png").is_file(),
                    reason="the real focus pair lives in ../shared/data/real (absent here)")
def test_predict_on_the_real_breakfast_pair(tmp_path):
    """The real 1998 pair (linear 16-bit, 25 mm f/8.3, focused at 0.529 and 0.869 m): the
    background comes out farther than the bread, the cup and the table front in front of it
    (regions and camera from that folder's README)."""
    folder = REAL / "breakfast"
    out = tmp_path / "out"
    assert main(["predict", "--focused", str(folder / "breakfast_near.png"),
                 str(folder / "breakfast_far.png"), "--focus-distance", "0.529", "0.869",
                 "--f-number", "8.3", "--focal-length", "0.025", "--pixel-pitch", "25e-6",
                 "--depth-range", "0.4", "1.5", "--linear", "--out", str(out)]) == 0
    depth = np.load(out / "depth.npy")
    regions = {"background": (10, 120, 20, 620), "bread": (200, 400, 50, 200),
               "cup": (180, 330, 280, 500), "table front": (440, 475, 20, 620)}
    medians = {name: float(np.median(depth[y0:y1, x0:x1]))
               for name, (y0, y1, x0, x1) in regions.items()}
    for name in ("bread", "cup", "table front"):
        assert medians["background"] > medians[name] * 1.2, medians


def test_a_nearly_sharp_image_is_one_more_shot_with_its_own_settings():
    """An f/8 photo beside f/2 ones focused at the same distance and another (as in the real
    DSLR set): with `image_settings` it is one more shot of the relative blur, not a perfect
    all-in-focus photo, and the depth beats the best constant."""
    rng = np.random.default_rng(9)
    image, depth = generate_scene((96, 128), rng, (1.5, 5.0))
    shots = CameraSettings(0.05, [8.0, 2.0, 2.0], [1.4, 1.4, 4.5], 1e-4, aperture="disk")
    _, photos = capture(image, depth, shots, rng, CaptureNoise())
    settings, f8 = shots.select_shots([1, 2]), shots.select_shots([0])
    out = estimate_depth(photos[1:], settings, (1.0, 8.0), image=photos[0], image_settings=f8)
    assert out["blur"].shape[0] == 3  # the f/8 photo counted as a shot
    error = ((out["depth"] - depth).abs() / depth).mean()
    constant = ((depth.median() - depth).abs() / depth).mean()
    assert float(error) < 0.6 * float(constant)
    with pytest.raises(ValueError, match="1 shot"):
        estimate_depth(photos[1:], settings, (1.0, 8.0), image=photos[0], image_settings=shots)


def test_predict_with_a_nearly_sharp_image(tmp_path, capsys):
    settings = CameraSettings(0.05, 2.0, [1.4, 4.5], 1e-4, aperture="disk")
    paths = _write_pngs(tmp_path, settings)
    out = tmp_path / "out"
    assert main(["predict", "--image", paths[0], "--image-f-number", "8", "--focused",
                 *paths, "--focus-distance", "1.4", "4.5", "--f-number", "2",
                 "--focal-length", "0.05", "--pixel-pitch", "1e-4", "--depth-range", "1", "8",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "--image is one more shot: f/8, focused at 1.4 m" in printed
    assert "method relative-blur" in printed
    assert main(["predict", "--image", paths[0], "--image-f-number", "8", "--method", "sweep",
                 "--focused", *paths, "--focus-distance", "1.4", "4.5", "--out",
                 str(tmp_path / "no")]) == 2
    assert "--image-f-number" in capsys.readouterr().err


def test_predict_takes_the_image_as_the_reference_shot_of_a_fitted_camera(tmp_path, capsys):
    """A camera JSON fitted with f/8 references (`reference_f_number`) makes --image an f/8
    shot unless the command says otherwise."""
    settings = CameraSettings(0.05, 2.0, [1.4, 4.5], 1e-4, aperture="disk")
    paths = _write_pngs(tmp_path, settings)
    camera = tmp_path / "camera.json"
    settings.to_json(camera, reference_f_number=8.0)
    common = ["--image", paths[0], "--focused", *paths, "--camera", str(camera),
              "--depth-range", "1", "8"]
    assert main(["predict", *common, "--out", str(tmp_path / "a")]) == 0
    printed = capsys.readouterr().out
    assert "--image counts as an f/8 shot (reference_f_number of" in printed
    assert "--image is one more shot: f/8, focused at 1.4 m" in printed
    assert main(["predict", *common, "--method", "sweep", "--out", str(tmp_path / "b")]) == 0
    printed = capsys.readouterr().out
    assert "counts as an f/8 shot" not in printed and "method sweep" in printed


# ---- depths the shots cannot place on one side of their focus plane --------------------------

@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mirrored_depths_is_the_span_with_an_equal_blur_elsewhere_in_the_range(dtype):
    from models.depth_from_photos import mirrored_depths, thin_lens_blur

    near, far = 1.0, 10.0
    settings = CameraSettings(0.035, [8.0, 2.8], [2.0, 2.0], 5.6e-5).to(dtype)
    span = mirrored_depths(settings, near, far)
    assert span == pytest.approx((1 / 0.9, 10.0))  # closed form: 1/D' = 2/2 - 1/D
    # independently: a depth has a twin in the range with the same blur in every shot
    inverse = torch.linspace(1 / far, 1 / near, 2001, dtype=torch.float64)
    blur = thin_lens_blur(settings.to(torch.float64).batched(1), inverse[None, None])[0]
    close = (blur[:, :, None] - blur[:, None, :]).abs().amax(0) < 1e-3 * blur.max()
    far_apart = (inverse[:, None] - inverse[None, :]).abs() > 0.02
    has_twin = (close & far_apart).any(1)
    depth = 1 / inverse
    inside = (depth > span[0] * 1.02) & (depth < span[1] / 1.02) & ((inverse - 0.5).abs() > 0.02)
    outside = (depth < span[0] / 1.02) | (depth > span[1] * 1.02)
    assert bool(has_twin[inside].all()) and not bool(has_twin[outside].any())


def test_mirrored_depths_none_for_two_focus_planes_or_a_focus_outside_the_range():
    from models.depth_from_photos import mirrored_depths

    assert mirrored_depths(CameraSettings(0.05, 2.0, [1.5, 4.0], 1e-4), 1.0, 10.0) is None
    assert mirrored_depths(CameraSettings(0.05, 2.0, [0.8], 1e-4), 1.0, 10.0) is None
    assert mirrored_depths(CameraSettings(0.05, 2.0, [12.0], 1e-4), 1.0, 10.0) is None


def test_estimate_depth_warns_where_one_focus_plane_splits_the_range():
    import warnings

    from models.depth_from_photos.estimate import warn_mirrored

    image = torch.rand(3, 24, 24)
    one_plane = CameraSettings(0.05, 2.0, [2.0], 1e-4)
    with pytest.warns(UserWarning, match="focused at 2 m.*between 1.11 and 10.00 m.*mirror"):
        estimate_depth(torch.rand(1, 3, 24, 24), one_plane, (1.0, 10.0), image=image)
    with warnings.catch_warnings():  # the range on one side, or two focus planes: no warning
        warnings.simplefilter("error")
        warn_mirrored(one_plane, 2.0, 10.0)
        warn_mirrored(CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4), 1.0, 10.0)


def test_no_mirror_warning_where_the_mirrored_depths_look_sharp():
    """A 2 cm ambiguous span around the focus plane blurs the shots by a few hundredths of a
    pixel: both sides look alike and sharp, so there is nothing to warn of."""
    import warnings

    from models.depth_from_photos.estimate import MIRROR_BLUR_PX, warn_mirrored

    one_plane = CameraSettings(0.05, 2.0, [2.0], 1e-4)
    assert float(one_plane.coc_at_infinity_px().abs()) * (2.01 / 1.99 - 1) < MIRROR_BLUR_PX
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_mirrored(one_plane, 1.99, 2.01)
    with pytest.warns(UserWarning, match="mirror"):
        warn_mirrored(one_plane, 1.5, 3.0)


def test_pair_errors_gradcheck():
    """Differentiable in both shots (the noise coefficients given), and the same values (to
    float64 rounding: the transforms are scipy's there) without gradients, where its chunk
    buffers are reused."""
    from models.depth_from_photos.relative_blur import pair_errors

    g = torch.Generator().manual_seed(0)
    first, second = (torch.rand(1, 3, 12, 12, generator=g, dtype=torch.float64,
                                requires_grad=True) for _ in range(2))
    noise = torch.tensor([[1e-4, 1e-3]], dtype=torch.float64)
    blurs = (torch.tensor([0.0, 1.5, 3.0], dtype=torch.float64),
             torch.tensor([2.0, 1.0, 0.5], dtype=torch.float64))

    def errors(a, b):
        return pair_errors(a, b, Disk(), *blurs, noise)

    assert torch.autograd.gradcheck(errors, (first, second))
    torch.testing.assert_close(errors(first, second).detach(),
                               errors(first.detach(), second.detach()), rtol=0, atol=1e-12)
