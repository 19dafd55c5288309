"""`datasets.RGBD`: a plain folder of RGB-D scenes whose focused images are synthesised the
paper's way; its door errors; `--data rgbd` and `--focus` on the command line."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from datasets import RGBD, DataFormatError, SynthesizedFocus
from datasets.focus import PAPER_FOCUS_FRACTIONS, paper_focus
from datasets.registry import build_dataset, focus_of
from optics import CameraSettings, render_focal_stack


def write_scene(folder: Path, h: int = 10, w: int = 14, depth: str = "npy", seed: int = 0,
                image: str = "image.png") -> dict:
    """One scene: an 8-bit sRGB photo and its depth (float metres in `.npy`, or 16-bit
    millimetres in `.png` with a hole of zeros)."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    photo = rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
    iio.imwrite(folder / image, photo)
    metres = rng.uniform(0.8, 9.0, size=(h, w))
    if depth == "npy":
        metres[0, :2] = np.nan  # unknown
        np.save(folder / "depth.npy", metres.astype(np.float32))
    else:
        millimetres = np.round(metres * 1000).astype(np.uint16)
        millimetres[0, :2] = 0  # unknown
        iio.imwrite(folder / "depth.png", millimetres)
        metres = millimetres / 1000.0
    return {"photo": photo, "depth": metres}


def write_camera(path: Path, focus=(1.0, 3.0), f_number: float = 2.0,
                 pitch: float = 4e-5) -> CameraSettings:
    camera = CameraSettings(0.05, f_number, list(focus), pitch)
    path.parent.mkdir(parents=True, exist_ok=True)
    camera.to_json(path)
    return camera


def test_scenes_read_metres_and_millimetres_with_their_holes(tmp_path):
    a = write_scene(tmp_path / "a", depth="npy")
    b = write_scene(tmp_path / "b", depth="png", seed=1)
    data = RGBD(tmp_path)
    assert data.ids == ["a", "b"] and len(data) == 2
    for sample, written in zip((data[0], data[1]), (a, b), strict=True):
        mask = sample["mask"][0]
        assert not mask[0, :2].any() and mask.sum() == mask.numel() - 2
        truth = torch.from_numpy(written["depth"]).float()
        assert torch.allclose(sample["depth"][0][mask], truth[mask], rtol=1e-6)
        # the holes are filled with the farthest known depth for rendering
        assert torch.allclose(sample["depth"][0, 0, :2], truth[mask].max().expand(2))
    assert data[1]["dataset"] == "rgbd" and data[1]["id"] == "b"


def test_default_camera_is_the_papers_and_the_render_is_the_psf_layer(tmp_path):
    write_scene(tmp_path / "s", h=10, w=14)
    sample = RGBD(tmp_path)[0]
    camera = sample["camera"]
    # NYU's camera (35 mm f/2.8, 5.6 um x 4 at 640 wide) scaled to 14 pixels wide
    assert camera.focus_distance.tolist() == pytest.approx([2.0, 8.0])
    assert camera.focus_distance.tolist() == pytest.approx(
        [10.0 * f for f in PAPER_FOCUS_FRACTIONS])
    assert camera.f_number.tolist() == pytest.approx([2.8, 2.8])
    assert camera.pixel_pitch.tolist() == pytest.approx([22.4e-6 * 640 / 14] * 2)
    expected = render_focal_stack(sample["image"][None], sample["depth"][None], camera)[0]
    assert torch.allclose(sample["focused"], expected.clamp(0, 1), atol=1e-6)


def test_camera_json_of_the_scene_over_the_roots(tmp_path):
    write_scene(tmp_path / "a")
    write_scene(tmp_path / "b", seed=1)
    write_camera(tmp_path / "camera.json", focus=(1.0, 3.0), pitch=4e-5)
    own = write_camera(tmp_path / "b" / "camera.json", focus=(1.5, 4.0), f_number=1.4)
    data = RGBD(tmp_path)
    assert data[0]["camera"].focus_distance.tolist() == pytest.approx([1.0, 3.0])
    assert data[0]["camera"].pixel_pitch.tolist() == pytest.approx([4e-5] * 2)  # as it is
    assert data[1]["camera"].f_number.tolist() == pytest.approx(own.f_number.tolist())
    assert data[1]["camera"].focus_distance.tolist() == pytest.approx([1.5, 4.0])


def test_splits_are_lists_or_every_folder(tmp_path):
    for name in ("a", "b", "c"):
        write_scene(tmp_path / name)
    (tmp_path / "test.txt").write_text("c\n")
    assert RGBD(tmp_path, split="all").ids == ["a", "b", "c"]
    assert RGBD(tmp_path, split="test").ids == ["c"]
    with pytest.raises(FileNotFoundError, match="no val.txt listing the scenes of split 'val'"):
        RGBD(tmp_path, split="val")


@pytest.mark.parametrize("broken, error, message", [
    ("no depth", FileNotFoundError, r"no depth map \(depth.npy, depth.png\)"),
    ("two depths", FileNotFoundError, r"2 depth maps \(depth.npy, depth.png\); keep one"),
    ("no photo", FileNotFoundError, "no all-in-focus photo"),
    ("bad camera", DataFormatError, "camera.json: cannot read camera settings"),
    ("camera shots", DataFormatError, "render different numbers of focused images"),
])
def test_door_errors_name_the_file(tmp_path, broken, error, message):
    write_scene(tmp_path / "a")
    scene = tmp_path / "b"
    write_scene(scene, seed=1)
    if broken == "no depth":
        (scene / "depth.npy").unlink()
    elif broken == "two depths":
        iio.imwrite(scene / "depth.png", np.full((10, 14), 2000, np.uint16))
    elif broken == "no photo":
        (scene / "image.png").unlink()
    elif broken == "bad camera":
        (scene / "camera.json").write_text("{not json")
    else:
        write_camera(scene / "camera.json", focus=(1.0, 2.0, 3.0))
    with pytest.raises(error, match=message) as info:
        RGBD(tmp_path)
    assert str(scene) in str(info.value)


@pytest.mark.parametrize("broken, message", [
    ("size", r"'.*depth.npy' is \(10, 13\) pixels but '.*image.png' is \(10, 14\)"),
    ("millimetres", r"median \d{4} m; expected metres with a median in 0-1000 m"),
    ("integers", "expected float depth in metres"),
    ("empty", "no valid depth pixel"),
])
def test_reading_a_bad_depth_map_names_it(tmp_path, broken, message):
    write_scene(tmp_path / "s")
    path = tmp_path / "s" / "depth.npy"
    depth = np.load(path)
    bad = {"size": depth[:, :13], "millimetres": depth * 1000, "integers": np.nan_to_num(depth).astype(np.int32),
           "empty": np.zeros_like(depth)}[broken]
    np.save(path, bad)
    data = RGBD(tmp_path)  # the files' contents are read with the scene
    with pytest.raises(DataFormatError, match=message):
        data[0]


def test_paper_focus_keeps_the_lens_and_sets_two_planes():
    lens = CameraSettings(0.035, 2.8, 1.7, 55.7e-6, aperture="disk")
    camera = paper_focus(lens, 12.0)
    assert camera.focus_distance.tolist() == pytest.approx([2.4, 9.6])
    assert camera.f_number.tolist() == [2.8, 2.8] and camera.aperture == "disk"
    assert camera.pixel_pitch.tolist() == pytest.approx([55.7e-6] * 2)


def test_synthesized_focus_renders_with_another_camera(tmp_path):
    write_scene(tmp_path / "s")
    data = RGBD(tmp_path)
    camera = CameraSettings(0.05, 1.4, [2.0, 6.0, 9.0], 1.8e-4)
    sample = SynthesizedFocus(data, camera, keep=True)[0]
    assert sample["camera"].n_shots == 3 and sample["id"] == "s"
    expected = render_focal_stack(sample["image"][None], sample["depth"][None],
                                  camera.to(torch.float32))[0].clamp(0, 1)
    assert torch.allclose(sample["focused"], expected, atol=1e-6)
    assert data[0]["focused"].shape[0] == 2  # the data set itself is left as it is


def test_registry_and_focus_modes(tmp_path):
    write_scene(tmp_path / "s")
    assert isinstance(build_dataset("rgbd", tmp_path, split="all", size=None), RGBD)
    assert focus_of("rgbd") == "synthesized" and focus_of("dslr") == "real"
    with pytest.raises(ValueError, match="the rgbd dataset has no real focused photos"):
        build_dataset("rgbd", tmp_path, split="all", focus="real")


def test_train_and_evaluate_commands_refuse_a_focus_the_data_lacks(tmp_path, capsys):
    from defocus.cli import main

    write_scene(tmp_path / "data" / "s")
    assert main(["train", "--data", "rgbd", "--root", str(tmp_path / "data"), "--focus", "real",
                 "--out", str(tmp_path / "run")]) == 2
    assert "--focus real: the rgbd dataset has no real focused photos" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "x.pt"), "--data", "ddff12", "--root",
                 str(tmp_path), "--focus", "synthesized"]) == 2
    assert "--data ddff12 has real focal stacks only" in capsys.readouterr().err


@pytest.mark.slow
def test_train_on_an_rgbd_folder_then_evaluate(tmp_path, capsys):
    """`defocus train --data rgbd` trains on your captures; `defocus evaluate` scores the
    checkpoint on them, rendered with the camera it was trained for."""
    from defocus.cli import main

    root = tmp_path / "data"
    for i, name in enumerate(("a", "b", "c")):
        write_scene(root / name, h=16, w=20, seed=i, depth="png" if i else "npy")
    (root / "train.txt").write_text("a\nb\n")
    (root / "test.txt").write_text("c\n")
    out = tmp_path / "run"
    assert main(["train", "--data", "rgbd", "--root", str(root), "--out", str(out), "--set",
                 "steps=1", "batch_size=2", "width=4", "progress=false", "device=cpu",
                 "depth_min=0.5", "depth_max=10"]) == 0
    config = (out / "config.yaml").read_text()
    assert "n_focus: 2" in config
    metrics = tmp_path / "m.json"
    assert main(["evaluate", str(out / "checkpoints" / "last.pt"), "--data", "rgbd", "--root",
                 str(root), "--json", str(metrics)]) == 0
    printed = capsys.readouterr().out
    assert "rendered with the camera the checkpoint was trained for: f/2.8 focused at 2, 8 m" \
        in printed
    assert 0 < json.loads(metrics.read_text())["abs_rel"] < 10


def test_the_first_scenes_keep_their_augmentation_and_take_their_own_hints(tmp_path):
    """`limit` (a recipe's `max_train`) gives a view of the first scenes: cropped as the whole
    set is, and the depth hints are found for those scenes only."""
    from datasets import JointAugment
    from defocus.app.experiment import limit
    from models.training import TrainConfig
    from models.training.hints import attach_hints

    for name in ("a", "b", "c"):
        write_scene(tmp_path / name, h=24, w=32, seed=ord(name))
    whole = RGBD(tmp_path)
    crops = limit(whole, 2).with_augment(JointAugment(crop_size=(8, 8)))
    assert crops.ids == ["a", "b"] and whole.ids == ["a", "b", "c"]
    assert tuple(crops[1]["image"].shape) == (3, 8, 8)
    assert limit(whole, None) is whole and limit(whole, 5) is whole and len(whole.first(0)) == 0
    hinted = attach_hints(crops, TrainConfig(hint_weight=1.0), progress=False, max_pixels=600)
    assert len(hinted.hints) == 2 and tuple(hinted.hints[0].shape) == (1, 24, 32)
    torch.testing.assert_close(hinted.first(1).hints, hinted.hints[:1])
