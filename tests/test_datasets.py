"""Loaders read back exactly what fixture files in each dataset's real format hold."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image
from test_datasets_fixtures import (
    KITTI_DRIVE,
    write_dslr,
    write_kitti,
    write_lightfield,
    write_make3d,
    write_middlebury,
    write_nyu,
)

from datasets import (
    DSLR,
    KITTI,
    PRESETS,
    JointAugment,
    LightField,
    Make3D,
    Middlebury,
    NYUv2,
    collate,
    refocus,
)
from datasets.base import DepthDataset
from datasets.focus import cached_focal_stack
from datasets.middlebury import load_motorcycle
from optics import CameraSettings, render_focal_stack


def srgb_to_linear(uint: np.ndarray) -> torch.Tensor:
    """Independent sRGB decoding of a uint8 ``(H,W,3)`` array into ``(3,H,W)`` float64."""
    x = torch.from_numpy(uint.astype(np.float64) / 255).permute(2, 0, 1)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def check_format(sample: dict, n_focus: int, h: int, w: int, dtype=torch.float32) -> None:
    assert sample["image"].shape == (3, h, w) and sample["image"].dtype == dtype
    assert sample["focused"].shape == (n_focus, 3, h, w) and sample["focused"].dtype == dtype
    assert sample["depth"].shape == (1, h, w) and bool((sample["depth"] > 0).all())
    assert sample["mask"].shape == (1, h, w) and sample["mask"].dtype == torch.bool
    assert isinstance(sample["camera"], CameraSettings)
    assert all(v.shape == (n_focus,) for v in sample["camera"].tensors().values())
    assert 0 <= float(sample["image"].min()) and float(sample["image"].max()) <= 1
    assert isinstance(sample["dataset"], str) and isinstance(sample["id"], str)


def check_synthesised(sample: dict, dtype=torch.float32) -> None:
    """The focused images are the renders of the sample's image and depth with its camera."""
    expected = render_focal_stack(sample["image"][None], sample["depth"][None], sample["camera"])[0]
    torch.testing.assert_close(sample["focused"], expected.clamp(0, 1).to(dtype))


# ---------------------------------------------------------------------------------------- NYU


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_nyu_reads_back_upright(tmp_path, dtype):
    written = write_nyu(tmp_path)
    train = NYUv2(tmp_path, split="train", dtype=dtype)
    test = NYUv2(tmp_path, split="test", dtype=dtype)
    assert len(train) == 2 and len(test) == 2 and len(NYUv2(tmp_path, split="all")) == 4
    for dataset, indices in ((train, written["train"]), (test, written["test"])):
        for k, i in enumerate(indices):
            sample = dataset[k]
            check_format(sample, 2, 12, 16, dtype)
            torch.testing.assert_close(sample["image"], srgb_to_linear(written["images"][i]).to(dtype))
            expected = torch.from_numpy(written["depths"][i]).to(dtype)
            valid = expected > 0
            assert torch.equal(sample["mask"][0], valid)
            torch.testing.assert_close(sample["depth"][0][valid], expected[valid])
            assert sample["dataset"] == "nyu" and sample["id"] == f"{i + 1:04d}"
    check_synthesised(train[0], dtype)
    assert not torch.allclose(train[0]["focused"][0], train[0]["image"])  # some blur
    torch.testing.assert_close(train[0]["camera"].focus_distance, torch.tensor([2.0, 8.0], dtype=dtype))


def test_nyu_resize_scales_pixel_pitch_and_caches(tmp_path):
    write_nyu(tmp_path / "nyu")
    cache = tmp_path / "cache"
    dataset = NYUv2(tmp_path / "nyu", size=(6, 8), cache_dir=cache)
    sample = dataset[0]
    check_format(sample, 2, 6, 8)
    torch.testing.assert_close(sample["camera"].pixel_pitch, torch.full((2,), 22.4e-6 * 640 / 16 * 2))
    check_synthesised(sample)
    assert len(list(cache.glob("*.pt"))) == 1
    assert torch.equal(dataset[0]["focused"], sample["focused"])  # from the cache
    assert len(list(cache.glob("*.pt"))) == 1


def test_fixed_crop_before_resize(tmp_path):
    write_nyu(tmp_path)
    full, cropped = NYUv2(tmp_path)[1], NYUv2(tmp_path, crop=(2, 3, 8, 10))[1]
    check_format(cropped, 2, 8, 10)
    for key in ("image", "depth", "mask"):
        assert torch.equal(cropped[key], full[key][..., 2:10, 3:13]), key
    torch.testing.assert_close(cropped["camera"].pixel_pitch, full["camera"].pixel_pitch)
    resized = NYUv2(tmp_path, crop=(2, 3, 8, 10), size=(4, 5))[1]
    torch.testing.assert_close(resized["camera"].pixel_pitch, 2 * full["camera"].pixel_pitch)


def test_cache_key_changes_with_content(tmp_path):
    settings = PRESETS["nyu"].settings()
    image, depth = torch.rand(3, 6, 6), torch.full((1, 6, 6), 3.0)
    first = cached_focal_stack(image, depth, settings, cache_dir=tmp_path)
    second = cached_focal_stack(image, depth * 2, settings, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.pt"))) == 2 and not torch.equal(first, second)


def test_cache_key_changes_with_the_pixels_of_a_mask_aperture(tmp_path):
    from optics import Mask

    settings = PRESETS["nyu"].settings()
    image = torch.rand(3, 12, 12)
    depth = torch.linspace(1.0, 8.0, 12).expand(1, 12, 12).contiguous()
    row = torch.zeros(5, 5)
    row[2] = 1.0
    horizontal = cached_focal_stack(image, depth, settings, Mask(row), cache_dir=tmp_path)
    vertical = cached_focal_stack(image, depth, settings, Mask(row.T.clone()), cache_dir=tmp_path)
    uncached = cached_focal_stack(image, depth, settings, Mask(row.T.clone()))
    assert len(list(tmp_path.glob("*.pt"))) == 2
    assert torch.equal(vertical, uncached) and not torch.equal(horizontal, vertical)


def test_a_cached_stack_of_another_shape_is_rendered_again(tmp_path):
    """A damaged or stale entry of another shape used to be returned as it was."""
    settings = PRESETS["nyu"].settings()
    image, depth = torch.rand(3, 6, 6), torch.full((1, 6, 6), 3.0)
    first = cached_focal_stack(image, depth, settings, cache_dir=tmp_path)
    (entry,) = tmp_path.glob("*.pt")
    for stale in (torch.zeros(1, 3, 6, 6), {"stack": first}):
        torch.save(stale, entry)
        again = cached_focal_stack(image, depth, settings, cache_dir=tmp_path)
        assert torch.equal(again, first)
        assert torch.equal(torch.load(entry, weights_only=True), first)  # and written again


def test_cache_takes_every_float_dtype(tmp_path):
    settings = PRESETS["nyu"].settings()
    image, depth = torch.rand(3, 6, 6), torch.full((1, 6, 6), 3.0)
    for dtype in (torch.bfloat16, torch.float16, torch.float64):
        stack = cached_focal_stack(image.to(dtype), depth.to(dtype), settings, cache_dir=tmp_path)
        assert stack.dtype == dtype
    assert len(list(tmp_path.glob("*.pt"))) == 3


def test_dataloader_with_workers(tmp_path):
    write_nyu(tmp_path)
    loader = torch.utils.data.DataLoader(NYUv2(tmp_path, split="all"), batch_size=2, num_workers=2,
                                         collate_fn=collate)
    batch = next(iter(loader))
    assert batch["focused"].shape == (2, 2, 3, 12, 16)
    assert batch["camera"].focus_distance.shape == (2, 2)
    camera = batch["camera"].shot(0)
    assert camera.coc_px(batch["depth"]).shape == (2, 1, 12, 16)


# -------------------------------------------------------------------------------------- KITTI


def test_kitti_sparse_depth_masked_and_densified(tmp_path):
    written = write_kitti(tmp_path)
    train, test = KITTI(tmp_path, split="train"), KITTI(tmp_path, split="test")
    assert len(train) == 2 and len(test) == 1
    assert train.ids[0] == f"{KITTI_DRIVE}/image_02/0000000005"
    for dataset, offset in ((train, 0), (test, 2)):
        for k in range(len(dataset)):
            sample = dataset[k]
            check_format(sample, 2, 10, 24)
            torch.testing.assert_close(sample["image"], srgb_to_linear(written["images"][k + offset]).float())
            stored = torch.from_numpy(written["depths"][k + offset].astype(np.float64))
            assert torch.equal(sample["mask"][0], stored > 0)
            torch.testing.assert_close(sample["depth"][0][stored > 0], (stored[stored > 0] / 256).float())
    # Nearest-neighbour fill, checked by brute force on one frame.
    sample, stored = train[0], written["depths"][0].astype(np.float64) / 256
    ys, xs = np.nonzero(stored)
    for y, x in [(0, 1), (5, 7), (9, 23)]:
        if stored[y, x] == 0:
            d2 = (ys - y) ** 2 + (xs - x) ** 2
            candidates = stored[ys, xs][d2 == d2.min()]  # ties: any nearest point is right
            assert np.isclose(candidates, float(sample["depth"][0, y, x]), rtol=1e-6).any()
    check_synthesised(sample)


def test_kitti_depth_in_benchmark_layout(tmp_path):
    """Depth PNGs unzipped as the depth benchmark ships them: <depth_root>/train/<drive>/..."""
    written = write_kitti(tmp_path / "raw")
    drive = KITTI_DRIVE.split("/")[1]
    source = tmp_path / "raw" / KITTI_DRIVE / "proj_depth"
    target = tmp_path / "depth" / "train" / drive / "proj_depth"
    target.parent.mkdir(parents=True)
    source.rename(target)
    sample = KITTI(tmp_path / "raw", "test", depth_root=tmp_path / "depth")[0]
    assert torch.equal(sample["mask"][0], torch.from_numpy(written["depths"][-1] > 0))


def test_kitti_densify_none_fills_with_cap(tmp_path):
    written = write_kitti(tmp_path)
    sample = KITTI(tmp_path, split="train", densify="none")[0]
    assert bool((sample["depth"][0][written["depths"][0] == 0] == 80.0).all())


# ------------------------------------------------------------------------------------- Make3D


def test_make3d_reads_jpeg_and_position3dgrid(tmp_path):
    written = write_make3d(tmp_path)
    train, test = Make3D(tmp_path, "train", size=None), Make3D(tmp_path, "test", size=None)
    assert len(train) == 2 and len(test) == 1
    for dataset in (train, test):
        for k, name in enumerate(dataset.ids):
            sample = dataset[k]
            check_format(sample, 2, 24, 18)
            jpeg = np.asarray(Image.open(written[name]["jpeg"]).convert("RGB"))
            torch.testing.assert_close(sample["image"], srgb_to_linear(jpeg).float())
            grid = written[name]["depth"]  # (8, 6) upsampled x3 by nearest neighbour
            expected = torch.from_numpy(np.repeat(np.repeat(grid, 3, axis=0), 3, axis=1)).float()
            torch.testing.assert_close(sample["depth"][0], expected)
    assert Make3D(tmp_path, "train").size == (460, 345)  # the usual default
    check_synthesised(Make3D(tmp_path, "train", size=(12, 9))[1])


# --------------------------------------------------------------------------------------- DSLR


def test_dslr_real_aperture_pairs(tmp_path):
    written = write_dslr(tmp_path)
    dataset = DSLR(tmp_path, "train")
    assert dataset.ids == ["scene00", "scene01"]
    for k, name in enumerate(dataset.ids):
        sample = dataset[k]
        check_format(sample, 1, 12, 16)
        torch.testing.assert_close(sample["image"], srgb_to_linear(written[name]["ref"]).float())
        torch.testing.assert_close(sample["focused"][0], srgb_to_linear(written[name]["wide"]).float())
        depth_mm = torch.from_numpy(written[name]["depth_mm"].astype(np.float64))
        assert torch.equal(sample["mask"][0], depth_mm > 0)
        torch.testing.assert_close(sample["depth"][0][depth_mm > 0], (depth_mm[depth_mm > 0] / 1000).float())
        torch.testing.assert_close(sample["camera"].f_number, torch.tensor([2.8]))
        torch.testing.assert_close(sample["camera"].pixel_pitch, torch.tensor([4.88e-6 * 7360 / 16]))


# ---------------------------------------------------------------------------------- LightField


@pytest.mark.parametrize("layout", ["interleaved", "tiled"])
def test_lightfield_reads_mosaic_views(tmp_path, layout):
    written = write_lightfield(tmp_path, layout=layout)
    dataset = LightField(tmp_path, layout=layout, views=7, radius=2.0)
    assert len(dataset) == 2 and len(LightField(tmp_path, split="test", layout=layout)) == 1
    for k, name in enumerate(dataset.ids):
        views = dataset.load_views(k)
        expected = torch.stack([torch.stack([srgb_to_linear(v) for v in row]) for row in written[name]])
        torch.testing.assert_close(views, expected[4:11, 4:11].float())
        sample = dataset[k]
        check_format(sample, 2, 10, 12)
        torch.testing.assert_close(sample["image"], expected[7, 7].float())
        torch.testing.assert_close(sample["focused"], refocus(views, [-0.5, 0.5], 2.0).clamp(0, 1))
        assert not bool(sample["mask"].any())


# ---------------------------------------------------------------------------------- Middlebury


def test_middlebury_scene_folder(tmp_path):
    written = write_middlebury(tmp_path)
    dataset = Middlebury(tmp_path)
    assert dataset.ids == ["Motorcycle-perfect"]
    sample = dataset[0]
    check_format(sample, 2, 12, 18)
    torch.testing.assert_close(sample["image"], srgb_to_linear(written["left"]).float())
    disparity = torch.from_numpy(written["disparity"]).double()
    known = torch.isfinite(disparity)
    depth = written["baseline_mm"] * 1e-3 * written["f"] / (disparity + written["doffs"])
    assert torch.equal(sample["mask"][0], known)
    torch.testing.assert_close(sample["depth"][0][known], depth[known].float())
    torch.testing.assert_close(sample["camera"].pixel_pitch, torch.full((2,), 0.085 / written["f"]))
    check_synthesised(sample)


def test_middlebury_builtin_motorcycle_matches_load_motorcycle():
    scene = load_motorcycle()
    sample = Middlebury(None, size=(50, 74))[0]
    assert sample["id"] == "motorcycle" and sample["depth"].shape == (1, 50, 74)
    d = sample["depth"][sample["mask"]]
    assert 2.0 < float(d.min()) and float(d.max()) < 5.2
    assert scene["image"].shape[-2:] == (500, 741)


# -------------------------------------------------------------------------------- augmentation


def coordinate_sample(h=9, w=13, n_focus=2):
    """Image, focused, depth and mask all encoding each pixel's (row, column)."""
    y, x = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                          indexing="ij")
    code = (y * w + x) / (h * w)
    image = torch.stack([code, code, code])
    return {
        "image": image,
        "focused": image.expand(n_focus, -1, -1, -1).clone(),
        "depth": 1 + code[None],
        "mask": (x.long() % 2 == 0)[None],
        "camera": PRESETS["nyu"].settings(torch.float64),
    }


@pytest.mark.parametrize("seed", range(6))
def test_joint_augment_keeps_alignment(seed):
    sample = coordinate_sample()
    aug = JointAugment(crop_size=(5, 7), hflip=0.5, gain=0.0)
    out = aug(sample, generator=torch.Generator().manual_seed(seed))
    assert out["image"].shape == (3, 5, 7) and out["depth"].shape == (1, 5, 7)
    torch.testing.assert_close(out["depth"][0] - 1, out["image"][0])
    for f in range(2):
        torch.testing.assert_close(out["focused"][f], out["image"])
    assert torch.equal(out["mask"][0], (torch.round(out["image"][0] * 9 * 13).long() % 13) % 2 == 0)
    # The crop is a real window of the original: the code increases by 1/117 per column.
    steps = torch.diff(out["image"][0], dim=1) * 9 * 13
    assert torch.allclose(steps.abs(), torch.ones_like(steps))


def test_joint_augment_gains_commute_with_rendering():
    torch.manual_seed(0)
    image, depth = torch.rand(3, 12, 12) * 0.5, torch.rand(1, 12, 12) * 6 + 1
    settings = PRESETS["nyu"].settings()
    sample = {"image": image, "focused": render_focal_stack(image[None], depth[None], settings)[0],
              "depth": depth, "mask": torch.ones(1, 12, 12, dtype=torch.bool)}
    aug = JointAugment(hflip=1.0, gain=0.3)
    out = aug(sample, generator=torch.Generator().manual_seed(1))
    rendered = render_focal_stack(out["image"][None], out["depth"][None], settings)[0]
    torch.testing.assert_close(out["focused"], rendered, atol=1e-5, rtol=1e-5)


def test_dataset_augment_applied_to_all_entries(tmp_path):
    write_nyu(tmp_path)
    aug = JointAugment(crop_size=(8, 10), hflip=1.0)
    plain, augmented = NYUv2(tmp_path), NYUv2(tmp_path, augment=aug)
    torch.manual_seed(3)
    out = augmented[0]
    torch.manual_seed(3)
    params = aug.make_params(12, 16)
    expected = aug.apply(plain[0], params)
    for key in ("image", "focused", "depth", "mask"):
        assert torch.equal(out[key], expected[key]), key


def test_base_class_checks_arguments():
    with pytest.raises(TypeError, match="preset"):
        DepthDataset("nyu")
    with pytest.raises(ValueError, match="crop"):
        DepthDataset(PRESETS["nyu"], crop=(1, 2))
    with pytest.raises(ValueError, match="crop_size"):
        JointAugment(crop_size=(0, 3))
    with pytest.raises(ValueError, match="size must be"):
        DepthDataset(PRESETS["nyu"], size=(32, -1))
