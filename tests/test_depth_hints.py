"""Depth hints (Watson et al. 2019): a depth found without labels pulls the network's depth
where it renders the focused images better; the photometric error stays the judge."""

import math

import pytest
import torch
from training_helpers import tiny_config

from datasets import JointAugment, Middlebury
from models.losses import DefocusLoss, photometric_error_map, photometric_loss
from models.training import TrainConfig, Trainer
from models.training.hints import label_free_hints
from optics import CameraSettings, render_focal_stack


def _scene(dtype, size=16):
    g = torch.Generator().manual_seed(0)
    image = torch.rand(1, 3, size, size, generator=g).to(dtype)
    depth = (1.5 + 5 * torch.rand(1, 1, size, size, generator=g)).to(dtype)
    camera = CameraSettings(0.05, 2.0, [[2.0, 6.0]], 180e-6).to(dtype)
    return image, depth, camera, render_focal_stack(image, depth, camera)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_error_map_is_the_loss_per_pixel(dtype):
    """The map averaged over pixels and images is the photometric loss; each pixel's value is
    the SSIM and L1 terms of that pixel (computed here without the map)."""
    g = torch.Generator().manual_seed(1)
    a, b = (torch.rand(2, 2, 3, 12, 12, generator=g).to(dtype) for _ in range(2))
    error = photometric_error_map(a, b, 0.6, 5)
    assert error.shape == (2, 2, 1, 12, 12)
    torch.testing.assert_close(error.mean(), photometric_loss(a, b, 0.6, 5))
    import kornia
    ssim = kornia.metrics.ssim(a.flatten(0, 1), b.flatten(0, 1), 5)
    by_hand = (0.6 * ((1 - ssim) / 2).clamp(0, 1) + 0.4 * (a - b).abs().flatten(0, 1)).mean(1)
    torch.testing.assert_close(error.flatten(0, 2), by_hand, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_hint_pulls_only_where_it_renders_better(dtype):
    image, depth, camera, focused = _scene(dtype)
    loss = DefocusLoss(smoothness_weight=0.0, hint_weight=0.5)
    wrong = depth * 1.5
    # the true depth as the hint of a wrong depth: used everywhere it renders better
    terms = loss(wrong, image, focused, camera, depth)
    assert float(terms["hint_share"]) > 0.9
    share = float(terms["hint_share"])
    assert float(terms["hint"]) == pytest.approx(math.log(1.5) * share, rel=1e-5)
    plain = DefocusLoss(smoothness_weight=0.0)(wrong, image, focused, camera)
    assert float(terms["loss"]) == pytest.approx(
        float(plain["loss"]) + 0.5 * float(terms["hint"]), rel=1e-5)
    # a wrong hint of the true depth renders worse everywhere: ignored
    terms = loss(depth, image, focused, camera, wrong)
    assert float(terms["hint_share"]) == 0.0 and float(terms["hint"]) == 0.0
    # no hint, or a weight of 0: the paper's loss, without the hint terms
    assert "hint" not in loss(depth, image, focused, camera)
    assert "hint" not in DefocusLoss()(depth, image, focused, camera, wrong)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_gate_always_pulls_at_every_pixel(dtype):
    """With the gate "always" a hint pulls even where the network's depth renders better: the
    term is the mean log-depth L1 over all pixels, and the photometric terms are the gate's
    own."""
    image, depth, camera, focused = _scene(dtype)
    wrong = depth * 1.5
    gated = DefocusLoss(smoothness_weight=0.0, hint_weight=0.5)(depth, image, focused, camera,
                                                              wrong)
    terms = DefocusLoss(smoothness_weight=0.0, hint_weight=0.5, hint_gate="always")(
        depth, image, focused, camera, wrong)
    assert float(gated["hint"]) == 0.0
    assert float(terms["hint"]) == pytest.approx(math.log(1.5), rel=1e-5)
    assert float(terms["hint_share"]) == 1.0
    assert float(terms["photometric"]) == float(gated["photometric"])
    assert float(terms["loss"]) == pytest.approx(
        float(gated["loss"]) + 0.5 * math.log(1.5), rel=1e-5)


def test_an_unknown_gate_is_refused_where_it_enters():
    with pytest.raises(ValueError, match=r"hint_gate must be one of \('photometric', 'always'\)"):
        DefocusLoss(hint_gate="sometimes")
    with pytest.raises(ValueError, match="hint_gate"):
        TrainConfig(hint_gate="sometimes")


def test_gradcheck_loss_with_a_hint_pulling_always():
    image, depth, camera, _ = _scene(torch.float64, size=5)
    focused = render_focal_stack(image, depth * 0.9, camera)
    loss = DefocusLoss(window_size=3, hint_weight=1.0, hint_gate="always")
    hint = depth * 0.85
    d = depth.clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda x: loss(x, image, focused, camera, hint)["loss"],
                                    (d,), atol=1e-5)


def test_gradcheck_loss_with_a_hint():
    image, depth, camera, _ = _scene(torch.float64, size=5)
    focused = render_focal_stack(image, depth * 0.9, camera)
    loss = DefocusLoss(window_size=3, hint_weight=1.0)
    hint = depth * 0.85
    d = depth.clone().requires_grad_()
    terms = loss(d, image, focused, camera, hint)
    assert 0 < float(terms["hint_share"]) <= 1
    assert torch.autograd.gradcheck(lambda x: loss(x, image, focused, camera, hint)["loss"],
                                    (d,), atol=1e-5)


def test_hints_are_cropped_and_flipped_with_their_sample(tmp_path):
    whole = Middlebury(None, size=(40, 60))
    depth = whole[0]["depth"]
    crops = whole.with_hints([depth * 2]).with_augment(JointAugment(crop_size=(16, 24),
                                                                    hflip=0.5))
    for seed in range(4):
        torch.manual_seed(seed)
        sample = crops[0]
        torch.testing.assert_close(sample["hint"], sample["depth"] * 2)
    with pytest.raises(ValueError, match=r"len\(hints\) must be 1 \(one hint per sample\), got 2"):
        whole.with_hints([depth, depth])
    with pytest.raises(ValueError, match="hints must be finite depths > 0, got 'a NaN"):
        whole.with_hints([depth * float("nan")])
    with pytest.raises(ValueError, match="hint has shape .1, 4, 4., expected .1, 40, 60."):
        whole.with_hints([torch.ones(1, 4, 4)])[0]


def test_label_free_hints_find_the_depth_of_rendered_scenes():
    """The hints of rendered scenes are close to their depth (no label read: the depth is
    removed before they are found)."""
    whole = Middlebury(None, size=(60, 90))
    sample = {k: v for k, v in whole[0].items() if k not in ("depth", "mask")}
    (hint,) = label_free_hints([sample], (1.0, 10.0), progress=False, max_pixels=6000)
    truth, mask = whole[0]["depth"], whole[0]["mask"]
    assert float(((hint - truth).abs() / truth)[mask].median()) < 0.1
    # the method's options reach it
    with pytest.raises(ValueError, match="n_candidates must be >= 3, got 2"):
        label_free_hints([sample], (1.0, 10.0), progress=False, max_pixels=6000,
                         options={"n_candidates": 2})


def test_config_and_trainer_refusals(tmp_path, scenes):
    with pytest.raises(ValueError, match="hint_weight must be a finite number >= 0"):
        TrainConfig(hint_weight=-1)
    with pytest.raises(ValueError, match="hint_weight=1.0 with learn_optics='focus'"):
        TrainConfig(hint_weight=1, learn_optics="focus")
    with pytest.raises(ValueError, match=r"has no \['hint'\].*hint_weight=1.0 .*attach_hints"):
        Trainer(tiny_config(tmp_path / "run", hint_weight=1), scenes)


def test_training_with_hints_logs_the_hint_terms(tmp_path, scenes):
    hinted = [{**scenes[i], "hint": scenes[i]["depth"] * 1.1} for i in range(len(scenes))]
    cfg = tiny_config(tmp_path / "run", hint_weight=1)
    history = Trainer(cfg, hinted).fit()
    assert all(0 <= row["hint_share"] <= 1 and row["hint"] >= 0 for row in history)
    header = (cfg.out_dir / "train_log.csv").read_text().splitlines()[0]
    assert "hint,hint_share" in header
    # the config's gate reaches the loss: "always" pulls at every pixel
    always = Trainer(tiny_config(tmp_path / "always", hint_weight=1, hint_gate="always"), hinted)
    assert always.loss_fn.hint_gate == "always"
    assert all(row["hint_share"] == 1.0 for row in always.fit())
    # the depth-supervised twin reads no hint
    twin = Trainer(tiny_config(tmp_path / "twin", hint_weight=1, supervision="depth"), scenes)
    assert "hint" not in twin.fit()[0]


def test_attach_hints_to_fixed_samples_only(scenes):
    """Procedural scenes (the same at every read) get their hints as they are; a dataset that
    crops at random by itself, or one without a length, is refused."""
    from torch.utils.data import IterableDataset

    from models.training.hints import HintedSamples, attach_hints

    cfg = TrainConfig(hint_weight=1.0, depth_min=1.5, depth_max=6.0)
    subset = [scenes[i] for i in range(2)]
    hinted = attach_hints(subset, cfg, progress=False, max_pixels=4000)
    assert isinstance(hinted, HintedSamples) and len(hinted) == 2
    assert hinted[1]["hint"].shape == scenes[1]["depth"].shape
    assert hinted[1]["image"] is scenes[1]["image"]
    with pytest.raises(ValueError, match="one hint per sample: 2 samples, got 1 hints"):
        attach_hints(subset, cfg, progress=False, source=subset[:1], max_pixels=4000)

    class Stream(IterableDataset):
        def __iter__(self):
            yield scenes[0]

    class Cropping(list):
        augment = JointAugment(crop_size=(8, 8))

    for refused in (Stream(), Cropping(subset)):
        with pytest.raises(ValueError, match="needs a dataset that holds the same samples"):
            attach_hints(refused, cfg)
