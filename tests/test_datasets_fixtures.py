"""Writers of tiny datasets in each dataset's real file format (used by the dataset and example tests).

Each writer puts files under ``root`` exactly as the real dataset lays them out and returns the
arrays it wrote, so tests can check that loaders read back exactly that. The checks of the
writers themselves are at the bottom.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import imageio.v3 as iio
import numpy as np
import scipy.io

from datasets.io import write_pfm

KITTI_DRIVE = "2011_09_26/2011_09_26_drive_0001_sync"
MAT73_HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."


def _rgb(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A random uint8 photo with a bright top-left corner (so a transposed or flipped read shows)."""
    image = rng.integers(0, 200, size=(h, w, 3), dtype=np.uint8)
    image[: h // 3, : w // 4] = 255
    return image


def write_nyu_arrays(root: Path, images: np.ndarray, depths: np.ndarray) -> Path:
    """`nyu_depth_v2_labeled.mat` holding upright `(N,H,W,3)` images and `(N,H,W)` depths of
    any dtype (MATLAB's HxWx3xN array is stored column-major: h5py sees it as (N,3,W,H))."""
    root.mkdir(parents=True, exist_ok=True)
    path = root / "nyu_depth_v2_labeled.mat"
    with h5py.File(path, "w", userblock_size=512) as file:
        file.create_dataset("images", data=images.transpose(0, 3, 2, 1))
        file.create_dataset("depths", data=depths.transpose(0, 2, 1))
    with open(path, "r+b") as raw:
        raw.write(MAT73_HEADER.ljust(128, b" "))
    return path


def write_nyu(root: Path, n: int = 4, h: int = 12, w: int = 16, seed: int = 0) -> dict:
    """``nyu_depth_v2_labeled.mat`` (MAT 7.3, column-major as MATLAB writes it) and ``splits.mat``."""
    rng = np.random.default_rng(seed)
    images = np.stack([_rgb(rng, h, w) for _ in range(n)])  # (N,H,W,3) upright
    depths = rng.uniform(0.7, 9.5, size=(n, h, w))  # metres
    depths[0, 0, :3] = 0.0  # a hole
    write_nyu_arrays(root, images, depths)
    train, test = np.arange(1, n + 1, 2), np.arange(2, n + 1, 2)  # 1-based, as MATLAB
    scipy.io.savemat(root / "splits.mat", {"trainNdxs": train[:, None], "testNdxs": test[:, None]})
    return {"images": images, "depths": depths, "train": train - 1, "test": test - 1}


def write_kitti(root: Path, frames: tuple[int, ...] = (5, 6, 7), h: int = 10, w: int = 24,
                seed: int = 1) -> dict:
    """Raw frames (PNG), projected LiDAR depth (uint16 PNG, metres * 256) and Eigen split files."""
    rng = np.random.default_rng(seed)
    image_dir = root / KITTI_DRIVE / "image_02" / "data"
    depth_dir = root / KITTI_DRIVE / "proj_depth" / "groundtruth" / "image_02"
    image_dir.mkdir(parents=True, exist_ok=True)
    depth_dir.mkdir(parents=True, exist_ok=True)
    images, depths = [], []
    for frame in frames:
        image = _rgb(rng, h, w)
        stored = rng.integers(256, 80 * 256, size=(h, w)).astype(np.uint16)
        stored[rng.random((h, w)) < 0.7] = 0  # sparse LiDAR: 0 = no return
        stored[0, 0] = 1280  # at least one point
        iio.imwrite(image_dir / f"{frame:010d}.png", image)
        iio.imwrite(depth_dir / f"{frame:010d}.png", stored)
        images.append(image)
        depths.append(stored)
    # monodepth2 style for train, image paths for test.
    (root / "eigen_train_files.txt").write_text(
        "".join(f"{KITTI_DRIVE} {f} l\n" for f in frames[:-1])
    )
    (root / "eigen_test_files.txt").write_text(
        f"{KITTI_DRIVE}/image_02/data/{frames[-1]:010d}.png {KITTI_DRIVE}/image_03/data/x.png\n"
    )
    return {"images": np.stack(images), "depths": np.stack(depths), "frames": frames}


def write_make3d(root: Path, n_train: int = 2, n_test: int = 1, h: int = 24, w: int = 18,
                 grid: tuple[int, int] = (8, 6), seed: int = 2) -> dict:
    """``Train400Img/img-*.jpg`` photos and ``Train400Depth/depth_sph_corr-*.mat`` (MAT 5)."""
    rng = np.random.default_rng(seed)
    written: dict = {}
    for split, count, (image_dir, depth_dir) in (
        ("train", n_train, ("Train400Img", "Train400Depth")),
        ("test", n_test, ("Test134Img", "Test134Depth")),
    ):
        (root / image_dir).mkdir(parents=True, exist_ok=True)
        (root / depth_dir).mkdir(parents=True, exist_ok=True)
        for i in range(count):
            name = f"10.21op2-p-{split}{i:03d}t000"
            image = _rgb(rng, h, w)
            iio.imwrite(root / image_dir / f"img-{name}.jpg", image, quality=95)
            position = rng.uniform(1, 80, size=(*grid, 4))  # x, y, z, depth (metres)
            scipy.io.savemat(root / depth_dir / f"depth_sph_corr-{name}.mat",
                             {"Position3DGrid": position})
            written[name] = {"depth": position[..., 3], "jpeg": root / image_dir / f"img-{name}.jpg"}
    return written


def write_dslr(root: Path, n: int = 2, h: int = 12, w: int = 16, seed: int = 3,
               split: str = "train") -> dict:
    """Aperture pairs (f/2.8 and f/8 PNGs) and 16-bit depth PNGs in millimetres."""
    rng = np.random.default_rng(seed)
    written = {}
    for folder in ("f2.8", "f8", "depth"):
        (root / split / folder).mkdir(parents=True, exist_ok=True)
    for i in range(n):
        wide, ref = _rgb(rng, h, w), _rgb(rng, h, w)
        depth_mm = rng.integers(500, 9000, size=(h, w)).astype(np.uint16)
        depth_mm[0, :2] = 0
        name = f"scene{i:02d}"
        iio.imwrite(root / split / "f2.8" / f"{name}.png", wide)
        iio.imwrite(root / split / "f8" / f"{name}.png", ref)
        iio.imwrite(root / split / "depth" / f"{name}.png", depth_mm)
        written[name] = {"wide": wide, "ref": ref, "depth_mm": depth_mm}
    return written


DSLR_TIMES = ("2018-04-26T16:38:31.689710", "2018-04-26T16:38:33.694566",
              "2018-04-26T16:39:47.099665")


def write_dslr_release(root: Path, times: tuple[str, ...] = DSLR_TIMES, h: int = 12, w: int = 16,
                       seed: int = 6, split: str = "train",
                       depth_lag_s: tuple[float, ...] = (0.9, -0.3, -2.5)) -> dict:
    """The DFD-indoor release layout: ``dfd_dataset_indoor_N2_8/{rgb,depth}/<split>`` and
    ``dfd_dataset_indoor_N8/rgb/<split>``; JPEG photos named by time stamp, depth PNGs (uint16
    mm, 0 = unknown) named by the depth sensor's own time stamp, ``depth_lag_s`` seconds off,
    plus one depth file with no photo a minute before the first: the sorted lists line up by
    position nowhere (and the first two depth files sort in the other order)."""
    from datetime import datetime, timedelta

    rng = np.random.default_rng(seed)
    wide_dir = root / "dfd_dataset_indoor_N2_8" / "rgb" / split
    ref_dir = root / "dfd_dataset_indoor_N8" / "rgb" / split
    depth_dir = root / "dfd_dataset_indoor_N2_8" / "depth" / split
    for folder in (wide_dir, ref_dir, depth_dir):
        folder.mkdir(parents=True, exist_ok=True)
    orphan = datetime.fromisoformat(times[0]) - timedelta(seconds=60)
    iio.imwrite(depth_dir / f"{orphan.isoformat()}.png", np.full((h, w), 1500, np.uint16))
    written = {}
    for stamp, lag in zip(times, depth_lag_s, strict=True):
        wide, ref = _rgb(rng, h, w), _rgb(rng, h, w)
        depth_mm = rng.integers(900, 6000, size=(h, w)).astype(np.uint16)
        depth_mm[0, :3] = 0
        iio.imwrite(wide_dir / f"{stamp}.JPG", wide, extension=".jpg", quality=95)
        iio.imwrite(ref_dir / f"{stamp}.JPG", ref, extension=".jpg", quality=95)
        depth_name = f"{(datetime.fromisoformat(stamp) + timedelta(seconds=lag)).isoformat()}.png"
        iio.imwrite(depth_dir / depth_name, depth_mm)
        written[stamp] = {"wide": iio.imread(wide_dir / f"{stamp}.JPG"),
                          "ref": iio.imread(ref_dir / f"{stamp}.JPG"), "depth_mm": depth_mm,
                          "depth_file": depth_name}
    return written


def lightfield_mosaic(views: np.ndarray, layout: str = "interleaved") -> np.ndarray:
    """Mosaic ``(n*H, n*W, 3)`` of views ``(n, n, H, W, 3)`` as a Lytro file lays them out."""
    n, _, h, w, c = views.shape
    if layout == "interleaved":  # each n x n block is one micro-lens
        return views.transpose(2, 0, 3, 1, 4).reshape(h * n, w * n, c)
    return views.transpose(0, 2, 1, 3, 4).reshape(n * h, n * w, c)


def write_lightfield(root: Path, n: int = 2, n_views: int = 14, h: int = 10, w: int = 12,
                     seed: int = 4, layout: str = "interleaved") -> dict:
    """Lytro mosaics of ``n_views x n_views`` sub-aperture views, one PNG per light field."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    written = {}
    for i in range(n):
        views = rng.integers(0, 256, size=(n_views, n_views, h, w, 3), dtype=np.uint8)
        name = f"IMG_{i:04d}_eslf"
        iio.imwrite(root / f"{name}.png", lightfield_mosaic(views, layout))
        written[name] = views
    (root / "test.txt").write_text(f"{name}.png\n")
    return written


def write_middlebury(root: Path, h: int = 12, w: int = 18, seed: int = 5) -> dict:
    """A Middlebury 2014 scene folder: im0.png, im1.png, disp0.pfm (inf = unknown), calib.txt."""
    rng = np.random.default_rng(seed)
    scene = root / "Motorcycle-perfect"
    scene.mkdir(parents=True, exist_ok=True)
    left, right = _rgb(rng, h, w), _rgb(rng, h, w)
    disparity = rng.uniform(1, 7, size=(h, w)).astype(np.float32)  # 2.1-4.4 m
    disparity[0, 0] = np.inf
    iio.imwrite(scene / "im0.png", left)
    iio.imwrite(scene / "im1.png", right)
    write_pfm(scene / "disp0.pfm", disparity)
    calib = {"f": 120.5, "doffs": 4.25, "baseline_mm": 193.001}
    (scene / "calib.txt").write_text(
        f"cam0=[{calib['f']} 0 8.5; 0 {calib['f']} 6.0; 0 0 1]\n"
        f"cam1=[{calib['f']} 0 12.75; 0 {calib['f']} 6.0; 0 0 1]\n"
        f"doffs={calib['doffs']}\nbaseline={calib['baseline_mm']}\nwidth={w}\nheight={h}\n"
        "ndisp=70\nisint=0\nvmin=20\nvmax=60\ndyavg=0\ndymax=0\n"
    )
    return {"left": left, "disparity": disparity, **calib}


def test_nyu_writer_is_column_major(tmp_path):
    written = write_nyu(tmp_path, n=2, h=3, w=5)
    with h5py.File(tmp_path / "nyu_depth_v2_labeled.mat", "r") as file:
        assert file["images"].shape == (2, 3, 5, 3)  # (N, C, W, H)
        assert file["images"][1, 2, 4, 0] == written["images"][1, 0, 4, 2]
    assert (tmp_path / "nyu_depth_v2_labeled.mat").read_bytes().startswith(b"MATLAB 7.3")


def test_lightfield_mosaic_layout():
    views = np.arange(2 * 2 * 2 * 3 * 1).reshape(2, 2, 2, 3, 1)
    mosaic = lightfield_mosaic(views)
    assert mosaic[1 * 2 + 0, 2 * 2 + 1, 0] == views[0, 1, 1, 2, 0]  # pixel (1,2) of view (0,1)
