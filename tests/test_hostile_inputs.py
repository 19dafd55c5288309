"""Hostile inputs (issue 39): nothing silently wrong, no unbounded memory, errors that name the
input as the user wrote it, and a Python API that checks its arguments at the door."""

from __future__ import annotations

import json
import math
import struct
import subprocess
import sys
import time
import zlib

import numpy as np
import pytest
import torch
from PIL import Image

from datasets.io import DataFormatError, read_npy
from datasets.photos import check_photo_content, read_photo
from datasets.photos.metadata import PhotoMetadata
from datasets.photos.settings import resolve_settings
from defocus.cli import main
from models import estimate_depth
from optics import CameraSettings, parse_aperture

SETTINGS = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
CAMERA = ["--focal-length", "0.05", "--pixel-pitch", "2e-5"]


def _png_claiming(path, width, height):
    """A PNG of a few bytes whose header claims `width` x `height` RGB pixels."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(
            ">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(bytes.fromhex("89504e470d0a1a0a") + chunk(b"IHDR", ihdr)
                     + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))
    return path


def _photos(folder, arrays):
    paths = []
    for index, array in enumerate(arrays):
        paths.append(folder / f"shot{index}.png")
        Image.fromarray(array).save(paths[-1])
    return [str(p) for p in paths]


def _texture(seed=0, size=(40, 48)):
    return (np.random.default_rng(seed).random((*size, 3)) * 255).astype(np.uint8)


def _predict(photos, out, *extra, focus=("1", "3")):
    return ["predict", "--focused", *photos, "--focus-distance", *focus, *CAMERA,
            "--out", str(out), *extra]


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "unexpected" not in err, err
    return err


# ---- unbounded memory ----------------------------------------------------------------------
@pytest.mark.parametrize("side", [100_000, 12_000])  # beyond Pillow's own limit, and ours
def test_a_huge_png_header_is_refused_before_decoding(tmp_path, side):
    path = _png_claiming(tmp_path / "huge.png", side, side)
    started = time.perf_counter()
    with pytest.raises(DataFormatError, match="megapixels"):
        read_photo(path)
    assert time.perf_counter() - started < 5


def test_a_huge_png_header_stays_far_below_3_gb(tmp_path):
    path = _png_claiming(tmp_path / "huge.png", 100_000, 100_000)
    code = ("import resource, sys\n"
            "from datasets.photos import read_photo\n"
            "try:\n    read_photo(sys.argv[1])\nexcept ValueError as e:\n    print('refused')\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n")
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                          text=True, timeout=300, check=True)
    refused, peak_kib = done.stdout.split()
    assert refused == "refused" and int(peak_kib) < 3 * 1024 * 1024


@pytest.mark.parametrize("dtype, message", [("float32", "holds float32 samples"),
                                            ("uint16", "states 12000x12000 pixels")])
def test_a_huge_tiff_is_refused_from_its_header(tmp_path, dtype, message):
    """Pillow reads no floating-point TIFF header: tifffile's is read instead, before 144
    megapixels are decoded (the files hold no pixel data: sparse)."""
    import tifffile

    path = tmp_path / "huge.tif"
    tifffile.imwrite(path, shape=(3, 12000, 12000), dtype=dtype, photometric="rgb",
                     planarconfig="separate")
    started = time.perf_counter()
    with pytest.raises(DataFormatError, match=message):
        read_photo(path)
    assert time.perf_counter() - started < 2


def test_a_raw_file_over_the_pixel_limit_is_refused_before_decoding(tmp_path, monkeypatch):
    """LibRaw's sizes are read before anything is unpacked: a raw file stating more than
    MAX_IMAGE_PIXELS photosites is refused, its pixels never decoded."""
    import rawpy
    from _synthetic_dng import write_dng

    from datasets.photos.raw import RawReadError, read_raw

    path = write_dng(tmp_path / "small.dng", np.full((32, 48), 2000, np.uint16))
    with pytest.raises(RawReadError, match="states 32x48 photosites .*at most 0.001 megapixels"):
        read_raw(path, max_pixels=1000)  # the real file's own sizes, through LibRaw

    class HugeRaw:  # what LibRaw states of a 20000x20000 sensor, without its pixels
        sizes = type("Sizes", (), {"raw_height": 20_000, "raw_width": 20_000, "height": 20_000,
                                   "width": 20_000})()

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def __getattr__(self, name):  # raw_image_visible, postprocess, ...: never reached
            raise AssertionError(f"{name} read before the size was checked")

    monkeypatch.setattr(rawpy, "imread", lambda *args, **kwargs: HugeRaw())
    with pytest.raises(DataFormatError, match="20000x20000 photosites .*at most 100 megapixels"):
        read_photo(path)


def test_a_16_bit_photo_is_read_without_full_size_temporaries(tmp_path):
    """Reading holds the float32 photo and its decoded samples, no float copies (a 100-megapixel
    16-bit photo, the limit, took 5.2 GB, now 2.2 GB), and checking it is finite holds nothing
    of its size: measured on a 16-megapixel one in a fresh process."""
    import tifffile

    path = tmp_path / "photo.tif"
    rng = np.random.default_rng(0)
    tifffile.imwrite(path, rng.integers(0, 65535, (4000, 4000, 3), dtype=np.uint16),
                     photometric="rgb")
    code = ("import resource, sys, torch\n"
            "from datasets.photos import read_photo\n"
            "from optics.checks import check_finite\n"
            "peak = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
            "before = peak()\n"
            "photo, _ = read_photo(sys.argv[1])\n"
            "read = peak()\n"
            "check_finite('photo', photo[None].expand(2, -1, -1, -1))\n"
            "print(before, read, peak(), photo.numel() * photo.element_size() // 1024)\n")
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                          text=True, timeout=300, check=True)
    before, read, checked, photo_kib = map(int, done.stdout.split())
    # the photo (1) and its 16-bit samples (0.5), with room for the allocator (before: 4.3)
    assert read - before < 3 * photo_kib
    assert checked - read < 0.1 * photo_kib  # before: 0.25


def test_an_npy_header_claiming_1e10_values_is_refused_before_loading(tmp_path):
    path = tmp_path / "depth.npy"
    with open(path, "wb") as file:
        np.lib.format.write_array_header_1_0(
            file, {"descr": "<f4", "fortran_order": False, "shape": (100_000, 100_000)})
    with pytest.raises(DataFormatError, match="1e\\+10 values"):
        read_npy(path, "a depth map")


@pytest.mark.parametrize("spec", ["polygon:100000000", "gaussian:1e6", "polygon:65"])
def test_absurd_psf_parameters_are_refused(spec, capsys):
    with pytest.raises(ValueError, match="n_blades must be an integer from 3 to|scale must be"):
        parse_aperture(spec)
    with pytest.raises(SystemExit):
        main(["render", "--aperture", spec])
    assert "aperture spec" in capsys.readouterr().err


# ---- silently wrong output -----------------------------------------------------------------
def test_per_shot_camera_values_are_honoured_not_truncated(tmp_path):
    fitted = CameraSettings(0.05, [8.3, 2.0], [1.0, 3.0], 2e-5)
    photos = [PhotoMetadata("a.png", {}), PhotoMetadata("b.png", {})]
    settings, _ = resolve_settings(photos, {}, fitted)
    assert settings.f_number.tolist() == [8.3, 2.0]
    with pytest.raises(ValueError, match="2 different f_number values"):
        resolve_settings(photos + [PhotoMetadata("c.png", {})], {"focus_distance": [1, 2, 3]},
                         fitted)


def test_per_shot_camera_values_of_another_count_name_the_file(tmp_path, capsys):
    camera = tmp_path / "cam.json"
    CameraSettings(0.05, [8.3, 2.0], [1.0, 3.0], 2e-5).to_json(camera)
    photos = _photos(tmp_path, [_texture(i) for i in range(3)])
    argv = ["predict", "--focused", *photos, "--focus-distance", "1", "2", "3", "--camera",
            str(camera), "--depth-range", "0.5", "5", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert f'{camera}: "f_number" holds 2 different values' in _one_line(capsys)


def test_dataset_camera_json_per_shot_values_are_honoured_or_named(tmp_path):
    """The loaders' door: a DSLR scene has one focused photo, so a camera JSON with two
    different f-numbers is refused naming the file and key (not cut to the first, nor a shape
    error at the first sample); one value repeated is that value."""
    from test_datasets_fixtures import write_dslr_release

    from datasets import DSLR

    write_dslr_release(tmp_path / "data")
    camera = tmp_path / "cam.json"
    CameraSettings(0.035, [2.8, 2.0], [1.9], 6e-5).to_json(camera)
    with pytest.raises(DataFormatError, match=f'{camera}: "f_number" holds 2 different values '
                                              r"\[2.8, 2.0\], one per shot, but a DSLR scene"):
        DSLR(tmp_path / "data", camera=camera)
    with pytest.raises(DataFormatError, match='camera: "f_number" holds 2 different values'):
        DSLR(tmp_path / "data", camera=CameraSettings(0.035, [2.8, 2.0], [1.9], 6e-5))
    CameraSettings(0.035, [2.8, 2.8], [1.9], 6e-5).to_json(camera)
    assert DSLR(tmp_path / "data", camera=camera)[0]["camera"].f_number.tolist() == \
        pytest.approx([2.8])


def test_photo_folder_camera_per_shot_values_are_honoured_or_named(tmp_path):
    from datasets import PhotoFolder

    scene = tmp_path / "root" / "scene"
    scene.mkdir(parents=True)
    for index, name in enumerate(("aif", "near", "far")):
        Image.fromarray(_texture(index, (16, 16))).save(scene / f"{name}.png")
    data = {**CameraSettings(0.05, [8.3, 2.0], [1.0, 3.0], 2e-5).to_dict(),
            "photos": ["near.png", "far.png"]}
    (scene / "camera.json").write_text(json.dumps(data))
    assert PhotoFolder(scene.parent)[0]["camera"].f_number.tolist() == pytest.approx([8.3, 2.0])
    data["f_number"] = [8.3, 2.0, 4.0]
    (scene / "camera.json").write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=f'{scene / "camera.json"}: "f_number" holds 3 '
                                              'different values .* "photos" names 2 focused'):
        PhotoFolder(scene.parent)


def test_the_same_photo_twice_is_refused(tmp_path, capsys):
    photos = _photos(tmp_path, [_texture()])
    assert main(_predict(photos * 2, tmp_path / "o", "--f-number", "2", "--depth-range", "0.5",
                         "5")) == 2
    assert "is the same photo as" in _one_line(capsys)
    assert not (tmp_path / "o").exists()


def test_photos_of_another_size_are_refused_by_name(tmp_path, capsys):
    """The focused photos are decoded straight into their stack: a photo of another size is
    refused naming it and the first, whether that is --image or the first --focused photo."""
    small, large = _texture(0, (40, 48)), _texture(1, (40, 50))
    photos = _photos(tmp_path, [small, large])
    argv = _predict(photos, tmp_path / "o", "--f-number", "2", "--depth-range", "0.5", "5")
    assert main(argv) == 2
    assert f"{photos[1]} is (40, 50) pixels but {photos[0]} is (40, 48)" in _one_line(capsys)
    (tmp_path / "aif").mkdir()
    assert main([*argv, "--image", _photos(tmp_path / "aif", [_texture(2, (30, 48))])[0]]) == 2
    assert "is (40, 48) pixels but" in _one_line(capsys)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("value", [0, 255])
def test_black_or_saturated_shots_are_refused(tmp_path, capsys, value):
    flat = np.full((40, 48, 3), value, np.uint8)
    photos = _photos(tmp_path, [_texture(), flat])
    assert main(_predict(photos, tmp_path / "o", "--f-number", "2", "--depth-range", "0.5",
                         "5")) == 2
    assert "no texture for defocus" in _one_line(capsys)


def test_a_mostly_clipped_photo_is_refused():
    photo = torch.ones(3, 100, 100)
    photo[:, 0, 0] = 0.5
    with pytest.raises(ValueError, match="black or saturated"):
        check_photo_content(photo, "x.png")
    check_photo_content(torch.rand(3, 16, 16))  # texture: fine


def test_calibrate_dataset_refuses_options_it_ignores(tmp_path, capsys):
    argv = ["calibrate", "--data", "dslr", "--root", str(tmp_path), "--focal-length", "0.05",
            "--f-number", "2"]
    assert main(argv) == 2
    err = _one_line(capsys)
    assert "--focal-length, --f-number do(es) nothing with --data" in err
    assert main(["calibrate", "--pair", "a.dng", "b.dng", "2", "--scenes", "0:3"]) == 2
    assert "--scenes do(es) nothing with --pair" in _one_line(capsys)


def test_a_depth_range_inside_the_focal_length_is_refused(tmp_path, capsys):
    photos = _photos(tmp_path, [_texture(0), _texture(1)])
    assert main(_predict(photos, tmp_path / "o", "--f-number", "2", "--depth-range", "0.01",
                         "5")) == 2
    assert "--depth-range must lie beyond the focal length (0.05 m)" in _one_line(capsys)
    with pytest.raises(ValueError, match="beyond the focal length"):
        estimate_depth(torch.rand(2, 3, 16, 16), SETTINGS, (0.03, 10.0))


# ---- errors that name the input ------------------------------------------------------------
@pytest.mark.parametrize("key, value, shown", [("f_number", math.nan, "NaN"),
                                               ("f_number", [math.nan, math.nan], "[NaN, NaN]"),
                                               ("pixel_pitch", -1, "-1"),
                                               ("focal_length", "50mm", '"50mm"')])
def test_bad_camera_json_values_name_the_file_and_key(tmp_path, capsys, key, value, shown):
    camera = tmp_path / "cam.json"
    data = CameraSettings(0.05, 2.0, [1.0, 3.0], 2e-5).to_dict()
    data[key] = value
    camera.write_text(json.dumps(data))
    photos = _photos(tmp_path, [_texture(0), _texture(1)])
    argv = ["predict", "--focused", *photos, "--camera", str(camera), "--depth-range", "0.5",
            "5", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = _one_line(capsys)
    assert f'{camera}: "{key}" must be a finite number > 0' in err and f"got {shown}" in err
    assert "tensor(" not in err


@pytest.mark.parametrize("option, value", [("--image-f-number", "nan"),
                                           ("--image-f-number", "0"),
                                           ("--image-focus-distance", "-1")])
def test_image_shot_options_are_named(tmp_path, capsys, option, value):
    photos = _photos(tmp_path, [_texture(0), _texture(1), _texture(2)])
    given = [] if option == "--image-f-number" else ["--image-f-number", "8"]
    argv = ["predict", "--image", photos[0], "--focused", *photos[1:], *given,
            option, value, "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = _one_line(capsys)
    assert f"{option} {value}: must be a finite number > 0" in err, err


@pytest.mark.parametrize("size", [(1, 1), (4, 4), (1, 64)])
def test_tiny_photos_are_one_line(tmp_path, capsys, size):
    photos = _photos(tmp_path, [_texture(0, size), _texture(1, size)])
    assert main(_predict(photos, tmp_path / "o", "--f-number", "2", "--depth-range", "0.5",
                         "5")) == 2
    assert "pixels on each side" in _one_line(capsys)


@pytest.mark.parametrize("option, value", [("--f-number", "1e-9"), ("--pixel-pitch", "1e-15")])
def test_tiny_f_numbers_and_pixel_pitches_are_one_line(tmp_path, capsys, option, value):
    photos = _photos(tmp_path, [_texture(0), _texture(1)])
    camera = {"--focal-length": "0.05", "--pixel-pitch": "2e-5", "--f-number": "2", option: value}
    argv = ["predict", "--focused", *photos, "--focus-distance", "1", "3", "--out",
            str(tmp_path / "o"), "--depth-range", "0.5", "5", *sum(camera.items(), ())]
    assert main(argv) == 2
    assert "check the f-number, the pixel pitch" in _one_line(capsys)


@pytest.mark.parametrize("device", ["meta", "xpu", "gpu", "cuda:99"])
def test_unknown_devices_are_one_line(tmp_path, capsys, device):
    photos = _photos(tmp_path, [_texture(0), _texture(1)])
    assert main(_predict(photos, tmp_path / "o", "--device", device)) == 2
    assert "--device" in _one_line(capsys)


def test_non_utf8_dataset_files_name_the_file(tmp_path):
    from datasets.io import read_text

    path = tmp_path / "split.txt"
    path.write_bytes(b"scene_\xff\xfe\n")
    with pytest.raises(DataFormatError, match=r"split\.txt'.*UTF-8.*0xff"):
        read_text(path, "a split file")


# ---- the Python API ------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_estimate_depth_computes_half_precision_photos_in_float32(dtype):
    torch.manual_seed(0)
    focused, image = torch.rand(2, 3, 24, 24), torch.rand(3, 24, 24)
    out = estimate_depth(focused.to(dtype), SETTINGS, (1.0, 10.0), image=image.to(dtype))
    assert out["depth"].dtype == torch.float32 and bool(torch.isfinite(out["depth"]).all())
    reference = estimate_depth(focused.to(dtype).float(), SETTINGS, (1.0, 10.0),
                               image=image.to(dtype).float())
    torch.testing.assert_close(out["depth"], reference["depth"])


def test_estimate_depth_refuses_integer_photos_in_one_line():
    with pytest.raises(TypeError, match=r"focused must hold floating-point .* torch\.uint8"):
        estimate_depth(torch.zeros(2, 3, 16, 16, dtype=torch.uint8), SETTINGS, (1.0, 10.0))
    with pytest.raises(TypeError, match=r"image must hold floating-point .* torch\.int64"):
        estimate_depth(torch.rand(2, 3, 16, 16), SETTINGS, (1.0, 10.0),
                       image=torch.zeros(3, 16, 16, dtype=torch.long))


@pytest.mark.parametrize("depth_range", [None, (1.0,), (1.0, 2.0, 3.0), "1-10", (1.0, "far")])
def test_estimate_depth_refuses_a_depth_range_that_is_not_two_numbers(depth_range):
    with pytest.raises(TypeError, match="depth_range must be two numbers"):
        estimate_depth(torch.rand(2, 3, 16, 16), SETTINGS, depth_range)


@pytest.mark.parametrize("depth_range", [(10.0, 1.0), (-1.0, 5.0), (1.0, math.inf)])
def test_estimate_depth_refuses_a_range_that_is_not_increasing_and_positive(depth_range):
    with pytest.raises(ValueError, match="0 < near < far"):
        estimate_depth(torch.rand(2, 3, 16, 16), SETTINGS, depth_range)


def test_estimate_depth_refuses_settings_that_are_not_camera_settings():
    with pytest.raises(TypeError, match="settings must be an optics.CameraSettings, got list"):
        estimate_depth(torch.rand(2, 3, 16, 16), [0.05, 2.0, [2.0, 6.0], 1e-4], (1.0, 10.0))
    with pytest.raises(TypeError, match="focused must be a torch.Tensor, got ndarray"):
        estimate_depth(np.zeros((2, 3, 16, 16)), SETTINGS, (1.0, 10.0))


def test_estimate_depth_refuses_the_settings_of_several_scenes():
    batch = CameraSettings(0.05, 2.0, [[2.0, 6.0], [3.0, 5.0]], 1e-4)
    with pytest.raises(ValueError, match=r"settings must be one scene's .* shape \(2, 2\)"):
        estimate_depth(torch.rand(2, 3, 16, 16), batch, (1.0, 10.0))
    photos = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    one = estimate_depth(photos, batch[:1], (1.0, 10.0))["depth"]
    assert torch.equal(one, estimate_depth(photos, batch[0], (1.0, 10.0))["depth"])


def test_estimate_depth_refuses_photos_that_are_not_linear_intensity():
    with pytest.raises(ValueError, match=r"focused must hold linear intensity in \[0, 1\], got "
                                         r"values from .* to 25\d.*divide by 255"):
        estimate_depth(torch.rand(2, 3, 16, 16) * 255, SETTINGS, (1.0, 10.0))
    with pytest.raises(ValueError, match=r"image must hold linear intensity .* from -0.9"):
        estimate_depth(torch.rand(2, 3, 16, 16), SETTINGS, (1.0, 10.0),
                       image=torch.rand(3, 16, 16) * 2 - 1)


def test_estimate_depth_with_an_all_in_focus_photo_refuses_blur_that_reads_no_depth():
    """A pixel pitch given in micrometres as metres leaves every blur under a pixel: the sweep
    would return one flat depth at the far end, rated confident."""
    photos = torch.rand(2, 3, 16, 16)
    wrong_pitch = CameraSettings(0.05, 1.8, [2.3, 4.6], 324.0)
    with pytest.raises(ValueError, match="changes by at most 0.00 pixels .* pixel pitch"):
        estimate_depth(photos, wrong_pitch, (1.5, 8.0), image=torch.rand(3, 16, 16))


def test_photos_in_another_order_than_the_camera_json_lists_are_refused(tmp_path, capsys):
    camera = tmp_path / "cam.json"
    photos = _photos(tmp_path, [_texture(0), _texture(1)])
    CameraSettings(0.05, 2.0, [1.0, 3.0], 2e-5).to_json(camera, photos=["shot0.png", "shot1.png"])
    argv = ["predict", "--focused", *photos[::-1], "--camera", str(camera), "--depth-range",
            "0.5", "5", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert "--focused gives shot1.png, shot0.png but" in _one_line(capsys)


@pytest.mark.parametrize("reference", ["eight", -3, 0.5, True])
def test_a_bad_reference_f_number_names_the_file_and_key(tmp_path, capsys, reference):
    camera = tmp_path / "cam.json"
    CameraSettings(0.05, 2.0, [1.0, 3.0], 2e-5).to_json(camera, reference_f_number=reference)
    photos = _photos(tmp_path, [_texture(0), _texture(1), _texture(2)])
    argv = ["predict", "--image", photos[0], "--focused", *photos[1:], "--camera", str(camera),
            "--depth-range", "0.5", "5", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert f'{camera}: "reference_f_number" must be an f-number >= 1, got {reference!r}' \
        in _one_line(capsys)


def test_estimate_depth_refuses_a_far_end_beyond_any_blur():
    with pytest.raises(ValueError, match="far end must be at most 1e\\+06 metres"):
        estimate_depth(torch.rand(2, 3, 16, 16), SETTINGS, (1.5, 1e39))


def test_a_folder_where_a_file_is_expected_is_named_as_such(tmp_path, capsys):
    photos = _photos(tmp_path, [_texture(0), _texture(1)])
    folder = tmp_path / "folder"
    folder.mkdir()
    assert main(["predict", "--image", str(folder), "--focused", *photos, "--out",
                 str(tmp_path / "o")]) == 2
    assert f"'{folder}' is a folder: expected" in _one_line(capsys)
    assert main(["predict", "--focused", *photos, "--camera", str(folder), "--depth-range", "1",
                 "5", "--out", str(tmp_path / "o")]) == 2
    assert f"'{folder}' is a folder: expected a camera JSON, a file" in _one_line(capsys)
