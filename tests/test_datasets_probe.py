"""Dataset files as a user's own copy may hold them: damaged, inconsistent or in another unit.

Each case was read silently wrong (or failed obscurely) before; each must now be refused with a
message naming the file, the value and what is allowed, or read correctly.
"""

from __future__ import annotations

import re
import warnings

import imageio.v3 as iio
import numpy as np
import pytest
import scipy.io
from test_datasets_fixtures import (
    KITTI_DRIVE,
    write_kitti,
    write_lightfield,
    write_make3d,
    write_middlebury,
    write_nyu,
)

from datasets.io import DataFormatError, read_list, read_pfm
from datasets.kitti import KITTI
from datasets.lightfield import LightField
from datasets.make3d import Make3D
from datasets.middlebury import Middlebury, read_calib
from datasets.nyu import NYUv2
from datasets.photo_folder import PhotoFolder

SCENE = "Motorcycle-perfect"


def names(path) -> str:
    return re.escape(repr(str(path)))


def _pfm(path, header: bytes, array: np.ndarray) -> None:
    path.write_bytes(header + np.flipud(array).astype("<f4").tobytes())


# --- PFM ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("header, message", [
    (b"Pf\n-4 3\n-1.0\n", "width and height must be > 0"),
    (b"Pf\n4 0\n-1.0\n", "width and height must be > 0"),
    (b"Pf\n4 3\n0\n", "scale a finite non-zero"),
    (b"Pf\n4 3\nnan\n", "scale a finite non-zero"),
])
def test_pfm_header_with_impossible_values_is_refused(tmp_path, header, message):
    path = tmp_path / "disp0.pfm"
    _pfm(path, header, np.ones((3, 4), np.float32))
    with pytest.raises(DataFormatError, match=names(path) + ".*" + message):
        read_pfm(path)


def test_pfm_with_more_data_than_its_header_is_refused(tmp_path):
    path = tmp_path / "disp0.pfm"  # a 3-channel raster under a 1-channel 'Pf' header
    _pfm(path, b"Pf\n4 3\n-1.0\n", np.ones((3, 4, 3), np.float32))
    with pytest.raises(DataFormatError, match=names(path) + ": PFM with more data than stated"):
        read_pfm(path)


def test_pfm_big_endian_and_a_trailing_newline_are_read(tmp_path):
    array = np.arange(12, dtype=np.float32).reshape(3, 4)
    path = tmp_path / "disp0.pfm"
    path.write_bytes(b"Pf\n4 3\n1.0\n" + np.flipud(array).astype(">f4").tobytes() + b"\n")
    np.testing.assert_array_equal(read_pfm(path), array)


# --- list files --------------------------------------------------------------------------------

def test_list_with_a_byte_order_mark_reads_its_first_name(tmp_path):
    path = tmp_path / "test.txt"
    path.write_bytes("\ufeffscene_a\r\nscene_b\r\n".encode())
    assert read_list(path) == ["scene_a", "scene_b"]


def test_middlebury_split_naming_a_scene_twice_or_nothing_is_refused(tmp_path):
    write_middlebury(tmp_path)
    (tmp_path / "test.txt").write_text(f"{SCENE}\n\n{SCENE}\n")
    with pytest.raises(DataFormatError, match=names(tmp_path / "test.txt") + ".*lines 1 and 3"):
        Middlebury(tmp_path, split="test")
    (tmp_path / "empty.txt").write_text("\n \n")
    with pytest.raises(DataFormatError, match=names(tmp_path / "empty.txt") + ".*names nothing"):
        Middlebury(tmp_path, split="empty")


def test_middlebury_split_naming_a_missing_scene_says_so(tmp_path):
    write_middlebury(tmp_path)
    (tmp_path / "test.txt").write_text("Nope\n")
    with pytest.raises(FileNotFoundError, match=r"no scene folder .*Nope.*listed in test.txt"):
        Middlebury(tmp_path, split="test")


def test_lightfield_split_naming_a_mosaic_twice_is_refused(tmp_path):
    write_lightfield(tmp_path, n=1, n_views=2, h=2, w=2)
    (tmp_path / "test.txt").write_text("IMG_0000_eslf.png\nIMG_0000_eslf.png\n")
    with pytest.raises(DataFormatError, match="listed twice"):
        LightField(tmp_path, split="test", n_views=2, views=2)


def test_kitti_split_naming_a_frame_twice_is_refused(tmp_path):
    write_kitti(tmp_path)
    path = tmp_path / "eigen_dup_files.txt"  # the same frame in both line formats
    path.write_text(f"{KITTI_DRIVE} 5 l\n{KITTI_DRIVE}/image_02/data/0000000005.png\n")
    with pytest.raises(DataFormatError, match=names(path) + " lines 1 and 2 both name frame"):
        KITTI(tmp_path, split="dup")


def test_photo_folder_split_without_its_list_is_refused_not_every_scene(tmp_path):
    (tmp_path / "scene_a").mkdir()
    with pytest.raises(FileNotFoundError, match=r"no test.txt listing the scenes of split 'test'"):
        PhotoFolder(tmp_path, split="test")
    (tmp_path / "test.txt").write_text("scene_b\n")
    with pytest.raises(FileNotFoundError, match=r"names scene folders \['scene_b'\]"):
        PhotoFolder(tmp_path, split="test")


# --- Middlebury calib.txt ----------------------------------------------------------------------

def test_middlebury_baseline_in_metres_is_refused(tmp_path):
    write_middlebury(tmp_path)
    calib = tmp_path / SCENE / "calib.txt"
    calib.write_text(calib.read_text().replace("baseline=193.001", "baseline=0.193001"))
    with pytest.raises(DataFormatError, match=names(calib) + ".*> 1 mm, got 0.193001.*metres"):
        read_calib(calib)


def test_middlebury_calib_key_given_twice_differently_is_refused(tmp_path):
    write_middlebury(tmp_path)
    calib = tmp_path / SCENE / "calib.txt"
    calib.write_text(calib.read_text() + "doffs=9\n")
    with pytest.raises(DataFormatError, match=names(calib) + ": doffs is given twice.*'4.25'.*'9'"):
        read_calib(calib)


def test_middlebury_calib_of_another_resolution_is_refused(tmp_path):
    write_middlebury(tmp_path, h=12, w=18)  # e.g. images downscaled, full-size calib.txt kept
    calib = tmp_path / SCENE / "calib.txt"
    calib.write_text(calib.read_text().replace("width=18", "width=36"))
    with pytest.raises(DataFormatError, match=names(calib) + ": states width=36 .* 12x18"):
        Middlebury(tmp_path)[0]


# --- depth units -------------------------------------------------------------------------------

@pytest.mark.parametrize("stored", [20, 65535])  # metres without * 256; saturated
def test_kitti_depth_png_in_another_unit_is_refused(tmp_path, stored):
    write_kitti(tmp_path, frames=(5, 6))
    path = tmp_path / KITTI_DRIVE / "proj_depth" / "groundtruth" / "image_02" / "0000000005.png"
    depth = np.zeros((10, 24), np.uint16)
    depth[::2] = stored
    iio.imwrite(path, depth)
    with pytest.raises(DataFormatError, match=names(path) + ": its LiDAR depths have median"):
        KITTI(tmp_path)[0]


# --- NYU splits.mat ----------------------------------------------------------------------------

@pytest.mark.parametrize("train, message", [
    (np.array([[1.5], [3.0]]), "whole 1-based indices, got \\[1.5\\]"),
    (np.array([[1], [3], [1]]), "lists frame\\(s\\) \\[1\\] more than once"),
    (np.zeros((0, 1)), "trainNdxs is empty"),
])
def test_nyu_split_indices_that_are_not_a_set_of_frames_are_refused(tmp_path, train, message):
    write_nyu(tmp_path)
    scipy.io.savemat(tmp_path / "splits.mat", {"trainNdxs": train, "testNdxs": np.array([[2]])})
    with pytest.raises(DataFormatError, match=names(tmp_path / "splits.mat") + ".*" + message):
        NYUv2(tmp_path, "train")


# --- Make3D pairing ----------------------------------------------------------------------------

def test_make3d_depth_file_without_its_photo_is_refused(tmp_path):
    write_make3d(tmp_path)
    scipy.io.savemat(tmp_path / "Train400Depth" / "depth_sph_corr-orphan.mat",
                     {"Position3DGrid": np.ones((8, 6, 4))})
    with pytest.raises(FileNotFoundError, match=r"1 depth file\(s\) .*depth_sph_corr-orphan.mat"):
        Make3D(tmp_path)


def test_make3d_photo_with_upper_case_suffix_is_kept(tmp_path):
    written = write_make3d(tmp_path)
    first = sorted((tmp_path / "Train400Img").glob("*.jpg"))[0]
    first.rename(first.with_suffix(".JPG"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dataset = Make3D(tmp_path, size=(24, 18))
    assert dataset.ids == sorted(name for name in written if "train" in name)
    assert dataset[0]["image"].shape == (3, 24, 18)


def test_lightfield_all_reads_mosaics_of_any_suffix_case(tmp_path):
    """`split="all"` looked for `*.png` only and dropped `.PNG` mosaics without a word."""
    write_lightfield(tmp_path, n=2, n_views=2, h=2, w=2)
    first = sorted(tmp_path.glob("*.png"))[0]
    first.rename(first.with_suffix(".PNG"))
    assert len(LightField(tmp_path, split="all", n_views=2, views=2)) == 2
