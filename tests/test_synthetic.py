"""Synthetic scenes: deterministic, in range, in the sample format, focused images rendered."""

import numpy as np
import pytest
import torch

from datasets.focus import CameraPreset
from datasets.synthetic import SYNTHETIC_PRESET, SyntheticScenes, generate_scene
from optics import CameraSettings, render_focal_stack


def test_deterministic_per_seed_and_index():
    a, b = SyntheticScenes(3, (20, 24), seed=5), SyntheticScenes(3, (20, 24), seed=5)
    for key in ("image", "focused", "depth"):
        torch.testing.assert_close(a[2][key], b[2][key], rtol=0, atol=0)
    c = SyntheticScenes(3, (20, 24), seed=6)
    assert not torch.equal(a[2]["depth"], c[2]["depth"]) or not torch.equal(a[2]["image"],
                                                                              c[2]["image"])
    assert not torch.equal(a[0]["image"], a[1]["image"])


def test_sample_format_and_ranges():
    scenes = SyntheticScenes(4, (16, 20))
    assert len(scenes) == 4
    for sample in scenes:
        assert sample["image"].shape == (3, 16, 20) and sample["image"].dtype == torch.float32
        assert sample["focused"].shape == (2, 3, 16, 20)
        assert sample["depth"].shape == (1, 16, 20) and sample["mask"].dtype == torch.bool
        assert 0 <= float(sample["image"].min()) and float(sample["image"].max()) <= 1
        assert 1.5 <= float(sample["depth"].min()) and float(sample["depth"].max()) <= 6.0
        assert isinstance(sample["camera"], CameraSettings) and sample["camera"].n_shots == 2
        assert sample["dataset"] == "synthetic"
    with pytest.raises(IndexError):
        scenes[4]


def test_focused_images_are_rendered_with_the_preset():
    preset = CameraPreset(0.05, 100e-6, focus_distances=(2.5,), f_numbers=(1.4,))
    scenes = SyntheticScenes(1, (16, 16), preset=preset, depth_range=(1.0, 5.0))
    sample = scenes[0]
    expected = render_focal_stack(sample["image"][None], sample["depth"][None], preset.settings())[0]
    torch.testing.assert_close(sample["focused"], expected.clamp(0, 1))
    assert float(sample["depth"].max()) <= 5.0


def test_layouts_vary():
    """Across seeds the generator produces slanted surfaces and several depth layers."""
    distinct, slanted = [], 0
    for i in range(12):
        _, depth = generate_scene((32, 32), np.random.default_rng(i))
        values = torch.unique(depth.round(decimals=3))
        distinct.append(values.numel())
        slanted += values.numel() > 20
    assert max(distinct) > 20 and slanted >= 2 and min(distinct) >= 1


def test_errors():
    with pytest.raises(ValueError, match="num_scenes"):
        SyntheticScenes(0)
    with pytest.raises(ValueError, match="size"):
        SyntheticScenes(2, (2, 2))
    with pytest.raises(ValueError, match="depth_range"):
        generate_scene((8, 8), np.random.default_rng(0), depth_range=(3.0, 1.0))


def test_default_preset_blur_is_small():
    """The default camera keeps CoCs at or below about 5 pixels over 1.5-6 m (cheap rendering)."""

    camera = SYNTHETIC_PRESET.settings().camera()
    depth = torch.linspace(1.5, 6.0, 50).reshape(1, 1, 1, 50).expand(2, 1, 1, 50)
    assert float(camera.coc_px(depth).max()) < 5.01


@pytest.mark.parametrize(("min_depth", "depth_cap", "message"), [
    (1.0, 0.5, "depth_cap must be a depth > min_depth"),
    (1.0, 1.0, "depth_cap must be a depth > min_depth"),
    (0.1, float("nan"), "depth_cap must be a depth > min_depth"),
    (-0.1, 10.0, "min_depth must be a finite depth >= 0"),
    (float("nan"), 10.0, "min_depth must be a finite depth >= 0"),
    (True, 10.0, "min_depth must be a finite depth >= 0"),
])
def test_camera_preset_refuses_a_depth_range_that_is_not_increasing(min_depth, depth_cap, message):
    with pytest.raises(ValueError, match=message):
        CameraPreset(0.05, 100e-6, focus_distances=(2.5,), min_depth=min_depth,
                     depth_cap=depth_cap)
    assert CameraPreset(0.05, 100e-6, (2.5,), depth_cap=float("inf")).depth_range == (1e-3, float("inf"))
