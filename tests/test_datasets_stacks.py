"""The focal-stack benchmarks (DDFF-12, FoD500, ZEDD, Mobile Depth) on tiny files written in
their release formats: values and units of every shot and depth map, and one-line errors for
broken downloads (from the library and from `defocus evaluate`)."""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from PIL import Image

from datasets import DDFF12, ZEDD, DataFormatError, FoD500, MobileDepth
from datasets.ddff12 import BASELINE_M, SUBAPERTURE_FOCAL_PX
from datasets.stacks import fuse_by_sharpness

FB = SUBAPERTURE_FOCAL_PX * BASELINE_M  # metres x pixels
ZEDD_CODES = ("6D3E", "4EA8", "3B39", "2D09", "2371", "1DB4", "183F", "1657", "1113")
ZEDD_FOCUS = (0.82, 1.0, 1.25, 1.6, 2.1, 2.8, 3.9, 5.5, 8.1)


def _texture(rng, h, w):
    return (rng.random((h, w, 3)) * 255).astype(np.uint8)


def write_ddff12(root: Path, n: int = 2, h: int = 12, w: int = 16, disparity=None,
                 name: str = "ddff-dataset-trainval.h5") -> Path:
    """A trainval file with the release's keys and dtypes: uint8 stacks, float32 disparity."""
    rng = np.random.default_rng(0)
    root.mkdir(parents=True, exist_ok=True)
    with h5py.File(root / name, "w") as file:
        for split in ("train", "val"):
            file[f"stack_{split}"] = np.stack([np.stack([_texture(rng, h, w) for _ in range(10)])
                                               for _ in range(n)])
            disp = rng.uniform(0.03, 0.25, (n, h, w)).astype(np.float32) if disparity is None \
                else np.broadcast_to(disparity, (n, h, w)).astype(np.float32)
            disp = disp.copy()
            disp[:, 0, 0] = 0.0  # no measurement
            file[f"disp_{split}"] = disp
    return root / name


def write_exr(path: Path, depth: np.ndarray) -> None:
    import OpenEXR

    half = depth.astype(np.float16)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"R": half, "G": half, "B": half}).write(str(path))


def write_fod500(root: Path, scenes=(0, 400, 401), size: int = 16, depth_scale: float = 1.0,
                 renders: int = 5) -> None:
    rng = np.random.default_rng(1)
    root.mkdir(parents=True, exist_ok=True)
    for scene in scenes:
        for i in range(renders):
            Image.fromarray(_texture(rng, size, size)).save(root / f"{scene:06d}_{i:02d}All.tif")
        depth = rng.uniform(0.1, 2.5, (size, size)).astype(np.float32)
        depth[0, 0] = 0.0
        write_exr(root / f"{scene:06d}Dpt.exr", depth * depth_scale)


def write_zedd(root: Path, split: str = "val", scenes: int = 2, h: int = 12, w: int = 18,
               depth_scale: float = 1.0, runs: int = 9, focal_px: float = 20.0) -> None:
    rng = np.random.default_rng(2)
    root.mkdir(parents=True, exist_ok=True)
    lines = ["# run\thex\tfocus distance (m)"] + [
        f"run_{k + 1}\t{ZEDD_CODES[k]}\t{ZEDD_FOCUS[k]}" for k in range(runs)]
    (root / "metadata.txt").write_text("\n".join(lines) + "\n")
    for s in range(1, scenes + 1):
        scene = root / split / f"{split}_{s:04d}"
        (scene / "focus_stack").mkdir(parents=True)
        (scene / "gt").mkdir()
        for k in range(runs):
            for f_number in ((2.8, 16.0) if k == 4 else (2.8,)):
                Image.fromarray(_texture(rng, h, w)).save(
                    scene / "focus_stack" / f"img_run_{k + 1}_motor_{ZEDD_CODES[k]}_aperture_F"
                    f"{f_number:.1f}.jpg", quality=95)
        np.savetxt(scene / "gt" / "K.txt", [[focal_px, 0, w / 2], [0, focal_px, h / 2], [0, 0, 1]])
        if split == "val":
            depth = rng.uniform(0.8, 9.0, (h, w)).astype(np.float32)
            depth[0, 0] = np.nan
            np.save(scene / "gt" / "depth.npy", depth * depth_scale)


def write_mobile_depth(root: Path, scene: str = "keyboard", frames: int = 5, h: int = 12,
                       w: int = 16, numbers=None, focus=None) -> Path:
    rng = np.random.default_rng(3)
    folder = root / scene
    folder.mkdir(parents=True, exist_ok=True)
    for n in (numbers if numbers is not None else range(frames)):
        Image.fromarray(_texture(rng, h, w)).save(folder / f"a{n:02d}.jpg", quality=95)
    if focus is not None:
        (folder / "focus_dpth.txt").write_text("\n".join(str(v) for v in focus) + "\n")
    return folder


# ---- DDFF-12 -----------------------------------------------------------------------------------

def test_ddff12_sample_values_and_units(tmp_path):
    path = write_ddff12(tmp_path)
    data = DDFF12(tmp_path, split="val")
    assert len(data) == 2 and data.ids == ["val_0000", "val_0001"]
    sample = data[1]
    assert sample["focused"].shape == (10, 3, 12, 16) and sample["image"].shape == (3, 12, 16)
    assert sample["has_all_in_focus"] is False  # the release has no all-in-focus image
    with h5py.File(path) as file:
        disp = file["disp_val"][1]
        stack = file["stack_val"][1]
    torch.testing.assert_close(sample["depth"][0][1:, 1:], torch.from_numpy(FB / disp[1:, 1:]))
    assert not sample["mask"][0, 0, 0] and bool(sample["mask"][0, 1:, 1:].all())
    # sRGB uint8 decoded to linear intensity
    srgb = stack[0, 3, 5, 0] / 255.0
    expected = srgb / 12.92 if srgb <= 0.04045 else ((srgb + 0.055) / 1.055) ** 2.4
    assert float(sample["focused"][0, 0, 3, 5]) == pytest.approx(expected, abs=1e-5)
    camera = sample["camera"]
    assert float(camera.focus_distance[0]) == pytest.approx(0.5)
    assert float(camera.focus_distance[-1]) == pytest.approx(7.0)
    inverse = 1 / camera.focus_distance.double()
    torch.testing.assert_close(inverse.diff(), inverse.diff()[:1].expand(9), rtol=1e-5, atol=0)
    assert float(camera.focal_length[0]) == pytest.approx(521.4052 * 19.6e-6, rel=1e-4)
    assert float(camera.pixel_pitch[0]) == pytest.approx(19.6e-6, rel=1e-4)
    # the thin lens blurs a point like shift-and-add over 9 views: (views-1) |d - d_f| pixels
    coc = camera.shot(0).coc_px(torch.full((1, 1, 1, 1), 2.0)).item()
    assert coc == pytest.approx(8 * abs(FB / 2.0 - FB / 0.5), rel=0.03)


def test_ddff12_shots_subset_and_file_path(tmp_path):
    path = write_ddff12(tmp_path)
    data = DDFF12(path, split="train", shots=[0, 2, 4, 6, 9])
    sample = data[0]
    assert sample["focused"].shape[0] == 5
    assert float(sample["camera"].focus_distance[-1]) == pytest.approx(7.0)
    with pytest.raises(ValueError, match="shots"):
        DDFF12(path, split="train", shots=[3, 1])


def test_ddff12_disparity_read_as_depth_is_refused(tmp_path):
    write_ddff12(tmp_path, disparity=np.float32(2.5))  # metres stored where disparity belongs
    with pytest.raises(DataFormatError, match=r"disp_val\[0\].*depth"):
        DDFF12(tmp_path, split="val")[0]


def test_ddff12_missing_key_and_truncated_file(tmp_path):
    path = write_ddff12(tmp_path)
    with h5py.File(path, "a") as file:
        del file["disp_val"]
    with pytest.raises(DataFormatError, match="missing key 'disp_val'") as info:
        DDFF12(tmp_path, split="val")
    assert str(path) in str(info.value) and "\n" not in str(info.value).split("Expected")[0]
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    with pytest.raises(DataFormatError, match="HDF5.*truncated"):
        DDFF12(tmp_path, split="val")
    with pytest.raises(FileNotFoundError, match="ddff-dataset-test.h5"):
        DDFF12(tmp_path, split="test")


# ---- FoD500 ------------------------------------------------------------------------------------

def test_fod500_sample_values_and_units(tmp_path):
    write_fod500(tmp_path)
    test = FoD500(tmp_path, split="test")
    assert test.ids == ["000400", "000401"] and FoD500(tmp_path, split="train").ids == ["000000"]
    sample = test[0]
    assert sample["focused"].shape == (5, 3, 16, 16) and sample["has_all_in_focus"] is False
    camera = sample["camera"]
    torch.testing.assert_close(camera.focus_distance,
                               torch.tensor([0.1, 0.15, 0.3, 0.7, 1.5]))
    assert float(camera.focal_length[0]) == pytest.approx(2.9e-3)
    assert float(camera.f_number[0]) == pytest.approx(1.0)
    assert float(camera.pixel_pitch[0]) == pytest.approx(3.1e-3 / 16)
    assert not sample["mask"][0, 0, 0] and float(sample["depth"].max()) <= 2.51
    assert float(sample["depth"][0, 1, 1]) > 0.09


def test_fod500_all_in_focus_render_is_used_when_present(tmp_path):
    write_fod500(tmp_path, scenes=(400,))
    Image.fromarray(np.full((16, 16, 3), 255, np.uint8)).save(tmp_path / "000400Aif.tif")
    sample = FoD500(tmp_path, split="test")[0]
    assert sample["has_all_in_focus"] is True and float(sample["image"].min()) == 1.0


def test_fod500_errors(tmp_path):
    write_fod500(tmp_path / "mm", scenes=(400,), depth_scale=1000.0)
    with pytest.raises(DataFormatError, match="000400Dpt.exr.*millimetres"):
        FoD500(tmp_path / "mm", split="test")[0]
    write_fod500(tmp_path / "four", scenes=(400,), renders=4)
    with pytest.raises(DataFormatError, match="scene 000400.*4 renders.*expected 5"):
        FoD500(tmp_path / "four", split="test")
    write_fod500(tmp_path / "cut", scenes=(400,))
    exr = tmp_path / "cut" / "000400Dpt.exr"
    exr.write_bytes(exr.read_bytes()[:-40])
    with pytest.raises(DataFormatError, match="000400Dpt.exr.*truncated"):
        FoD500(tmp_path / "cut", split="test")[0]
    exr.unlink()
    with pytest.raises(FileNotFoundError, match="000400Dpt.exr"):
        FoD500(tmp_path / "cut", split="test")


# ---- ZEDD --------------------------------------------------------------------------------------

def test_zedd_sample_values_and_units(tmp_path):
    write_zedd(tmp_path)
    data = ZEDD(tmp_path)
    sample = data[0]
    assert data.ids == ["val_0001", "val_0002"]
    assert sample["focused"].shape == (5, 3, 12, 18) and sample["has_all_in_focus"] is True
    camera = sample["camera"]
    torch.testing.assert_close(camera.focus_distance,
                               torch.tensor([ZEDD_FOCUS[i] for i in (0, 2, 4, 6, 8)]))
    assert float(camera.f_number[0]) == pytest.approx(2.8)
    assert float(camera.pixel_pitch[0]) == pytest.approx(36e-3 / 18)
    assert float(camera.focal_length[0]) == pytest.approx(20.0 * 36e-3 / 18)
    depth = np.load(tmp_path / "val" / "val_0001" / "gt" / "depth.npy")
    assert not sample["mask"][0, 0, 0]  # NaN in the file
    torch.testing.assert_close(sample["depth"][0, 1:, :], torch.from_numpy(depth[1:, :]))
    other = ZEDD(tmp_path, shots=[1, 3], f_number=2.8)[0]
    assert other["focused"].shape[0] == 2


def test_zedd_errors(tmp_path):
    write_zedd(tmp_path / "mm", depth_scale=1000.0, scenes=1)
    with pytest.raises(DataFormatError, match="depth.npy.*millimetres"):
        ZEDD(tmp_path / "mm")[0]
    write_zedd(tmp_path / "runs", runs=8, scenes=1)  # run_9 (focus setting 8) missing
    with pytest.raises(DataFormatError, match="metadata.txt.*no focus distance for run_9"):
        ZEDD(tmp_path / "runs")
    write_zedd(tmp_path / "cut", scenes=1)
    npy = tmp_path / "cut" / "val" / "val_0001" / "gt" / "depth.npy"
    npy.write_bytes(npy.read_bytes()[:100])
    with pytest.raises(DataFormatError, match="depth.npy.*truncated"):
        ZEDD(tmp_path / "cut")[0]
    write_zedd(tmp_path / "test", split="test", scenes=1)
    sample = ZEDD(tmp_path / "test", split="test")[0]
    assert not bool(sample["mask"].any())
    # no depth in the test split: K is in the 1824-pixel-wide depth frame, the pitch the photo's
    assert float(sample["camera"].focal_length[0]) == pytest.approx(20.0 * 36e-3 / 1824)
    assert float(sample["camera"].pixel_pitch[0]) == pytest.approx(36e-3 / 18)


# ---- Mobile Depth ------------------------------------------------------------------------------

def test_mobile_depth_frames_and_focus(tmp_path):
    write_mobile_depth(tmp_path, "keyboard", focus=[10.0, 8.0, 6.0, 4.0, 2.0])
    write_mobile_depth(tmp_path, "plants")
    data = MobileDepth(tmp_path, focus_range=(0.1, 1.0))
    assert data.ids == ["keyboard", "plants"]
    keyboard, plants = data[0], data[1]
    assert keyboard["focused"].shape == (5, 3, 12, 16) and not bool(keyboard["mask"].any())
    # calibrated values, largest nearest: the first frame is the nearest
    assert float(keyboard["camera"].focus_distance[0]) == pytest.approx(0.1)
    assert float(keyboard["camera"].focus_distance[-1]) == pytest.approx(1.0)
    # no calibration: far to near, equally spaced in inverse distance
    assert float(plants["camera"].focus_distance[0]) == pytest.approx(1.0)
    assert float(plants["camera"].focus_distance[-1]) == pytest.approx(0.1)
    metres = MobileDepth(tmp_path, scenes=["plants"], focus_distances=[0.5, 0.4, 0.3, 0.2, 0.15],
                         n_shots=3)[0]
    torch.testing.assert_close(metres["camera"].focus_distance, torch.tensor([0.5, 0.3, 0.15]))


def test_mobile_depth_errors(tmp_path):
    write_mobile_depth(tmp_path / "gap", numbers=[0, 1, 3])
    with pytest.raises(DataFormatError, match="frames out of order.*missing \\[2\\]"):
        MobileDepth(tmp_path / "gap")
    write_mobile_depth(tmp_path / "short", focus=[1.0, 2.0, 3.0])
    with pytest.raises(DataFormatError, match="focus_dpth.txt.*3 focus values for 5 frames"):
        MobileDepth(tmp_path / "short")
    write_mobile_depth(tmp_path / "order", focus=[1.0, 3.0, 2.0, 4.0, 5.0])
    with pytest.raises(DataFormatError, match="focus_dpth.txt.*strictly"):
        MobileDepth(tmp_path / "order")


@pytest.mark.parametrize("bad", [math.nan, -1.0, math.inf])
def test_mobile_depth_refuses_focus_values_that_are_no_distance_naming_the_file(tmp_path, bad):
    folder = write_mobile_depth(tmp_path, frames=3, focus=[1.0, bad, 3.0])
    with pytest.raises(DataFormatError, match=f"{folder / 'focus_dpth.txt'}'?: focus values"):
        MobileDepth(tmp_path)
    with pytest.raises(ValueError, match="focus_distances for scene 'keyboard' must hold one "
                                         "finite distance > 0"):
        MobileDepth(tmp_path, focus_distances=[1.0, bad, 3.0])


def test_mobile_depth_refuses_a_corrupt_frame_one_frame_and_two_columns(tmp_path):
    folder = write_mobile_depth(tmp_path / "corrupt", frames=3)
    frame = folder / "a01.jpg"
    frame.write_bytes(frame.read_bytes()[:200])
    with pytest.raises(DataFormatError, match=f"{frame}'?: cannot be read as a photo"):
        MobileDepth(tmp_path / "corrupt")[0]
    folder = write_mobile_depth(tmp_path / "one", frames=1)
    with pytest.raises(DataFormatError, match=f"{folder}'?: 1 frame.* needs 2 or more"):
        MobileDepth(tmp_path / "one")
    folder = write_mobile_depth(tmp_path / "columns", frames=3)
    (folder / "focus_dpth.txt").write_text("0.1 1\n0.2 1\n0.3 1\n")
    with pytest.raises(DataFormatError, match="focus_dpth.txt'?: .*2 columns"):
        MobileDepth(tmp_path / "columns")


def test_fuse_by_sharpness_takes_each_pixel_from_the_sharpest_shot():
    sharp = torch.rand(3, 8, 16)
    flat = torch.full((3, 8, 16), 0.5)
    left = torch.cat([sharp[..., :8], flat[..., 8:]], -1)
    right = torch.cat([flat[..., :8], sharp[..., 8:]], -1)
    fused = fuse_by_sharpness(torch.stack([left, right]), window=3)
    torch.testing.assert_close(fused[..., 1:7], sharp[..., 1:7])
    torch.testing.assert_close(fused[..., 9:15], sharp[..., 9:15])


# ---- the command line --------------------------------------------------------------------------

def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    assert err.startswith("defocus evaluate: error: "), err
    return err


@pytest.mark.parametrize("case", ["ddff12 disparity as depth", "ddff12 truncated",
                                  "fod500 millimetres", "zedd missing focus", "mobile order",
                                  "no root"])
def test_evaluate_reports_broken_benchmarks_in_one_line(case, tmp_path, capsys):
    from defocus.cli import main

    root = tmp_path / "data"
    if case == "ddff12 disparity as depth":
        write_ddff12(root, disparity=np.float32(3.0))
    elif case == "ddff12 truncated":
        path = write_ddff12(root)
        path.write_bytes(path.read_bytes()[:2000])
    elif case == "fod500 millimetres":
        write_fod500(root, scenes=(400,), depth_scale=1000.0)
    elif case == "zedd missing focus":
        write_zedd(root, runs=8, scenes=1)
    elif case == "mobile order":
        write_mobile_depth(root, numbers=[0, 2])
    name = case.split()[0] if case != "no root" else "zedd"
    if name == "mobile":
        name = "mobile_depth"
    out = tmp_path / "out.json"
    argv = ["evaluate", "--data", name, "--json", str(out)]
    if case != "no root":
        argv += ["--root", str(root)]
    assert main(argv) == 2
    message = _one_line_error(capsys)
    expected = {"ddff12 disparity as depth": "disp_val", "ddff12 truncated": "ddff-dataset-trainval.h5",
                "fod500 millimetres": "000400Dpt.exr", "zedd missing focus": "run_9",
                "mobile order": "a00", "no root": "--root"}[case]
    if case == "mobile order":
        expected = "frames out of order"
    assert expected in message
    assert not out.exists()


def test_evaluate_scores_a_benchmark_on_fixtures(tmp_path, capsys):
    from defocus.cli import main

    write_ddff12(tmp_path / "ddff", n=1, h=24, w=32)
    out = tmp_path / "ddff.json"
    assert main(["evaluate", "--data", "ddff12", "--root", str(tmp_path / "ddff"),
                 "--max-samples", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| method" in text and "bump" in text and "Hazirbas" in text
    import json

    metrics = json.loads(out.read_text())
    assert metrics["images"] == 1 and metrics["protocol"] == "ddff12"
    write_mobile_depth(tmp_path / "mobile")
    assert main(["evaluate", "--data", "mobile_depth", "--root", str(tmp_path / "mobile")]) == 0
    assert "judged by eye" in capsys.readouterr().out


def test_evaluate_offers_every_label_free_method():
    from defocus.options import METHOD_NAMES
    from models.depth_from_photos import METHODS

    assert set(METHOD_NAMES) == {"auto", *METHODS}


def write_mobile_depth_release(root: Path, frames: int = 4, h: int = 12, w: int = 16) -> None:
    """The two release zips unpacked side by side: data3's `Aligned/Figure<N>/<scene>/a<NN>.jpg`
    and data2's `calibration/<name>/calibrated.txt` (`<focus value> <aperture>` a frame, then the
    focal length alone)."""
    rng = np.random.default_rng(4)
    for figure, scene in (("Figure1", "keyboard"), ("Figure5", "metals"), ("Figure7", "bucket")):
        folder = root / "Aligned" / figure / scene
        folder.mkdir(parents=True)
        for n in range(frames):
            Image.fromarray(_texture(rng, h, w)).save(folder / f"a{n:02d}.jpg", quality=95)
    for name, values in (("keyboard", [3.0, 2.0, 1.5, 1.0]), ("metal", [1.0, 2.0, 3.0, 4.0])):
        folder = root / "calibration" / name
        folder.mkdir(parents=True)
        lines = [f"{v} 0.01" for v in values] + ["25.5"]
        (folder / "calibrated.txt").write_text("\n".join(lines) + "\n")


def test_mobile_depth_release_layout(tmp_path):
    write_mobile_depth_release(tmp_path)
    for root in (tmp_path, tmp_path / "Aligned"):  # the calibration is found from either
        data = MobileDepth(root, focus_range=(0.1, 1.0))
        assert data.ids == ["bucket", "keyboard", "metals"]
        bucket, keyboard, metals = data.focus
        # keyboard: the largest calibrated value (frame 0) is the nearest
        assert keyboard[0] == pytest.approx(0.1) and keyboard[-1] == pytest.approx(1.0)
        # metals reads calibration/metal, whose values run the other way (negated, as DFV does)
        assert metals[0] == pytest.approx(0.1) and metals[-1] == pytest.approx(1.0)
        # bucket has no calibration: frame order, far to near
        assert bucket[0] == pytest.approx(1.0) and bucket[-1] == pytest.approx(0.1)
        assert data.frames[1][2].name == "a02.jpg"
    assert MobileDepth(tmp_path, scenes=["metals"])[0]["focused"].shape == (4, 3, 12, 16)
    with pytest.raises(FileNotFoundError, match="named \\['plants'\\].*found"):
        MobileDepth(tmp_path, scenes=["plants"])


def test_mobile_depth_release_calibration_order(tmp_path):
    write_mobile_depth_release(tmp_path)
    calibrated = tmp_path / "calibration" / "keyboard" / "calibrated.txt"
    calibrated.write_text("3.0 0.01\n1.5 0.01\n2.0 0.01\n1.0 0.01\n25.5\n")
    with pytest.raises(DataFormatError, match="calibrated.txt.*strictly.*sort_by_focus"):
        MobileDepth(tmp_path)
    data = MobileDepth(tmp_path, scenes=["keyboard"], sort_by_focus=True, focus_range=(0.1, 1.0))
    # frames ordered by value, smallest (farthest) first: a03, a01, a02, a00
    assert [p.name for p in data.frames[0]] == ["a03.jpg", "a01.jpg", "a02.jpg", "a00.jpg"]
    assert data.focus[0][0] == pytest.approx(1.0) and data.focus[0][-1] == pytest.approx(0.1)
    calibrated.write_text("3.0 0.01\n2.0 0.01\n25.5\n")
    with pytest.raises(DataFormatError, match="calibrated.txt.*2 focus values for 4 frames"):
        MobileDepth(tmp_path, scenes=["keyboard"])
    calibrated.write_text("3.0 0.01\n2.0 x\n1.5 0.01\n1.0 0.01\n25.5\n")
    with pytest.raises(DataFormatError, match="calibrated.txt.*not lines of numbers"):
        MobileDepth(tmp_path, scenes=["keyboard"])


def test_mobile_depth_release_bad_input(tmp_path):
    write_mobile_depth_release(tmp_path)
    with pytest.raises(FileNotFoundError, match="calibration folder .*nowhere.* is missing"):
        MobileDepth(tmp_path, calibration=tmp_path / "nowhere")
    # the same scene in two figures: which one is meant is unknown
    twin = tmp_path / "Aligned" / "Figure3" / "keyboard"
    twin.mkdir(parents=True)
    Image.fromarray(np.zeros((12, 16, 3), np.uint8)).save(twin / "a00.jpg")
    with pytest.raises(DataFormatError, match="two scene folders named 'keyboard'"):
        MobileDepth(tmp_path)
