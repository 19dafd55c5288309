"""Issue 11, case 13: datasets check the dtypes and ranges of what they read."""

from __future__ import annotations

import re

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from test_datasets_fixtures import (
    KITTI_DRIVE,
    write_dslr,
    write_kitti,
    write_middlebury,
    write_nyu_arrays,
)

from datasets import DSLR, KITTI, DataFormatError, Middlebury, NYUv2
from datasets.depth import densify_nearest, fill_unknown
from datasets.middlebury import read_calib
from datasets.photos import read_photo, read_raw


def names(path) -> str:
    return re.escape(repr(str(path)))


@pytest.fixture
def rng():
    return np.random.default_rng(0)


def test_case13_nyu_uint16_millimetres_read_as_metres_with_warning(tmp_path, rng):
    images = rng.integers(0, 256, size=(2, 6, 8, 3), dtype=np.uint8)
    depths_mm = rng.integers(1001, 5998, size=(2, 6, 8)).astype(np.uint16)
    write_nyu_arrays(tmp_path, images, depths_mm)
    with pytest.warns(UserWarning, match="stored as uint16.*millimetres"):
        dataset = NYUv2(tmp_path, split="all", size=(6, 8))
    sample = dataset.load(0)
    expected = torch.from_numpy(depths_mm[0].astype(np.float64) / 1000).float()
    assert torch.allclose(sample["depth"][0], expected)
    assert 1.0 < float(sample["depth"].min()) and float(sample["depth"].max()) < 6.0


def test_case13_nyu_float_images_in_unit_range_not_divided_by_255(tmp_path, rng):
    uint8 = rng.integers(0, 256, size=(1, 6, 8, 3), dtype=np.uint8)
    depths = rng.uniform(1, 9, size=(1, 6, 8))
    write_nyu_arrays(tmp_path / "u8", uint8, depths)
    write_nyu_arrays(tmp_path / "f", (uint8 / 255.0).astype(np.float32), depths)
    reference = NYUv2(tmp_path / "u8", split="all").load(0)["image"]
    from_float = NYUv2(tmp_path / "f", split="all").load(0)["image"]
    assert float(from_float.max()) > 0.5  # was <= 1/255 before
    assert torch.allclose(from_float, reference, atol=1e-6)


def test_case13_nyu_float_images_outside_unit_range_refused(tmp_path, rng):
    images = rng.uniform(0, 255, size=(1, 6, 8, 3)).astype(np.float32)
    path = write_nyu_arrays(tmp_path, images, rng.uniform(1, 9, size=(1, 6, 8)))
    with pytest.raises(DataFormatError, match=names(path) + ".*frame 1 of images.*in \\[0, 1\\]"):
        NYUv2(tmp_path, split="all").load(0)


def test_case13_nyu_float_millimetre_depths_refused(tmp_path, rng):
    images = rng.integers(0, 256, size=(1, 6, 8, 3), dtype=np.uint8)
    path = write_nyu_arrays(tmp_path, images, rng.uniform(1000, 6000, size=(1, 6, 8)))
    with pytest.raises(DataFormatError, match=names(path) + " frame 1.*millimetres"):
        NYUv2(tmp_path, split="all").load(0)


def test_case13_nyu_frame_without_valid_depth_refused(tmp_path, rng):
    images = rng.integers(0, 256, size=(2, 6, 8, 3), dtype=np.uint8)
    depths = rng.uniform(1, 9, size=(2, 6, 8))
    depths[1] = 0.0  # no measurement at all
    path = write_nyu_arrays(tmp_path, images, depths)
    dataset = NYUv2(tmp_path, split="all", size=(6, 8))
    assert dataset[0]["focused"].shape[0] == 2
    with pytest.raises(DataFormatError, match=names(path) + " frame 2: no valid depth pixel"):
        dataset[1]  # used to be filled with an invented 1 m and rendered


def test_case13_read_raw_refuses_integer_dtypes(tmp_path):
    for dtype in (torch.int32, torch.uint8, torch.bool):
        with pytest.raises(TypeError, match="dtype must be a floating-point.*truncate"):
            read_raw(tmp_path / "x.dng", dtype=dtype)


def test_float_photo_refused_naming_the_file(tmp_path):
    """The one photo decoder of the loaders (`read_photo`) refuses floating-point samples,
    0-255 stored as float or not: they state no scale of light."""
    path = tmp_path / "photo.tiff"
    for value in (200.0, 0.25):
        iio.imwrite(path, np.full((4, 5, 3), value, dtype=np.float32))
        with pytest.raises(DataFormatError, match=names(path) + ".*float32 samples"):
            read_photo(path)


def test_kitti_frame_without_lidar_points_refused(tmp_path):
    write_kitti(tmp_path)
    depth_path = (tmp_path / KITTI_DRIVE / "proj_depth" / "groundtruth" / "image_02" /
                  "0000000005.png")
    iio.imwrite(depth_path, np.zeros((10, 24), dtype=np.uint16))
    for densify in ("nearest", "none"):
        dataset = KITTI(tmp_path, split="train", densify=densify)
        with pytest.raises(DataFormatError, match=names(depth_path) + ": no valid depth"):
            dataset.load(0)


def test_dslr_frame_without_depth_refused(tmp_path):
    write_dslr(tmp_path)
    depth_path = tmp_path / "train" / "depth" / "scene00.png"
    iio.imwrite(depth_path, np.zeros((12, 16), dtype=np.uint16))
    with pytest.raises(DataFormatError, match=names(depth_path) + ": no valid depth"):
        DSLR(tmp_path).load(0)


def test_middlebury_all_unknown_disparity_refused(tmp_path):
    from datasets.io import write_pfm

    write_middlebury(tmp_path)
    disp = tmp_path / "Motorcycle-perfect" / "disp0.pfm"
    write_pfm(disp, np.full((12, 18), np.inf, dtype=np.float32))
    with pytest.raises(DataFormatError, match=names(disp) + ": no valid depth"):
        Middlebury(tmp_path).load(0)


@pytest.mark.parametrize("text, message", [
    ("cam0=[0 0 8.5; 0 0 6.0; 0 0 1]\ndoffs=4\nbaseline=193\n", "cam0 focal length must be"),
    ("cam0=[120 0 8.5; 0 120 6.0; 0 0 1]\ndoffs=4\nbaseline=nan\n", "baseline must be finite"),
    ("cam0=[120 0 8.5; 0 120 6.0; 0 0 1]\ndoffs=4\nbaseline=-5\n", "baseline must be finite"),
    ("cam0=[120 0 8.5; 0 120 6.0; 0 0 1]\ndoffs=inf\nbaseline=193\n", "doffs must be a finite"),
    ("cam0=[120 0 8.5]\ndoffs=4\nbaseline=193\n", "9 entries"),
    ("cam0=[120 0 8.5; 0 120 6.0; 0 0 1]\nbaseline=193\n", "could not read 'doffs'"),
])
def test_bad_calib_txt_named(tmp_path, text, message):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(DataFormatError, match=names(path) + ".*" + re.escape(message)):
        read_calib(path)


def test_bad_calib_txt_binary_named(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_bytes(b"\xff\xfe\x00\x01garbage")
    with pytest.raises(DataFormatError, match=names(path) + ": expected a Middlebury calib.txt in "
                                                        "UTF-8 text, but byte 1 is 0xff"):
        read_calib(path)


def test_fill_helpers_refuse_empty_masks():
    depth, empty = torch.zeros(1, 2, 2), torch.zeros(1, 2, 2, dtype=torch.bool)
    with pytest.raises(ValueError, match="no valid depth pixel"):
        fill_unknown(depth, empty)
    assert float(fill_unknown(depth, empty, 80.0).min()) == 80.0
    with pytest.raises(ValueError, match="no valid depth pixel"):
        densify_nearest(depth, empty)
