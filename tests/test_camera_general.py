"""The camera-general pipeline: random cameras and realistic photos, the thin-lens solve, safe
weights, and `defocus predict` on real-format photos (EXIF orientation, calibration JSON)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch
from PIL import Image

from datasets.capture import (
    CaptureNoise,
    RandomCameraScenes,
    capture,
    random_camera,
)
from datasets.io import DataFormatError
from datasets.photos import read_photo
from datasets.synthetic import generate_scene
from defocus.cli import main
from models.depth_from_photos import (
    BlurNet,
    DepthFromDefocus,
    solve_depth,
    texture_weight,
    working_scale,
)
from models.depth_from_photos.blur_net import blur_loss
from models.loading import is_weights_file, load_weights, save_weights, sha256
from models.metrics import best_constant_depth
from optics import CameraSettings


def test_random_cameras_hit_their_blur_target():
    rng = np.random.default_rng(0)
    for _ in range(20):
        s = random_camera(rng, 2.0, 9.0, n_shots=3, max_coc_px=(2.0, 6.0))
        assert s.n_shots == 3 and 2.0 - 1e-6 <= s.largest_coc_px(2.0, 9.0) <= 6.0 + 1e-6
        assert bool((s.focal_length >= 0.018).all() and (s.focal_length <= 0.2).all())


def test_samples_hold_the_true_coc_of_their_camera():
    data = RandomCameraScenes(pool_size=2, scene_size=(40, 40), crop=(32, 32), seed=1)
    sample = data.sample(np.random.default_rng(3))
    assert sample["image"].shape == (3, 32, 32) and sample["focused"].shape == (2, 3, 32, 32)
    expected = sample["camera"].camera().signed_coc_px(sample["depth"][None].expand(2, 1, 32, 32))
    torch.testing.assert_close(sample["coc_px"], expected, rtol=1e-4, atol=1e-4)


def test_capture_without_imperfections_is_the_render():
    rng = np.random.default_rng(0)
    image, depth = generate_scene((24, 24), rng, (1.5, 6.0))
    s = CameraSettings(0.05, 2.0, [2.0, 5.0], 1e-4, "disk")
    aif, focused = capture(image, depth, s, rng, CaptureNoise.none(), mode="scatter")
    torch.testing.assert_close(aif, image)
    expected = s.shot(1).render(image[None].double(), depth[None].double())[0].float()
    torch.testing.assert_close(focused[1], expected, atol=1e-5, rtol=0)


def test_capture_saves_jpegs_as_pillow_does(tmp_path):
    from kornia.color import linear_rgb_to_rgb, rgb_to_linear_rgb

    from datasets.capture import take_photos

    rng = np.random.default_rng(0)
    image, _ = generate_scene((32, 48), rng, (1.5, 6.0))
    perfect = CaptureNoise.none()
    eight_bit = CaptureNoise(0.0, 0.0, 0.0, 0.0, 0.0, 8)
    jpeg = CaptureNoise(0.0, 0.0, 0.0, 0.0, 0.0, 8, jpeg_quality=80)
    stored, _ = take_photos(image, image[None], rng, eight_bit)
    compressed, focused = take_photos(image, image[None], rng, jpeg)
    # independently: the 8-bit photo through Pillow's JPEG at quality 80, decoded
    levels = np.round(linear_rgb_to_rgb(stored).permute(1, 2, 0).double().numpy() * 255)
    Image.fromarray(levels.astype(np.uint8)).save(tmp_path / "p.jpg", quality=80)
    decoded = torch.from_numpy(np.asarray(Image.open(tmp_path / "p.jpg"), dtype=np.float64) / 255)
    torch.testing.assert_close(compressed, rgb_to_linear_rgb(decoded.permute(2, 0, 1)).float(),
                               rtol=0, atol=1e-6)
    torch.testing.assert_close(focused[0], compressed)  # every shot is saved alike
    error = (compressed - take_photos(image, image[None], rng, perfect)[0]).abs().mean()
    assert 0 < float(error) < 0.02  # lossy, but close


@pytest.mark.parametrize(("fields", "message"), [
    ({"jpeg_quality": 96}, "jpeg_quality must be an integer in 1-95"),
    ({"jpeg_quality": -1}, "jpeg_quality must be an integer in 1-95"),
    ({"jpeg_quality": 90.0}, "jpeg_quality must be an integer in 1-95"),
    ({"jpeg_quality": True}, "jpeg_quality must be an integer in 1-95"),
    ({"jpeg_quality": 90, "bits": 0}, "bits must be 8 for jpeg_quality=90"),
])
def test_capture_noise_refuses_an_impossible_jpeg(fields, message):
    with pytest.raises(ValueError, match=message):
        CaptureNoise(**fields)


@pytest.mark.parametrize("depth_value", [1.3, 2.5, 4.0, 7.5])
def test_solve_recovers_depth_from_exact_blurs(depth_value):
    s = CameraSettings(0.05, 1.4, [2.0, 6.0], 1e-4)
    depth = torch.full((1, 1, 16, 16), depth_value, dtype=torch.float64)
    blur = s.to(torch.float64).camera().coc_px(depth.expand(2, 1, 16, 16)).reshape(1, 2, 16, 16)
    solved, confidence = solve_depth(blur, torch.ones(1, 1, 16, 16, dtype=torch.float64), s,
                                     1.0, 10.0, n_candidates=256)
    torch.testing.assert_close(solved, depth, rtol=0.01, atol=0)
    assert bool((confidence > 0.9).all())


def test_confidence_is_lower_where_there_is_no_texture():
    g = torch.Generator().manual_seed(0)
    image = torch.rand(1, 3, 64, 64, generator=g) * 0.8
    image[..., :, :32] = 0.4  # the left half is flat
    _, confidence = solve_depth(torch.ones(1, 2, 64, 64), texture_weight(image),
                                CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4), 1.0, 10.0)
    flat, textured = confidence[..., 8:-8, 4:20].mean(), confidence[..., 8:-8, 44:60].mean()
    assert float(flat) < 0.5 * float(textured)


class _ConstantBlur(torch.nn.Module):
    """A "network" that answers one blur everywhere (a fresh BlurNet's output is about this)."""

    def __init__(self, blur: float):
        super().__init__()
        self.blur = torch.nn.Parameter(torch.tensor(blur, dtype=torch.float64))

    def forward(self, image, focused):
        return self.blur.expand_as(image[:, :1])


def test_a_fresh_blur_net_starts_inside_the_blurs_it_reads():
    image = torch.rand(2, 3, 40, 40, generator=torch.Generator().manual_seed(0))
    torch.manual_seed(0)
    start = BlurNet(width=8)(image, image)
    assert 2.0 <= float(start.min()) and float(start.max()) <= 8.0


def _loss_slope(guess: float, image, focused, **kwargs) -> float:
    net = _ConstantBlur(guess)
    blur_loss(net, image, focused, **kwargs).backward()
    return float(net.blur.grad)


@pytest.mark.parametrize("truth, guess", [(3.0, 1.5), (3.0, 4.5), (2.0, 0.5), (0.0, 1.0)])
def test_self_supervised_loss_points_to_the_true_blur_from_either_side(truth, guess):
    # A PSF under a pixel spreads nothing, so a loss that renders the guess alone has no
    # gradient below a pixel (and a network there collapsed); both sides get a floor blur.
    from models.depth_from_photos.blur_net import LOSS_PSF
    from optics import Disk, render_defocus

    image = torch.rand(2, 3, 40, 40, generator=torch.Generator().manual_seed(0),
                       dtype=torch.float64)
    focused = render_defocus(image, torch.full_like(image[:, :1], truth), psf=LOSS_PSF)
    slope = _loss_slope(guess, image, focused)
    assert slope * (guess - truth) > 1e-5  # descent moves the guess towards the truth
    # without the floor a sub-pixel guess has no gradient at all
    flat = _ConstantBlur(0.7)
    rendered = render_defocus(image, flat.blur.expand_as(image[:, :1]), psf=Disk())
    (rendered - focused).abs().mean().backward()
    assert abs(float(flat.blur.grad)) < 1e-12


def test_self_supervised_loss_compares_the_clean_views_when_given():
    # A pixel of misalignment looks like blur, so imperfect photos pull the answer up; the
    # clean views of the same scene do not.
    from models.depth_from_photos.blur_net import LOSS_PSF
    from optics import render_defocus

    gen = torch.Generator().manual_seed(1)
    clean = torch.rand(2, 3, 48, 48, generator=gen, dtype=torch.float64)
    clean_focused = render_defocus(clean, torch.full_like(clean[:, :1], 3.0), psf=LOSS_PSF)
    noisy = clean + 0.02 * torch.randn(clean.shape, generator=gen, dtype=torch.float64)
    shifted = torch.roll(clean_focused, 1, -1)
    shifted = shifted + 0.02 * torch.randn(clean.shape, generator=gen, dtype=torch.float64)
    guesses = torch.linspace(1.0, 6.0, 21).tolist()

    def best(**kwargs) -> float:
        losses = []
        for g in guesses:
            with torch.no_grad():
                losses.append(float(blur_loss(_ConstantBlur(g), noisy, shifted,
                                              smoothness=0.0, **kwargs)))
        return guesses[int(np.argmin(losses))]

    with_clean = best(clean=(clean, clean_focused))
    assert abs(with_clean - 3.0) <= 0.5
    assert best() >= with_clean + 0.5  # the bias the clean views remove


def test_working_scale_bounds_the_blur_and_the_pixels():
    s = CameraSettings(0.05, 1.4, [2.0, 6.0], 6e-6)  # 50 mm f/1.4, 6 um pixels
    scale = working_scale(s, 1.0, 10.0, (3000, 4000), max_coc_px=12.0)
    small = s.replace(pixel_pitch=s.pixel_pitch / scale)
    assert small.largest_coc_px(1.0, 10.0) == pytest.approx(12.0, rel=1e-6)
    assert working_scale(s.replace(pixel_pitch=1e-3), 1.0, 10.0, (3000, 4000)) \
        == pytest.approx((1.5e6 / 12e6) ** 0.5)


def test_weights_round_trip_and_hash(tmp_path):
    torch.manual_seed(0)
    model = DepthFromDefocus(BlurNet(width=4))
    digest = save_weights(model, tmp_path / "w.pt", steps=1)
    assert digest == sha256(tmp_path / "w.pt") and is_weights_file(tmp_path / "w.pt")
    again = load_weights(tmp_path / "w.pt", digest)
    x = torch.rand(1, 3, 16, 16)
    torch.testing.assert_close(again.blur_net(x, x), model.blur_net(x, x))
    (tmp_path / "bad.pt").write_bytes((tmp_path / "w.pt").read_bytes() + b"\0")
    with pytest.raises(ValueError, match="sha256"):
        load_weights(tmp_path / "bad.pt", digest)
    (tmp_path / "photo.png").write_bytes(b"\x89PNG not really")
    assert not is_weights_file(tmp_path / "photo.png")


def _write_jpeg(path, array, orientation=1, focal_mm=None, f_number=None, **tags):
    exif = Image.Exif()
    exif[274] = orientation
    detail = {int(tag.lstrip("_")): value for tag, value in tags.items()}
    if focal_mm is not None:
        detail[37386] = float(focal_mm)
    if f_number is not None:
        detail[33437] = float(f_number)
    if detail:
        exif[0x8769] = detail
    Image.fromarray(array).save(path, quality=95, exif=exif.tobytes())


def test_read_photo_applies_exif_orientation_and_values(tmp_path):
    stored = np.zeros((20, 30, 3), np.uint8)
    stored[:5] = 255  # the top rows are white as stored
    _write_jpeg(tmp_path / "p.jpg", stored, orientation=6, focal_mm=50, f_number=2.8)
    image, info = read_photo(tmp_path / "p.jpg")
    assert image.shape == (3, 30, 20)  # orientation 6: turned 90 degrees clockwise to view
    assert float(image[:, :, -5:].mean()) > 0.8 and float(image[:, :, :5].mean()) < 0.1
    assert info.orientation == 6
    assert info.focal_length == pytest.approx(0.05) and info.f_number == pytest.approx(2.8)


def test_read_photo_pixel_pitch_from_the_35mm_equivalent_focal_length(tmp_path):
    # a phone: 4.2 mm lens, "26 mm" equivalent, no focal-plane resolution; 40x30 pixels stored
    stored = np.zeros((30, 40, 3), np.uint8)
    sensor_diagonal = 0.0432666 * 4.2 / 26  # metres: full frame's diagonal over the crop factor
    for orientation in (1, 6):  # turning the photo upright changes no pixel's size
        _write_jpeg(tmp_path / "p.jpg", stored, orientation, focal_mm=4.2, _41989=26)
        _, info = read_photo(tmp_path / "p.jpg")
        assert info.pixel_pitch == pytest.approx(sensor_diagonal / 50, rel=1e-5)
        assert info.pixel_pitch_source == "35 mm equivalent"
    # the focal-plane resolution, where given, is read first: 1000 pixels per centimetre
    _write_jpeg(tmp_path / "p.jpg", stored, focal_mm=4.2, _41989=26, _41486=1000.0, _41488=3)
    _, info = read_photo(tmp_path / "p.jpg")
    assert info.pixel_pitch == pytest.approx(1e-5) and info.pixel_pitch_source == \
        "focal-plane resolution"
    # a resolution unit EXIF does not define (9) is not taken for inches: the equivalent holds
    _write_jpeg(tmp_path / "p.jpg", stored, focal_mm=4.2, _41989=26, _41486=1000.0, _41488=9)
    _, info = read_photo(tmp_path / "p.jpg")
    assert info.pixel_pitch_source == "35 mm equivalent"
    # without the real focal length the equivalent alone gives no pitch
    _write_jpeg(tmp_path / "p.jpg", stored, _41989=26)
    assert read_photo(tmp_path / "p.jpg")[1].pixel_pitch is None


def test_jpeg_photos_are_known_as_compressed_and_warned_of_when_read_at_full_size(tmp_path):
    from datasets.photos.settings import JPEG_SCALE_LIMIT, compression_warning

    stored = np.zeros((8, 8, 3), np.uint8)
    _write_jpeg(tmp_path / "a.jpg", stored)
    Image.fromarray(stored).save(tmp_path / "b.png")
    jpeg, png = read_photo(tmp_path / "a.jpg")[1], read_photo(tmp_path / "b.png")[1]
    assert jpeg.compressed and not png.compressed
    assert compression_warning([png], 1.0) is None
    assert compression_warning([png, jpeg], JPEG_SCALE_LIMIT) is None  # downscaled enough
    assert compression_warning([png, jpeg], 1.0).startswith("a.jpg: JPEG photos read at 1.00")


def _deep_photo(seed=0, shape=(12, 18, 3)):
    return np.random.default_rng(seed).integers(0, 65536, shape, dtype=np.uint16)


def test_read_photo_keeps_all_16_bits_of_a_colour_tiff_and_png(tmp_path):
    import png
    import tifffile
    from kornia.color import rgb_to_linear_rgb

    stored = _deep_photo()
    expected = rgb_to_linear_rgb(torch.from_numpy(stored.astype(np.float64) / 65535)
                                 .permute(2, 0, 1))
    tifffile.imwrite(tmp_path / "p.tif", stored, photometric="rgb")
    png.from_array(stored.reshape(12, -1), "RGB;16").save(tmp_path / "p.png")
    for name in ("p.tif", "p.png"):
        image, _ = read_photo(tmp_path / name, dtype=torch.float64)
        torch.testing.assert_close(image, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_a_16_bit_tiff_is_turned_upright_as_pillow_turns_an_8_bit_one(tmp_path, orientation):
    import tifffile

    stored = (_deep_photo(orientation) // 257).astype(np.uint8)
    tag = [(274, "H", 1, orientation, True)]
    tifffile.imwrite(tmp_path / "8.tif", stored, photometric="rgb", extratags=tag)
    tifffile.imwrite(tmp_path / "16.tif", stored.astype(np.uint16) * 257, photometric="rgb",
                     extratags=tag)
    eight, info = read_photo(tmp_path / "8.tif", dtype=torch.float64)
    sixteen, _ = read_photo(tmp_path / "16.tif", dtype=torch.float64)
    assert info.orientation == orientation
    assert eight.shape[1:] == ((18, 12) if orientation >= 5 else (12, 18))  # Pillow turned it
    torch.testing.assert_close(sixteen, eight, rtol=0, atol=1e-12)


def test_a_16_bit_tiff_tifffile_cannot_decode_is_read_by_pillow_with_a_warning(tmp_path,
                                                                                monkeypatch):
    import tifffile

    stored = _deep_photo()
    tifffile.imwrite(tmp_path / "p.tif", stored, photometric="rgb")

    def no_codec(*args, **kwargs):
        raise KeyError("<COMPRESSION.LZW: 5> requires the 'imagecodecs' package")

    monkeypatch.setattr(tifffile, "imread", no_codec)
    with pytest.warns(UserWarning, match="8 bits per channel only.*imagecodecs"):
        image, _ = read_photo(tmp_path / "p.tif", dtype=torch.float64)
    assert image.shape == (3, 12, 18)


def test_read_photo_refuses_a_floating_point_tiff_clearly(tmp_path):
    import tifffile

    tifffile.imwrite(tmp_path / "f.tif", np.random.default_rng(0).random((8, 8, 3), np.float32),
                     photometric="rgb")
    with pytest.raises(DataFormatError, match=r"f\.tif.*float32.*8- or 16-bit"):
        read_photo(tmp_path / "f.tif")


@pytest.fixture()
def photos(tmp_path):
    """A scene photographed through a 50 mm f/1.4 camera, as JPEGs, and a weights file."""
    def make(orientation=1, distances=None):
        rng = np.random.default_rng(0)
        image, depth = generate_scene((48, 64), rng, (1.5, 6.0))
        settings = CameraSettings(0.05, 1.4, [2.0, 6.0], 180e-6, "disk")
        aif, focused = capture(image, depth, settings, rng, CaptureNoise())
        from kornia.color import linear_rgb_to_rgb

        paths = []
        for i, linear in enumerate([aif, *focused]):
            srgb = (linear_rgb_to_rgb(linear.clamp(0, 1)).permute(1, 2, 0).numpy() * 255).round()
            path = tmp_path / f"shot{i}_{orientation}.jpg"
            tags = {} if distances is None or i == 0 else {"_37382": distances[i - 1]}
            _write_jpeg(path, srgb.astype(np.uint8), orientation, focal_mm=50, f_number=1.4,
                        **tags)
            paths.append(str(path))
        torch.manual_seed(0)
        save_weights(DepthFromDefocus(BlurNet(width=4)), tmp_path / "w.pt")
        return [str(tmp_path / "w.pt"), "--image", paths[0], "--focused", *paths[1:]]
    return make


def test_predict_reads_exif_and_a_calibration_json(photos, tmp_path, capsys):
    args = photos()
    # 48x64 JPEGs are read at their full resolution: the compression would read as blur
    with pytest.warns(UserWarning, match=r"shot0_1.jpg, shot1_1.jpg, shot2_1.jpg: JPEG photos "
                                         r"read at 1.00 of their resolution"):
        assert main(["predict", *args, "--focus-distance", "2", "6", "--pixel-pitch", "180e-6",
                     "--depth-range", "1", "8", "--out", str(tmp_path / "a")]) == 0
    # it says which camera it used, and where each value came from
    assert ("camera: focal length 50.0 mm (EXIF), f/1.4 (EXIF), pixel pitch 180.00 um (given), "
            "focused at 2, 6 m (given)") in capsys.readouterr().out
    a = np.load(tmp_path / "a" / "depth.npy")
    assert a.shape == (48, 64) and np.isfinite(a).all() and 1 <= a.min() and a.max() <= 8
    mm = np.asarray(Image.open(tmp_path / "a" / "depth_mm.png"))
    assert mm.dtype == np.uint16 and abs(int(mm[10, 10]) - round(float(a[10, 10]) * 1000)) <= 1
    assert (tmp_path / "a" / "confidence.png").is_file() and (tmp_path / "a" / "figure.png").is_file()
    # the same camera from a calibration JSON (focal length, f-number, pitch, focus distances)
    CameraSettings(0.05, 1.4, [2.0, 6.0], 180e-6, "disk").to_json(tmp_path / "fit.json")
    assert main(["predict", *args, "--camera", str(tmp_path / "fit.json"),
                 "--depth-range", "1", "8", "--out", str(tmp_path / "b")]) == 0
    assert "50.0 mm (calibration), f/1.4 (calibration)" in capsys.readouterr().out
    np.testing.assert_allclose(np.load(tmp_path / "b" / "depth.npy"), a, rtol=1e-5)


def test_predict_takes_focus_distances_from_exif_where_every_photo_states_them(photos, tmp_path,
                                                                              capsys):
    common = ["--pixel-pitch", "180e-6", "--depth-range", "1", "8"]
    given = photos()[1:]  # no weights: the sweep
    assert main(["predict", *given, "--focus-distance", "2", "6", *common,
                 "--out", str(tmp_path / "given")]) == 0
    # photos that do not state it: one line saying what to give
    assert main(["predict", *given, *common, "--out", str(tmp_path / "none")]) == 2
    assert "give --focus-distance with one value per focused photo (2): no photo's EXIF " \
           "states it" in capsys.readouterr().err
    # the same photos (rewritten) stating SubjectDistance 2 m and 6 m
    stated = photos(distances=[2.0, 6.0])[1:]
    assert main(["predict", *stated, *common, "--out", str(tmp_path / "exif")]) == 0
    assert "focused at 2, 6 m (EXIF)" in capsys.readouterr().out
    np.testing.assert_array_equal(np.load(tmp_path / "exif" / "depth.npy"),
                                  np.load(tmp_path / "given" / "depth.npy"))
    # the command line wins over EXIF
    assert main(["predict", *stated, "--focus-distance", "2.5", "6", *common,
                 "--out", str(tmp_path / "over")]) == 0
    assert "focused at 2.5, 6 m (given)" in capsys.readouterr().out


def test_predict_without_a_model_file_sweeps_over_depth(photos, tmp_path, capsys):
    args = photos()[1:]  # no model file: the sweep
    assert main(["predict", *args, "--focus-distance", "2", "6", "--pixel-pitch", "180e-6",
                 "--depth-range", "1", "8", "--out", str(tmp_path / "s")]) == 0
    depth = np.load(tmp_path / "s" / "depth.npy")
    rng = np.random.default_rng(0)
    _, truth = generate_scene((48, 64), rng, (1.5, 6.0))  # the fixture's scene
    truth = truth[0].numpy()
    constant = best_constant_depth(target=torch.from_numpy(truth))
    assert np.mean(np.abs(depth - truth) / truth) < 0.8 * np.mean(np.abs(constant - truth) / truth)
    assert main(["predict", "--image", args[1], "--depth-range", "1", "8"]) == 2
    assert "--focused" in capsys.readouterr().err


def test_predict_sweeps_with_the_chosen_aggregation(photos, tmp_path):
    """`--aggregation windows` runs the sweep of `SweepDepth(aggregation="windows")`."""
    args = photos()[1:]
    common = [*args, "--focus-distance", "2", "6", "--pixel-pitch", "180e-6",
              "--depth-range", "1", "8"]
    assert main(["predict", *common, "--aggregation", "windows", "--out", str(tmp_path / "w")]) == 0
    assert main(["predict", *common, "--out", str(tmp_path / "s")]) == 0
    windows, semi_global = (np.load(tmp_path / name / "depth.npy") for name in ("w", "s"))
    assert np.isfinite(windows).all() and not np.allclose(windows, semi_global)


def test_predict_runs_on_the_chosen_device(photos, tmp_path, device):
    """`--device` (CUDA where present): the same depth as on the CPU, written from host memory."""
    args = photos()[1:]
    common = [*args, "--focus-distance", "2", "6", "--pixel-pitch", "180e-6",
              "--depth-range", "1", "8"]
    assert main(["predict", *common, "--device", str(device), "--out", str(tmp_path / "d")]) == 0
    assert main(["predict", *common, "--device", "cpu", "--out", str(tmp_path / "c")]) == 0
    here, cpu = (np.load(tmp_path / name / "depth.npy") for name in ("d", "c"))
    assert np.median(np.abs(here - cpu) / cpu) < 1e-3


def test_predict_says_when_it_narrows_the_stated_range(photos, tmp_path, capsys):
    """0.3-20 m for a scene at 1.5-6 m: the blur at 0.3 m would shrink the photos; the second
    pass works over the scene's own range."""
    args = photos()[1:]
    assert main(["predict", *args, "--focus-distance", "2", "6", "--pixel-pitch", "180e-6",
                 "--depth-range", "0.3", "20", "--out", str(tmp_path / "n")]) == 0
    out = capsys.readouterr().out
    assert "the scene lies within" in out and "working resolution 1.000" in out, out
    depth = np.load(tmp_path / "n" / "depth.npy")
    assert np.isfinite(depth).all() and 1.0 < np.median(depth) < 8.0


def test_predict_rotated_photos_come_out_upright(photos, tmp_path):
    args = photos(orientation=6)
    assert main(["predict", *args, "--focus-distance", "2", "6", "--pixel-pitch", "180e-6",
                 "--depth-range", "1", "8", "--out", str(tmp_path / "r")]) == 0
    assert np.load(tmp_path / "r" / "depth.npy").shape == (64, 48)


def test_predict_says_which_camera_value_is_missing(photos, tmp_path, capsys):
    args = photos()
    assert main(["predict", *args, "--focus-distance", "2", "6", "--depth-range", "1", "8",
                 "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "pixel_pitch is unknown" in err and "--pixel-pitch" in err


def test_the_blur_net_example_trains_from_a_config_with_photo_imperfections(tmp_path, capsys):
    """The experimental camera-general network trains from `examples/blur_net.py` (it left the
    command line: it measures worse than the sweep), and a bad config key is one line."""
    import importlib.util
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "examples" / "blur_net.py"
    spec = importlib.util.spec_from_file_location("example_blur_net", script)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    config = tmp_path / "tiny.yaml"
    config.write_text("seed: 0\nwidth: 4\nsteps: 2\nbatch_size: 2\nlr: 0.001\npool_size: 2\n"
                      "scene_size: [40, 40]\ncrop: [32, 32]\nmax_coc_px: [0.5, 6.0]\nthreads: 1\n"
                      "noise: {read: 0.0, shot: 0.0, shift_px: 0.0, bits: 0}\n")
    assert example.main(["--config", str(config), "--out", str(tmp_path / "run")]) == 0
    weights = tmp_path / "run" / "dfd_general.pt"
    assert is_weights_file(weights) and load_weights(weights).blur_net.width == 4
    config.write_text(config.read_text().replace("shift_px", "shfit_px"))
    assert example.main(["--config", str(config), "--out", str(tmp_path / "bad")]) == 2
    assert "shfit_px" in capsys.readouterr().err
    from defocus.cli import COMMANDS

    assert "pretrain" not in COMMANDS


def _cameras_benchmark():
    """The `benchmarks/cameras.py` module (benchmarks are scripts, not a package)."""
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    try:
        import cameras
    finally:
        sys.path.pop(0)
    return cameras


def test_the_cameras_benchmark_runs_on_jpeg_photos(capsys):
    """`benchmarks/cameras.py` end to end on the demo camera, its photos saved as JPEGs."""
    cameras = _cameras_benchmark()
    assert cameras.main(["--cameras", "demo", "--no-direct", "--jpeg", "90"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("| demo"))
    ratio = float(row.split("|")[5])
    assert 0 < ratio < 1  # better than a constant, even through JPEG
    assert "sweep: ratio <= 0.30 for every camera" in out


def test_the_cameras_benchmark_places_the_third_shot():
    """`--third`: midway between the pair in inverse depth, one step of its spacing nearer, or
    midway through the stated depth range (an independent computation in dioptres); anything
    else is refused by name."""
    cameras = _cameras_benchmark()
    near, far = 4.0, 12.0  # dioptres 0.25 and 1/12: spacing 1/6
    assert cameras.third_focus((near, far)) == pytest.approx(1 / (1 / 4 + 1 / 12) * 2)
    assert 1 / cameras.third_focus((near, far), "nearer") == pytest.approx(0.25 + 1 / 6)
    near_range, far_range = cameras.DEPTH_RANGE
    assert 1 / cameras.third_focus((near, far), "range") == pytest.approx(
        (1 / near_range + 1 / far_range) / 2)
    assert set(cameras.THIRD_SHOT) == {"midway", "nearer", "range"}
    with pytest.raises(ValueError, match="placement must be one of"):
        cameras.third_focus((near, far), "middle")
