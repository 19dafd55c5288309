"""Missing or malformed data fails early with an error naming the file and what was expected."""

from __future__ import annotations

import re

import h5py
import imageio.v3 as iio
import numpy as np
import pytest
import scipy.io
import torch
from test_datasets_fixtures import (
    KITTI_DRIVE,
    write_dslr,
    write_kitti,
    write_lightfield,
    write_make3d,
    write_middlebury,
    write_nyu,
)

from datasets import DSLR, KITTI, DataFormatError, LightField, Make3D, Middlebury, NYUv2, collate
from datasets.io import read_pfm

WRITERS = {
    NYUv2: write_nyu,
    KITTI: write_kitti,
    Make3D: write_make3d,
    DSLR: write_dslr,
    LightField: write_lightfield,
    Middlebury: write_middlebury,
}


def truncate(path, keep=0.5):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def names(path) -> str:
    return re.escape(str(path))


@pytest.mark.parametrize("cls", list(WRITERS), ids=lambda c: c.__name__)
def test_missing_root(tmp_path, cls):
    with pytest.raises(FileNotFoundError, match=names(tmp_path / "nowhere") + ".*Expected"):
        cls(tmp_path / "nowhere")


# ------------------------------------------------------------------------------ missing files


def test_missing_files(tmp_path):
    write_nyu(tmp_path / "nyu")
    (tmp_path / "nyu" / "splits.mat").unlink()
    with pytest.raises(FileNotFoundError, match=names(tmp_path / "nyu" / "splits.mat")):
        NYUv2(tmp_path / "nyu", split="train")
    assert len(NYUv2(tmp_path / "nyu", split="all")) == 4  # "all" needs no splits.mat

    write_kitti(tmp_path / "kitti")
    depth = tmp_path / "kitti" / KITTI_DRIVE / "proj_depth/groundtruth/image_02/0000000006.png"
    depth.unlink()
    with pytest.raises(FileNotFoundError, match=names(depth) + ".*KITTI depth PNG"):
        KITTI(tmp_path / "kitti", split="train")
    frame = tmp_path / "kitti" / KITTI_DRIVE / "image_02/data/0000000007.png"
    frame.unlink()
    with pytest.raises(FileNotFoundError, match=names(frame) + ".*raw frame"):
        KITTI(tmp_path / "kitti", split="test")
    with pytest.raises(FileNotFoundError, match="eigen_val_files.txt"):
        KITTI(tmp_path / "kitti", split="val")

    written = write_make3d(tmp_path / "make3d")
    name = sorted(written)[0]
    mat = tmp_path / "make3d" / "Test134Depth" / f"depth_sph_corr-{name}.mat"
    mat.unlink()
    with pytest.raises(FileNotFoundError, match=names(mat)):
        Make3D(tmp_path / "make3d", "test")

    write_dslr(tmp_path / "dslr")
    (tmp_path / "dslr" / "train" / "depth" / "scene01.png").unlink()
    with pytest.raises(FileNotFoundError, match=names(tmp_path / "dslr/train/depth/scene01.png")):
        DSLR(tmp_path / "dslr")

    write_lightfield(tmp_path / "lf")
    (tmp_path / "lf" / "IMG_0001_eslf.png").unlink()
    with pytest.raises(FileNotFoundError, match=names(tmp_path / "lf" / "IMG_0001_eslf.png")):
        LightField(tmp_path / "lf", split="test")

    write_middlebury(tmp_path / "mb")
    (tmp_path / "mb" / "Motorcycle-perfect" / "disp0.pfm").unlink()
    with pytest.raises(FileNotFoundError, match=names(tmp_path / "mb/Motorcycle-perfect/disp0.pfm")):
        Middlebury(tmp_path / "mb")


# ---------------------------------------------------------------------------- truncated files


def test_truncated_files(tmp_path):
    write_nyu(tmp_path / "nyu")
    mat = tmp_path / "nyu" / "nyu_depth_v2_labeled.mat"
    truncate(mat)
    with pytest.raises(DataFormatError, match=names(mat) + ".*truncated"):
        NYUv2(tmp_path / "nyu", split="all")

    write_nyu(tmp_path / "nyu2")
    truncate(tmp_path / "nyu2" / "splits.mat", 0.6)
    with pytest.raises(DataFormatError, match=names(tmp_path / "nyu2" / "splits.mat")):
        NYUv2(tmp_path / "nyu2", split="test")

    write_kitti(tmp_path / "kitti")
    depth = tmp_path / "kitti" / KITTI_DRIVE / "proj_depth/groundtruth/image_02/0000000005.png"
    truncate(depth)
    dataset = KITTI(tmp_path / "kitti")  # per-frame files are read on access
    with pytest.raises(DataFormatError, match=names(depth) + ".*truncated"):
        dataset[0]

    written = write_make3d(tmp_path / "make3d")
    name = sorted(written)[0]
    mat = tmp_path / "make3d" / "Test134Depth" / f"depth_sph_corr-{name}.mat"
    truncate(mat, 0.3)
    with pytest.raises(DataFormatError, match=names(mat)):
        Make3D(tmp_path / "make3d", "test", size=None)[0]

    write_lightfield(tmp_path / "lf")
    truncate(tmp_path / "lf" / "IMG_0000_eslf.png")
    with pytest.raises(DataFormatError, match=names(tmp_path / "lf" / "IMG_0000_eslf.png")):
        LightField(tmp_path / "lf")[0]

    write_middlebury(tmp_path / "mb")
    pfm = tmp_path / "mb" / "Motorcycle-perfect" / "disp0.pfm"
    truncate(pfm, 0.8)
    with pytest.raises(DataFormatError, match=names(pfm) + ".*truncated PFM"):
        Middlebury(tmp_path / "mb")[0]


def test_truncated_files_in_dataloader_worker(tmp_path):
    """The worker's error reaches the main process with the file name in it."""
    write_dslr(tmp_path)
    truncate(tmp_path / "train" / "f8" / "scene00.png")
    loader = torch.utils.data.DataLoader(DSLR(tmp_path), batch_size=1, num_workers=1,
                                         collate_fn=collate)
    with pytest.raises(DataFormatError, match=names(tmp_path / "train/f8/scene00.png")):
        next(iter(loader))


# -------------------------------------------------------------------------------- wrong shape


def test_wrong_shapes(tmp_path):
    root = tmp_path / "nyu"
    root.mkdir()
    with h5py.File(root / "nyu_depth_v2_labeled.mat", "w") as file:
        file.create_dataset("images", data=np.zeros((2, 3, 16, 12), np.uint8))
        file.create_dataset("depths", data=np.zeros((2, 12, 16)))  # (N,H,W): not MATLAB's order
    with pytest.raises(DataFormatError, match=names(root / "nyu_depth_v2_labeled.mat") + ".*(N,3,W,H)"):
        NYUv2(root, split="all")

    written = write_make3d(tmp_path / "make3d")
    name = sorted(written)[0]
    mat = tmp_path / "make3d" / "Test134Depth" / f"depth_sph_corr-{name}.mat"
    scipy.io.savemat(mat, {"Position3DGrid": np.ones((8, 6, 3))})
    with pytest.raises(DataFormatError, match=names(mat) + r".*\(any, any, 4\)"):
        Make3D(tmp_path / "make3d", "test")[0]

    write_kitti(tmp_path / "kitti")
    depth = tmp_path / "kitti" / KITTI_DRIVE / "proj_depth/groundtruth/image_02/0000000005.png"
    iio.imwrite(depth, np.ones((9, 24), np.uint16))
    with pytest.raises(DataFormatError, match=names(depth) + ".*0000000005.png"):
        KITTI(tmp_path / "kitti")[0]

    write_dslr(tmp_path / "dslr")
    depth = tmp_path / "dslr" / "train" / "depth" / "scene00.png"
    iio.imwrite(depth, np.ones((12, 16, 3), np.uint8))
    with pytest.raises(DataFormatError, match=names(depth) + ".*single-channel 16-bit"):
        DSLR(tmp_path / "dslr")[0]

    write_lightfield(tmp_path / "lf", n_views=14)
    with pytest.raises(DataFormatError, match=names(tmp_path / "lf" / "IMG_0000_eslf.png") + ".*13x13"):
        LightField(tmp_path / "lf", n_views=13)[0]

    write_middlebury(tmp_path / "mb")
    calib = tmp_path / "mb" / "Motorcycle-perfect" / "calib.txt"
    calib.write_text("doffs=1\nbaseline=100\n")
    with pytest.raises(DataFormatError, match=names(calib) + ".*cam0"):
        Middlebury(tmp_path / "mb")[0]


def test_bad_arguments(tmp_path):
    write_nyu(tmp_path)
    with pytest.raises(ValueError, match="split must be one of"):
        NYUv2(tmp_path, split="val")
    with pytest.raises(ValueError, match="views must be odd"):
        LightField(tmp_path, views=4)
    with pytest.raises(IndexError, match="out of range"):
        NYUv2(tmp_path)[5]


def test_pfm_round_trip_is_upright(tmp_path):
    array = np.arange(12, dtype=np.float32).reshape(3, 4)
    from datasets.io import write_pfm

    write_pfm(tmp_path / "a.pfm", array)
    assert np.array_equal(read_pfm(tmp_path / "a.pfm"), array)
    raw = (tmp_path / "a.pfm").read_bytes()
    first_row_stored = np.frombuffer(raw[-16:], "<f4")  # PFM stores rows bottom to top
    assert np.array_equal(first_row_stored, array[0])
