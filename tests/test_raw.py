"""Tests of datasets.photos.raw: real raw files (../shared/data/raw) and synthetic Bayer DNGs."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
from _synthetic_dng import BLACK, WB, WHITE, write_dng

from datasets.photos import (
    PhotoMetadata,
    RawReadError,
    metadata_sensor,
    metadata_settings,
    read_metadata,
    read_raw,
    read_raw_stack,
    resolve_known,
)
from optics import CameraSettings

SAMPLES = Path(os.environ.get("DEFOCUS_RAW_SAMPLES", Path(__file__).parents[2] / "shared/data/raw"))
needs_samples = pytest.mark.skipif(
    not (SAMPLES / "canon_eos_6d.dng").is_file(),
    reason=f"real raw samples not found in {SAMPLES} (set DEFOCUS_RAW_SAMPLES)",
)
REFUSED = ["truncated_CanonRaw.cr2", "truncated_CanonRaw.cr3", "truncated_FujiFilm.raf",
           "truncated_Minolta.mrw", "truncated_Nikon.nef", "truncated_Sigma.x3f"]


@needs_samples
def test_canon_linear_dng_image_and_metadata():
    import rawpy

    path = SAMPLES / "canon_eos_6d.dng"
    image, meta = read_raw(path, white_balance="none", binning=4)
    assert image.shape == (1, 3, 816 // 4, 1224 // 4) and image.dtype == torch.float32
    assert meta.focal_length == pytest.approx(0.065)
    assert meta.f_number == pytest.approx(5.6)
    assert meta.lens_model == "EF24-105mm f/4L IS USM"
    assert meta.camera_make == "Canon" and meta.camera_model == "Canon EOS 6D"
    assert meta.iso == 1000 and meta.exposure_time == pytest.approx(1 / 60, rel=1e-5)
    assert meta.binning == 4 and meta.cfa_pattern is None  # linear (demosaiced) DNG
    # Linear: the raw values over the white level, averaged in 4x4 blocks, no gamma.
    with rawpy.imread(str(path)) as raw:
        values = raw.raw_image_visible[..., :3].astype(np.float64) / raw.white_level
    expected = torch.from_numpy(values).permute(2, 0, 1)[None]
    expected = torch.nn.functional.avg_pool2d(expected, 4)
    torch.testing.assert_close(image.double(), expected, atol=2e-5, rtol=0)


@needs_samples
@pytest.mark.parametrize("name", REFUSED)
def test_truncated_files_fail_clearly(name):
    with pytest.raises(RawReadError, match=name.replace(".", r"\.")):
        read_raw(SAMPLES / name)
    with pytest.raises(RawReadError, match="LibRaw cannot read"):
        read_metadata(SAMPLES / name)


@needs_samples
def test_stripped_dng_refused_but_metadata_read():
    path = SAMPLES / "truncated_DNG.dng"
    with pytest.raises(RawReadError, match="truncated_DNG.dng: the file holds no image data"):
        read_raw(path)
    meta = read_metadata(path)
    assert meta.focal_length == pytest.approx(0.055) and meta.f_number == pytest.approx(8.0)
    assert meta.camera_model == "Canon EOS 350D DIGITAL"


@needs_samples
def test_panasonic_stripped_data_never_crashes():
    # LibRaw fills the missing pixel data with noise or stale memory, depending on what was read
    # before: either a finite image comes back or a clear refusal naming the file.
    path = SAMPLES / "truncated_Panasonic.rw2"
    try:
        image, _ = read_raw(path, binning=8)
        assert image.shape[:2] == (1, 3) and torch.isfinite(image).all()
    except RawReadError as error:
        assert "truncated_Panasonic.rw2: the file holds no image data" in str(error)
    meta = read_metadata(path)
    assert meta.focal_length == pytest.approx(0.0051) and meta.f_number == pytest.approx(4.0)
    assert meta.camera_model == "DMC-LX3" and meta.cfa_pattern is not None


def _mosaic(h=32, w=48, seed=0):
    rng = np.random.default_rng(seed)
    return rng.integers(BLACK, WHITE + 1, size=(h, w)).astype(np.uint16)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.dng"):
        read_raw(tmp_path / "nope.dng")


def test_synthetic_metadata(tmp_path):
    path = write_dng(tmp_path / "a.dng", _mosaic(), f_number=2.8, focal_length_mm=50.0,
                     pixel_pitch=4e-6, lens="Lens X")
    image, meta = read_raw(path, binning=2)
    assert (meta.focal_length, meta.f_number, meta.lens_model) == (0.05, 2.8, "Lens X")
    assert meta.camera_make == "Defocus" and meta.iso == 400
    assert meta.cfa_pattern == "RGGB"
    assert meta.black_level == [BLACK] * 4 and meta.white_level == WHITE
    assert meta.pixel_pitch == pytest.approx(4e-6)
    np.testing.assert_allclose(meta.camera_white_balance, WB, rtol=1e-3)
    sensor = metadata_sensor(meta)
    assert float(sensor.effective_pixel_pitch) == pytest.approx(8e-6)
    assert resolve_known([meta])[0]["pixel_pitch"] == pytest.approx(8e-6)
    settings = metadata_settings(meta, 2.0, aperture="disk")
    assert isinstance(settings, CameraSettings) and tuple(settings.shape) == (1,)
    assert settings.aperture == "disk" and float(settings.focus_distance) == 2.0
    assert float(settings.focal_length) == 0.05 and float(settings.f_number) == 2.8
    assert float(settings.pixel_pitch) == pytest.approx(8e-6)  # sensor pitch x binning
    assert float(metadata_settings(meta, 2.0, pixel_pitch=5e-6).pixel_pitch) == pytest.approx(1e-5)
    assert metadata_settings(meta, [1.0, 3.0]).shot(1).lens.focus_distance == 3.0


def test_camera_settings_name_what_the_file_lacks():
    meta = PhotoMetadata("bare.dng", {"f_number": 4.0})
    with pytest.raises(ValueError, match=r"bare\.dng: .*focal length.*pass focal_length in "
                       r"metres.*pixel pitch.*pass pixel_pitch") as error:
        metadata_settings(meta, 2.0)
    assert "f-number" not in str(error.value)
    settings = metadata_settings(meta, 2.0, pixel_pitch=5e-6, focal_length=0.035)
    assert float(settings.focal_length) == 0.035 and float(settings.pixel_pitch) == 5e-6
    with pytest.raises(ValueError, match="focus_distance must be > focal_length"):
        metadata_settings(meta, 0.01, pixel_pitch=5e-6, focal_length=0.035)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_half_size_is_black_subtracted_white_scaled(tmp_path, dtype):
    raw = _mosaic()
    path = write_dng(tmp_path / "a.dng", raw)
    image, _ = read_raw(path, white_balance="none", binning=2, dtype=dtype)
    scaled = (raw.astype(np.float64) - BLACK) / (WHITE - BLACK)
    expected = np.stack([scaled[0::2, 0::2], (scaled[0::2, 1::2] + scaled[1::2, 0::2]) / 2,
                         scaled[1::2, 1::2]])
    assert image.dtype == dtype and image.shape == (1, 3, 16, 24)
    np.testing.assert_allclose(image[0].double().numpy(), expected, atol=4e-5)
    # Binning by 4: 2x2 averages of the half-size image.
    image4, meta4 = read_raw(path, white_balance="none", binning=4, dtype=dtype)
    pooled = expected.reshape(3, 8, 2, 12, 2).mean((2, 4))
    np.testing.assert_allclose(image4[0].double().numpy(), pooled, atol=4e-5)
    assert meta4.binning == 4


def test_full_resolution_keeps_sampled_values_and_white_balance(tmp_path):
    raw = _mosaic()
    path = write_dng(tmp_path / "a.dng", raw)
    plain, _ = read_raw(path, white_balance="none", demosaic="linear")
    balanced, meta = read_raw(path, white_balance="camera", demosaic="linear")
    scaled = (raw.astype(np.float64) - BLACK) / (WHITE - BLACK)
    # At a red site the red value is the sample itself, at a blue site the blue one.
    np.testing.assert_allclose(plain[0, 0, 0::2, 0::2].numpy(), scaled[0::2, 0::2], atol=4e-5)
    np.testing.assert_allclose(plain[0, 2, 1::2, 1::2].numpy(), scaled[1::2, 1::2], atol=4e-5)
    gains = torch.tensor(meta.white_balance).view(1, 3, 1, 1)
    torch.testing.assert_close(balanced, plain * gains)
    assert balanced.max() > 1  # white balance is not clipped


def test_colour_spaces_follow_colour_science(tmp_path):
    import colour

    path = write_dng(tmp_path / "a.dng", _mosaic())
    camera, meta = read_raw(path, binning=2)
    srgb, _ = read_raw(path, colour_space="srgb", binning=2)
    xyz, _ = read_raw(path, colour_space="xyz", binning=2)
    matrix = torch.tensor(meta.colour_matrix)
    torch.testing.assert_close(srgb, torch.einsum("ij,bjhw->bihw", matrix, camera))
    expected = colour.RGB_to_XYZ(srgb[0].permute(1, 2, 0).double().numpy(), "sRGB")
    np.testing.assert_allclose(xyz[0].permute(1, 2, 0).numpy(), expected, atol=1e-5)


def test_stack_and_bad_options(tmp_path):
    a = write_dng(tmp_path / "a.dng", _mosaic(seed=1))
    b = write_dng(tmp_path / "b.dng", _mosaic(seed=2))
    c = write_dng(tmp_path / "c.dng", _mosaic(32, 32))
    images, metas = read_raw_stack([a, b], binning=2)
    assert images.shape == (2, 3, 16, 24) and len(metas) == 2
    with pytest.raises(ValueError, match="c.dng'? is"):
        read_raw_stack([a, c])
    with pytest.raises(ValueError, match="at least one"):
        read_raw_stack([])
    with pytest.raises(ValueError, match="binning"):
        read_raw(a, binning=0)
    with pytest.raises(ValueError, match="colour_space"):
        read_raw(a, colour_space="adobe")
    with pytest.raises(ValueError, match="white-balanced"):
        read_raw(a, colour_space="srgb", white_balance="none")
    not_raw = tmp_path / "x.dng"
    not_raw.write_bytes(b"not a raw file at all")
    with pytest.raises(RawReadError, match="x.dng"):
        read_raw(not_raw)


def test_read_photo_reads_raw_files_upright_with_their_metadata(tmp_path):
    """`datasets.photos.read_photo` decodes a raw file (not its embedded preview) and turns it
    upright by the file's orientation."""
    from _synthetic_dng import mosaic_with_noise, texture

    from datasets.photos import read_photo

    scene = texture(96, seed=3)[..., :, :80]  # 96 x 80: not square
    mosaic = mosaic_with_noise(scene, 1)
    write_dng(tmp_path / "a.dng", mosaic, f_number=2.8)
    write_dng(tmp_path / "b.dng", mosaic, f_number=2.8, orientation=6)
    stored, info = read_photo(tmp_path / "a.dng")
    turned, turned_info = read_photo(tmp_path / "b.dng")
    assert stored.shape == (3, 96, 80) and turned.shape == (3, 80, 96)
    torch.testing.assert_close(turned, torch.rot90(stored, -1, (1, 2)))  # a quarter turn clockwise
    assert turned_info.orientation == 6 and not info.compressed
    assert info.focal_length == pytest.approx(0.025) and info.f_number == pytest.approx(2.8)
    assert info.pixel_pitch == pytest.approx(5e-6) and float(stored.max()) <= 1.0
    # linear: the texture's contrast survives (a gamma-encoded preview would compress it)
    green = stored[1].double()
    truth = scene[0, 1]
    assert float(torch.corrcoef(torch.stack([green.flatten(), truth.flatten()]))[0, 1]) > 0.9
    ratio = green / truth
    assert float(ratio.std() / ratio.mean()) < 0.1  # one gain everywhere: no tone curve


def test_predict_reads_raw_photos(tmp_path, capsys):
    """`defocus predict` on DNGs of a textured plane at 3 m, focused at 1.5 m and 6 m."""
    from _synthetic_dng import mosaic_with_noise, render_plane, synthetic_camera, texture

    from defocus.cli import main

    crop = 12
    scene = texture(96 + 2 * crop, seed=5)
    paths = [write_dng(tmp_path / "aif.dng", mosaic_with_noise(scene[..., crop:-crop, crop:-crop],
                                                               1), f_number=16.0)]
    for focus in (1.5, 6.0):
        shot = render_plane(scene, synthetic_camera(focus=focus), 3.0, crop)
        paths.append(write_dng(tmp_path / f"at{focus}.dng", mosaic_with_noise(shot, 2)))
    assert main(["predict", "--image", str(paths[0]), "--focused", *map(str, paths[1:]),
                 "--focus-distance", "1.5", "6", "--depth-range", "1", "10",
                 "--out", str(tmp_path / "out")]) == 0
    assert ("camera: focal length 25.0 mm (EXIF), f/4 (EXIF), pixel pitch 5.00 um (EXIF "
            "focal-plane resolution)") in capsys.readouterr().out
    depth = np.load(tmp_path / "out" / "depth.npy")
    assert abs(float(np.median(depth[16:-16, 16:-16])) / 3.0 - 1) < 0.05


@needs_samples
def test_read_photo_decodes_a_real_dng_not_its_preview():
    from datasets.photos import read_photo

    image, info = read_photo(SAMPLES / "canon_eos_6d.dng")
    assert image.shape == (3, 816, 1224) and image.dtype == torch.float32
    assert info.focal_length == pytest.approx(0.065) and info.f_number == pytest.approx(5.6)
    assert 0 <= float(image.min()) and float(image.max()) <= 1
    assert len(torch.unique(image[1])) > 4096  # more levels than any 8-bit preview holds
