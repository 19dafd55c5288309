"""Training crops of full-resolution samples, the in-memory sample cache and the default
focal-stack cache folder (`datasets.base`, `datasets.focus`), and tiled whole-image prediction."""

from __future__ import annotations

import os
import tempfile

import pytest
import torch
from test_datasets_fixtures import write_middlebury

from datasets import JointAugment, Middlebury
from datasets.focus import default_cache_dir, resolve_cache_dir


class CountingMiddlebury(Middlebury):
    loads = 0

    def load(self, index):
        type(self).loads += 1
        return super().load(index)


@pytest.fixture
def scene(tmp_path):
    write_middlebury(tmp_path / "mb", h=20, w=30)
    return tmp_path / "mb"


def test_crop_is_taken_after_synthesis(scene):
    whole = Middlebury(scene, memory_cache_mb=16)
    augment = JointAugment(crop_size=(8, 12), hflip=0.0)
    crops = whole.with_augment(augment)
    torch.manual_seed(3)
    crop = crops[0]
    torch.manual_seed(3)
    top, left, h, w = augment.make_params(20, 30)["crop"]
    full = whole[0]
    window = (..., slice(top, top + h), slice(left, left + w))
    for key in ("image", "focused", "depth", "mask"):
        assert torch.equal(crop[key], full[key][window]), key  # same window, blur of the full scene
    assert torch.equal(crop["camera"].pixel_pitch, full["camera"].pixel_pitch)  # pitch unchanged


def test_memory_cache_loads_once_and_hands_out_copies(scene):
    CountingMiddlebury.loads = 0
    whole = CountingMiddlebury(scene, memory_cache_mb=16)
    crops = whole.with_augment(JointAugment(crop_size=(8, 8)))
    first = whole[0]
    first["image"].fill_(0)  # the caller's copy, not the cache's
    for _ in range(3):
        assert crops[0]["image"].shape == (3, 8, 8)
    again = whole[0]
    assert CountingMiddlebury.loads == 1
    assert bool(again["image"].any())


def test_memory_cache_off_and_limits(scene):
    CountingMiddlebury.loads = 0
    plain = CountingMiddlebury(scene)
    plain[0], plain[0]
    assert CountingMiddlebury.loads == 2
    tiny = CountingMiddlebury(scene, memory_cache_mb=1e-3)  # one sample does not fit
    tiny[0], tiny[0]
    assert CountingMiddlebury.loads == 4
    with pytest.raises(ValueError, match="memory_cache_mb must be >= 0 MiB, got -1"):
        Middlebury(scene, memory_cache_mb=-1)
    with pytest.raises(TypeError, match="augment must be a JointAugment"):
        plain.with_augment("crop")


def test_crop_larger_than_the_image_is_refused(scene):
    crops = Middlebury(scene).with_augment(JointAugment(crop_size=(64, 64)))
    with pytest.raises(ValueError, match="larger than the image 20x30"):
        crops[0]


def test_auto_cache_dir_is_the_per_user_folder(scene, tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(tmp_path / "user-cache"))
    assert default_cache_dir() == tmp_path / "user-cache" / "focal_stacks"
    assert resolve_cache_dir(None) is None
    dataset = Middlebury(scene, cache_dir="auto")
    dataset[0]
    assert len(list((tmp_path / "user-cache" / "focal_stacks").glob("*.pt"))) == 1


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anywhere")
def test_auto_cache_dir_unwritable_is_none(tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(locked / "cache"))
    assert default_cache_dir() is None


def test_auto_cache_dir_unwritable_is_none_as_root(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(blocker / "cache"))
    assert default_cache_dir() is None


def test_time_budget_stops_training_and_the_table_says_so(capsys):
    """`TrainConfig.minutes`: `fit` stops when the budget is spent (no probe run), saves a
    checkpoint, and the table names the steps actually run."""
    from models import experiment
    from models.training import TrainConfig

    samples = [{"image": torch.rand(3, 16, 16), "depth": torch.full((1, 16, 16), 2.0),
                "mask": torch.ones(1, 16, 16, dtype=torch.bool)}] * 2
    cfg = TrainConfig(steps=10**6, batch_size=2, input_mode="aif", supervision="depth", width=4,
                      progress=False, out_dir=tempfile.mkdtemp(), device="cpu", minutes=0.02)
    rows = experiment.train_and_evaluate(cfg, samples, samples, report=print)
    out = capsys.readouterr().out
    assert "the time budget of 0.02 min was spent" in out and "budget 0.02 min" in out
    steps = int(out.split("trained ")[1].split(" ")[0])
    assert 1 <= steps < 10**6 and f"ours (small, aif, {steps} steps)" in rows
    assert (cfg.out_dir / "checkpoints" / "last.pt").is_file()


def test_resize_keeps_linear_highlights_and_the_range():
    from datasets.transforms import resize_sample

    image = torch.rand(3, 40, 50) * 0.5
    image[:, 10:20, 10:20] = 3.0  # a linear highlight, above 1
    out = resize_sample({"image": image, "focused": image[None].expand(2, 3, 40, 50)}, (20, 25))
    for key in ("image", "focused"):
        assert float(out[key].max()) == pytest.approx(3.0)  # the old clip to [0, 1] read 1.0
        assert out[key].min() >= image.min()
        assert float(out[key].mean()) == pytest.approx(float(image.mean()), rel=1e-2)
