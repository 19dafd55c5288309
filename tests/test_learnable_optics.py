"""Learned optics: `optics.LearnableCamera` / `LearnableMask` (gradients, constraints, start at
the fixed camera) and training with them (`TrainConfig.learn_optics`, `defocus train
--learn-optics`): the rendering in the forward, checkpoints, run folder and evaluation."""

import csv
import json
import math

import pytest
import torch

from optics import CameraSettings, LearnableCamera, LearnableMask, Mask, disk_mask
from optics.learnable import OPEN

FIXED = CameraSettings(0.05, 2.8, [2.0, 6.0], 1.8e-4)
RANGE = (1.0, 10.0)


def _scene(dtype=torch.float64, size=6, seed=0):
    gen = torch.Generator().manual_seed(seed)
    image = torch.rand(1, 2, size, size, generator=gen, dtype=dtype)
    depth = 1.2 + 7 * torch.rand(1, 1, size, size, generator=gen, dtype=dtype)
    return image, depth


def _perturbed(camera, scale=0.3, seed=1):
    """Move every parameter off its start (a gradcheck at a generic point)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in camera.parameters():
            p.add_(scale * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    return camera


# -- gradients -------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["focus_logits", "f_number_logits", "mask.logits"])
@pytest.mark.parametrize("mode", ["scatter", "gather"])
def test_render_gradcheck_each_learned_parameter(name, mode):
    """float64 gradcheck of the focal stack in each learned parameter (focus distances,
    f-numbers, mask values), through the renderer's PSF layer."""
    settings = CameraSettings(0.05, 2.0, [1.5, 4.0], 6e-5)  # CoCs of a few pixels
    camera = _perturbed(LearnableCamera(settings, RANGE, mask_size=4))
    image, depth = _scene()
    param = dict(camera.named_parameters())[name].detach().clone().requires_grad_(True)

    def render(value):
        return torch.func.functional_call(camera, {name: value}, (image, depth),
                                          {"mode": mode})

    assert render(param).abs().sum() > 0
    assert torch.autograd.gradcheck(render, (param,), eps=1e-6, atol=1e-6, fast_mode=True)


def test_learned_values_gradcheck_against_the_physical_values():
    """The focus distances and f-numbers are smooth functions of their parameters (float64)."""
    camera = _perturbed(LearnableCamera(FIXED, RANGE, learn=("focus", "f-number")))
    for name, value in (("focus_logits", lambda c: c.focus_distance()),
                        ("f_number_logits", lambda c: c.f_number())):
        param = dict(camera.named_parameters())[name].detach().clone().requires_grad_(True)

        def f(x, name=name, value=value):
            with torch.nn.utils.stateless._reparametrize_module(camera, {name: x}):
                return value(camera)

        assert torch.autograd.gradcheck(f, (param,), eps=1e-7, atol=1e-7)


def test_mask_gradient_is_that_of_the_exactly_constrained_mask():
    """`values()`' gradient (one Newton step on a cached offset) equals the derivative of the
    mask whose offset is solved exactly at every point (central differences, float64)."""
    mask = LearnableMask(disk_mask(4))
    _perturbed(mask, scale=1.0)
    logits = mask.logits.detach().clone()

    def exact(l):  # noqa: E741 - solve sum(sigmoid(l + b)) = light by bisection, no gradients
        low, high = -60.0, 60.0
        for _ in range(200):
            mid = (low + high) / 2
            low, high = (low, mid) if torch.sigmoid(l + mid).sum() > mask.light else (mid, high)
        return torch.sigmoid(l + (low + high) / 2)

    values = mask.values().reshape(-1)
    jacobian = torch.stack([torch.autograd.grad(v, mask.logits, retain_graph=True)[0].reshape(-1)
                            for v in values])  # (output, logit)
    step = 1e-6
    for i in range(logits.numel()):
        d = torch.zeros_like(logits).reshape(-1)
        d[i] = step
        d = d.reshape(logits.shape)
        numeric = (exact(logits + d) - exact(logits - d)) / (2 * step)
        torch.testing.assert_close(jacobian[:, i].reshape(4, 4), numeric,
                                   atol=1e-7, rtol=1e-5)


# -- constraints and start -------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1, 2])
def test_constraints_hold_after_huge_steps(seed):
    camera = LearnableCamera(CameraSettings(0.05, [2.8, 4.0, 8.0], [6.0, 2.0, 3.0], 1.8e-4),
                             RANGE, f_number_range=(1.4, 22.0), mask_size=8)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in camera.parameters():
            p.add_(200 * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    focus, numbers = camera.focus_distance(), camera.f_number()
    assert torch.isfinite(focus).all() and torch.isfinite(numbers).all()
    assert ((focus >= RANGE[0]) & (focus <= RANGE[1])).all()
    # the shots keep their order: shot 1 nearest, then shot 2, then shot 0 (as 2 < 3 < 6 m)
    assert focus[1] <= focus[2] <= focus[0]
    assert ((numbers >= 1.4) & (numbers <= 22.0)).all()
    values = camera.mask.values()
    assert ((values >= 0) & (values <= 1)).all()
    torch.testing.assert_close(values.sum(), camera.mask.light, rtol=1e-9, atol=1e-9)
    camera.settings().check()  # a valid camera


def test_constraints_hold_under_an_optimizer_that_pushes_out():
    """Adam with a large step pushing every value out of its limits: still inside."""
    camera = LearnableCamera(FIXED, RANGE)
    optimizer = torch.optim.Adam(camera.parameters(), lr=5.0)
    for _ in range(20):
        optimizer.zero_grad()
        mask = camera.mask.values()
        (-camera.focus_distance().sum() - camera.f_number().sum() - (mask ** 2).sum()
         - mask[:4].sum()).backward()
        optimizer.step()
        focus = camera.focus_distance().detach()
        assert (focus >= 1.0).all() and (focus <= 10.0).all() and focus[0] <= focus[1]
        assert (camera.f_number() <= 22.0).all()
        values = camera.mask.values().detach()
        assert ((values >= 0) & (values <= 1)).all()
        torch.testing.assert_close(values.sum(), camera.mask.light, rtol=1e-9, atol=1e-9)


def test_starts_at_the_fixed_camera_and_the_open_disk():
    fixed = CameraSettings(0.05, [2.8, 4.0], [6.0, 2.0], 1.8e-4, aperture="disk")
    camera = LearnableCamera(fixed, RANGE)
    start = camera.settings()
    for name in ("focal_length", "f_number", "focus_distance", "pixel_pitch"):
        torch.testing.assert_close(getattr(start, name), getattr(fixed, name), rtol=1e-12, atol=0)
    expected = (1 - OPEN) + (2 * OPEN - 1) * disk_mask(16)
    torch.testing.assert_close(camera.mask.values(), expected, rtol=1e-9, atol=1e-9)
    # not learned: the fixed values exactly, and the fixed PSF
    fixed_only = LearnableCamera(fixed, RANGE, learn=("mask",))
    assert torch.equal(fixed_only.focus_distance(), fixed.focus_distance)
    assert torch.equal(fixed_only.f_number(), fixed.f_number)
    assert type(LearnableCamera(fixed, RANGE, learn=("focus",)).aperture).__name__ == "Disk"


def test_learned_mask_renders_as_the_fixed_mask_of_its_values():
    """The learned mask's PSF is `Mask`'s of its current values (the frozen copy evaluate uses)."""
    mask = _perturbed(LearnableMask(disk_mask(8)), scale=2.0)
    for coc in (0.5, 3.0, 7.5):
        torch.testing.assert_close(mask.kernel(coc).detach(), mask.frozen().kernel(coc))
    # the open disk: close to the disk aperture's kernel at a large CoC
    disk = Mask(disk_mask(64)).kernel(20.0)
    assert (LearnableMask().kernel(20.0).detach() - disk).abs().sum() < 0.1


@pytest.mark.parametrize("kwargs, words", [
    ({"learn": ("zoom",)}, "learn must name"),
    ({"depth_range": (3.0, 10.0)}, "strictly inside depth_range"),
    ({"settings": CameraSettings(0.05, 2.8, [2.0, 2.0], 1.8e-4)}, "all different"),
    ({"f_number_range": (4.0, 22.0)}, "strictly inside f_number_range"),
    ({"f_number_range": (8.0, 4.0)}, "N_min < N_max"),
    ({"mask_size": 1}, "mask_size"),
])
def test_refused_at_the_door(kwargs, words):
    args = {"settings": FIXED, "depth_range": RANGE, **kwargs}
    with pytest.raises(ValueError, match=words):
        LearnableCamera(**args)


def test_record_is_json():
    import json

    record = LearnableCamera(FIXED, RANGE, mask_size=4).record()
    assert json.loads(json.dumps(record))["learned"] == ["focus", "f-number", "mask"]
    assert len(record["mask"]) == 4 and record["focus_distance"] == pytest.approx([2.0, 6.0])


# -- training ----------------------------------------------------------------------------------

def _config(tmp_path, **changes):
    from models.training import TrainConfig

    fields = {"steps": 3, "batch_size": 2, "width": 4, "progress": False, "workers": 0,
              "out_dir": tmp_path / "run", "checkpoint_minutes": 0.0,
              "learn_optics": "focus,f-number,mask", "optics_lr": 0.05, "mask_size": 8}
    return TrainConfig(**{**fields, **changes})


def test_config_learn_optics():
    from models.training import TrainConfig

    assert TrainConfig().learn_optics == ""
    assert TrainConfig(learn_optics="mask,focus").learn_optics == "focus,mask"
    assert TrainConfig.load(None, ["learn_optics=[f-number, mask]"]).learn_optics == \
        "f-number,mask"
    for bad in ("lens", "focus,focus", ["focus", 3]):
        with pytest.raises(ValueError, match="learn_optics must name"):
            TrainConfig(learn_optics=bad)
    with pytest.raises(ValueError, match="f_number_min < f_number_max"):
        TrainConfig(f_number_min=8.0, f_number_max=4.0)
    with pytest.raises(ValueError, match="set compile=false"):
        TrainConfig(learn_optics="focus", compile=True)


def test_fixed_camera_path_is_unchanged(tmp_path, scenes):
    """learn_optics empty: no camera, one param group, the batch passed on as it is, the log's
    and checkpoint's keys as before, and two runs bit-identical."""
    from models.checkpoints import load_checkpoint
    from models.training import Trainer

    trainer = Trainer(_config(tmp_path, learn_optics=""), scenes)
    assert trainer.camera is None and len(trainer.optimizer.param_groups) == 1
    batch = {"image": torch.rand(1, 3, 4, 4)}
    assert trainer.forward.rendered(batch) is batch
    history = trainer.fit()
    again = Trainer(_config(tmp_path, learn_optics="", out_dir=tmp_path / "again"), scenes).fit()
    assert [row["loss"] for row in history] == [row["loss"] for row in again]
    with open(tmp_path / "run" / "train_log.csv") as handle:
        header = next(csv.reader(handle))
    assert not any(k.startswith(("focus_distance", "f_number", "mask")) for k in header)
    state = load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")
    assert not {"optics", "camera_mask"} & set(state)
    assert not (tmp_path / "run" / "camera.json").exists()


def test_first_render_reproduces_the_data(tmp_path, scenes):
    """At the start the learned camera renders the procedural scenes' own focused images."""
    from models.training import Trainer
    from models.training.learned_camera import render_batch
    from optics import collate

    cfg = _config(tmp_path, learn_optics="focus,f-number", read_noise=0.0, shot_noise=0.0)
    trainer = Trainer(cfg, scenes)
    batch = collate([scenes[0], scenes[1]])
    with torch.no_grad():
        rendered = render_batch(trainer.camera, batch, trainer.config)
    torch.testing.assert_close(rendered["focused"], batch["focused"], atol=1e-5, rtol=0)
    torch.testing.assert_close(rendered["camera"].focus_distance, batch["camera"].focus_distance)


def test_rendered_noise_follows_the_light(tmp_path, scenes):
    """The focused images rendered through a learned camera carry the sensor's noise at the
    light each shot gathers: at the start the `CaptureNoise` model's, one stop down (f-number
    x sqrt 2) twice the read noise; scoring draws the same noise every time."""
    from models.training import Trainer
    from models.training.learned_camera import render_batch, rendered_samples
    from optics import collate, noise_std

    quiet = Trainer(_config(tmp_path, learn_optics="f-number", read_noise=0.0, shot_noise=0.0),
                    scenes)
    noisy = Trainer(_config(tmp_path, learn_optics="f-number", out_dir=tmp_path / "noisy"),
                    scenes)
    batch = collate([scenes[i] for i in range(4)])
    with torch.no_grad():
        for light in (1.0, 0.5):
            for trainer in (quiet, noisy):  # the same f-numbers: light x the start's
                logits = torch.logit(torch.log(trainer.camera.fixed_f_number / light**0.5)
                                     / math.log(22.0))
                trainer.camera.f_number_logits.copy_(logits)
            clean = render_batch(quiet.camera, batch, quiet.config)["focused"]
            drawn = render_batch(noisy.camera, batch, noisy.config,
                                 torch.Generator().manual_seed(0))["focused"]
            torch.testing.assert_close(noisy.camera.light(), torch.full((2,), light,
                                       dtype=torch.float64))
            ratio = ((drawn - clean) / noise_std(clean, 0.004, 0.0004, light)).std()
            assert 0.97 < float(ratio) < 1.03, (light, float(ratio))
    again = [list(rendered_samples(noisy.camera, [scenes[0], scenes[1]], noisy.config)) for _ in range(2)]
    assert all(torch.equal(a["focused"], b["focused"]) for a, b in zip(*again, strict=True))


def test_optics_lr_zero_renders_the_fixed_camera(tmp_path, scenes):
    """`optics_lr=0`: every batch rendered through the starting camera, which stays as it is:
    the baseline of a learned camera under the same noise."""
    from models.training import Trainer

    trainer = Trainer(_config(tmp_path, optics_lr=0.0), scenes)
    start = trainer.camera.record()
    trainer.fit()
    assert trainer.camera.record() == start


def test_contrast_objective_moves_the_camera_by_its_log_ratio_and_not_the_network(tmp_path,
                                                                                 scenes):
    """`optics_objective="contrast"`: the loss's value and the network's gradient are those of
    the plain loss; the camera's gradient is the loss times the gradient of
    log(loss) - log(the loss at the network's depth x and / 1.25), computed here apart."""
    from models.training import Trainer
    from optics import collate

    batch = collate([scenes[0], scenes[1]])
    grads, values = {}, {}
    for objective in ("loss", "contrast"):
        trainer = Trainer(_config(tmp_path, optics_objective=objective, read_noise=0.0,
                                  shot_noise=0.0, out_dir=tmp_path / objective), scenes)
        depth, terms = trainer.forward(batch)
        terms["loss"].backward()
        grads[objective] = [p.grad.clone() for p in (*trainer.model.parameters(),
                                                     *trainer.camera.parameters())]
        values[objective] = float(terms["loss"].detach())
        assert ("contrast" in terms) == (objective == "contrast")  # logged with the run
    assert values["contrast"] == pytest.approx(values["loss"], rel=1e-6)
    n = len(list(trainer.model.parameters()))
    for a, b in zip(grads["loss"][:n], grads["contrast"][:n], strict=True):
        torch.testing.assert_close(a, b)
    rendered = trainer.forward.rendered(batch)
    depth = trainer.forward.network_depth(rendered)
    loss = trainer.loss_fn(depth, rendered["image"], rendered["focused"], rendered["camera"])
    reference = sum(trainer.loss_fn(depth.detach() * f, rendered["image"], rendered["focused"],
                                    rendered["camera"])["loss"] for f in (1.25, 0.8)) / 2
    expected = torch.autograd.grad(loss["loss"].detach() * (loss["loss"].log() - reference.log()),
                                   list(trainer.camera.parameters()))
    for a, b in zip(grads["contrast"][n:], expected, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-7)
    assert not all(torch.allclose(a, b) for a, b in zip(grads["contrast"][n:], grads["loss"][n:],
                                                        strict=True))
    with pytest.raises(ValueError, match="optics_objective must be one of"):
        _config(tmp_path, optics_objective="identifiability")


@pytest.mark.slow
def test_training_learns_the_camera(tmp_path, scenes):
    """A few steps on tiny procedural scenes: every learned value moves, the loss is finite,
    and the camera is in the checkpoint, the log and the run folder."""
    from models.checkpoints import load_checkpoint
    from models.training import Trainer
    from optics import CameraSettings as Settings

    trainer = Trainer(_config(tmp_path), scenes)
    start = trainer.camera.record()
    history = trainer.fit()
    end = trainer.camera.record()
    assert all(math.isfinite(row["loss"]) for row in history)
    for name in ("focus_distance", "f_number", "mask"):
        assert end[name] != start[name], name
    assert len(trainer.optimizer.param_groups) == 2
    assert trainer.optimizer.param_groups[1]["initial_lr"] == 0.05  # optics_lr
    run = tmp_path / "run"
    for name in ("camera.json", "mask.png", "optics.png"):
        assert (run / name).is_file(), name
    settings, extra = Settings.read_json(run / "camera.json")
    assert settings.focus_distance.tolist() == pytest.approx(end["focus_distance"])
    assert extra["learned"] == ["focus", "f-number", "mask"] and extra["step"] == 3
    with open(run / "train_log.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert float(rows[-1]["focus_distance_2"]) == pytest.approx(end["focus_distance"][1])
    assert {"f_number_1", "mask_open", "mask_asymmetry"} <= set(rows[0])
    state = load_checkpoint(run / "checkpoints" / "last.pt")  # weights_only=True
    assert state["camera"]["focus_distance"] == pytest.approx(end["focus_distance"])
    torch.testing.assert_close(state["camera_mask"].double(), torch.tensor(end["mask"]).double())
    assert "focus_logits" in state["optics"]


@pytest.mark.slow
def test_resume_restores_the_learned_camera(tmp_path, scenes):
    """2 + 2 steps resumed from the checkpoint = 4 steps at once, optics included."""
    from models.training import Trainer

    whole = Trainer(_config(tmp_path, steps=4, out_dir=tmp_path / "whole"), scenes)
    whole.fit()
    first = Trainer(_config(tmp_path, steps=4, out_dir=tmp_path / "parts"), scenes)
    first.fit(until=2)
    first.save_checkpoint()
    resumed = Trainer(_config(tmp_path, steps=4, out_dir=tmp_path / "parts"), scenes)
    assert resumed.step == 2
    resumed.fit()
    for a, b in zip(whole.camera.state_dict().values(), resumed.camera.state_dict().values(),
                    strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    for data in (scenes, ()):  # without data: the camera it started from is in the checkpoint
        loaded = Trainer.from_checkpoint(tmp_path / "parts" / "checkpoints" / "last.pt", data)
        assert loaded.camera.record() == resumed.camera.record()


@pytest.mark.slow
def test_evaluate_renders_with_the_learned_camera(tmp_path, scenes):
    from defocus.app.evaluate import checkpoint_focus
    from models.training import Trainer

    trainer = Trainer(_config(tmp_path, steps=2), scenes)
    trainer.fit()
    checkpoint = tmp_path / "run" / "checkpoints" / "last.pt"
    samples, line, warning = checkpoint_focus(scenes, checkpoint, trainer.config.aperture)
    assert warning is None and "learned 8x8 aperture mask" in line
    with torch.no_grad():
        expected = trainer.camera.render(scenes[0]["image"][None].double(),
                                         scenes[0]["depth"][None].double())[0]
    torch.testing.assert_close(samples[0]["focused"].double(), expected.clamp(0, 1),
                               atol=1e-5, rtol=0)
    # with the run's sensor noise: the draws and the light of the scoring during training
    from models.training.learned_camera import rendered_samples

    noise = (trainer.config.read_noise, trainer.config.shot_noise)
    noisy, _, _ = checkpoint_focus(scenes, checkpoint, trainer.config.aperture, noise=noise)
    trained = next(iter(rendered_samples(trainer.camera, [scenes[0]], trainer.config)))
    assert float(trainer.camera.light().detach().min()) != 1.0  # the learned f-numbers moved
    torch.testing.assert_close(noisy[0]["focused"], trained["focused"].clamp(0, 1),
                               atol=1e-5, rtol=0)
    assert not torch.allclose(noisy[0]["focused"], samples[0]["focused"], atol=1e-3)


def test_cli_refuses_real_focused_photos(tmp_path, capsys):
    from defocus.cli import main

    root = tmp_path / "dfd_indoor"
    root.mkdir()
    assert main(["train", "--learn-optics", "focus", "--data", "dslr", "--root",
                 str(root), "--out", str(tmp_path / "run")]) == 2
    error = capsys.readouterr().err
    assert "real photos" in error and "--focus synthesized" in error
    assert len(error.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()
    assert main(["train", "--learn-optics", "focus", "--set", "learn_optics=mask"]) == 2
    assert "give only the option" in capsys.readouterr().err


def test_depth_supervised_twin_learns_the_camera_through_its_input(tmp_path, scenes):
    """With depth labels the network's input (focused images and settings) comes through the
    learned camera, so the optics get gradients from the depth error alone."""
    from models.training import Trainer

    trainer = Trainer(_config(tmp_path, supervision="depth", learn_optics="focus,f-number",
                              steps=2), scenes)
    start = trainer.camera.record()
    trainer.fit()
    assert trainer.camera.record()["focus_distance"] != start["focus_distance"]
    assert trainer.camera.record()["f_number"] != start["f_number"]


def test_a_learned_checkpoint_loads_as_a_depth_model(tmp_path, scenes):
    """`defocus predict`'s loader reads the learned camera as the camera it was trained for."""
    from models.loading import load_depth_model
    from models.training import Trainer

    trainer = Trainer(_config(tmp_path, steps=1), scenes)
    trainer.fit()
    model = load_depth_model(tmp_path / "run" / "checkpoints" / "last.pt")
    assert model.camera["focus_distance"] == pytest.approx(
        trainer.camera.record()["focus_distance"])


# -- a camera as built: tolerances --------------------------------------------------------------

def test_tolerance_moves_focus_and_f_number_by_their_closed_forms():
    from optics import CameraTolerance

    built = CameraTolerance(focus=-0.02, f_stops=-1 / 3).settings(FIXED)
    torch.testing.assert_close(built.focus_distance, FIXED.focus_distance * 0.98)
    # a third of a stop: the aperture's area (1 / N^2) times 2^(1/3)
    torch.testing.assert_close((FIXED.f_number / built.f_number) ** 2,
                               torch.full_like(FIXED.f_number, 2 ** (1 / 3)))
    assert built.focal_length.equal(FIXED.focal_length) and built.aperture == FIXED.aperture
    assert CameraTolerance().settings(FIXED).focus_distance.equal(FIXED.focus_distance)
    assert CameraTolerance().exact and not CameraTolerance(f_stops=0.1).exact


def test_tolerance_mask_noise_is_seeded_and_physical():
    from optics import CameraTolerance

    mask = Mask(disk_mask(8))
    noisy = CameraTolerance(mask_noise=0.1, seed=3).mask(mask)
    again = CameraTolerance(mask_noise=0.1, seed=3).mask(mask)
    other = CameraTolerance(mask_noise=0.1, seed=4).mask(mask)
    assert noisy.image.equal(again.image) and not noisy.image.equal(other.image)
    assert float(noisy.image.min()) >= 0 and float(noisy.image.max()) <= float(mask.image.max())
    spread = float((noisy.image - mask.image).std())
    assert 0.05 < spread < 0.12  # about the noise asked for, less what the clipping takes
    assert CameraTolerance(focus=0.02).mask(mask) is mask
    assert CameraTolerance(mask_noise=0.1).mask(None) is None


@pytest.mark.parametrize("kwargs", [{"focus": -1.0}, {"mask_noise": -0.1},
                                    {"f_stops": float("nan")}, {"focus": "2 %"}])
def test_tolerance_refused_at_the_door(kwargs):
    from optics import CameraTolerance

    with pytest.raises(ValueError, match=next(iter(kwargs))):
        CameraTolerance(**kwargs)


def test_robustness_scores_the_design_and_each_tolerance(tmp_path, scenes, capsys):
    """`defocus evaluate --robustness`: the design's row is the plain evaluation's, each
    tolerance renders with the camera as built (a focus 2 % off changes the focused images),
    the mask's row only for a learned mask; refusals name the options."""
    from defocus.app.evaluate import (
        EvaluateRequest,
        checkpoint_focus,
        evaluate_checkpoint,
        robustness,
    )
    from defocus.cli import main
    from models.training import Trainer
    from optics import ROBUSTNESS, CameraTolerance

    trainer = Trainer(_config(tmp_path, steps=2), scenes)
    trainer.fit()
    checkpoint = tmp_path / "run" / "checkpoints" / "last.pt"
    test = [scenes[i] for i in range(3)]
    rows = robustness(EvaluateRequest(test, checkpoint, synthesize=True))
    assert list(rows) == [t.describe() for t in ROBUSTNESS]
    plain = evaluate_checkpoint(EvaluateRequest(test, checkpoint, synthesize=True))
    assert rows["as designed"].metrics == plain.metrics
    assert rows["focus +2 %"].metrics["abs_rel"] != plain.metrics["abs_rel"]
    designed, _, _ = checkpoint_focus(test, checkpoint, trainer.config.aperture)
    built, line, _ = checkpoint_focus(test, checkpoint, trainer.config.aperture,
                                      CameraTolerance(focus=0.02))
    assert "as built: focus +2 %" in line
    assert not torch.allclose(designed[0]["focused"], built[0]["focused"])
    fixed = tmp_path / "fixed"
    Trainer(_config(fixed, steps=2, learn_optics="focus"), scenes).fit()
    fixed_rows = robustness(EvaluateRequest(test, fixed / "run" / "checkpoints" / "last.pt",
                                            synthesize=True))
    assert len(fixed_rows) == len(ROBUSTNESS) - 1 and not any("mask" in n for n in fixed_rows)
    for argv, words in ((["--perturb-focus", "-1"], "focus > -1"),
                        (["--perturb-focus", "0.02", "--robustness"], "without --perturb"),
                        (["--perturb-focus", "0.02", "--focus", "real"], "--focus synthesized")):
        assert main(["evaluate", str(checkpoint), "--data", "synthetic", *argv]) == 2
        assert words in capsys.readouterr().err
    table = tmp_path / "robustness.json"
    assert main(["evaluate", str(checkpoint), "--data", "synthetic", "--scenes", "3", "--size",
                 "16", "16", "--robustness", "--json", str(table)]) == 0
    out = capsys.readouterr().out
    assert "as designed: abs rel 1.00x the design's" in out and "f-number -0.33 stop" in out
    assert set(json.loads(table.read_text())) == set(rows)
    # --last N: the last N samples of the split (the examples' held-out scenes)
    scored = {}
    for last in ("3", "1"):
        path = tmp_path / f"last{last}.json"
        assert main(["evaluate", str(checkpoint), "--data", "synthetic", "--scenes", "3",
                     "--size", "16", "16", "--last", last, "--json", str(path)]) == 0
        scored[last] = json.loads(path.read_text())
    assert {k: scored["3"][k] for k in ("abs_rel", "rmse")} == \
        {k: json.loads(table.read_text())["as designed"][k] for k in ("abs_rel", "rmse")}
    assert scored["1"] != scored["3"]
    assert main(["evaluate", str(checkpoint), "--data", "synthetic", "--last", "0"]) == 2
    assert "--last must be >= 1" in capsys.readouterr().err


# -- an oriented aperture: the signed CoC ----------------------------------------------------

CODE = torch.tensor([[1.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.3]])  # no point symmetry


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mask_kernel_of_a_negative_coc_is_the_point_reflection(dtype):
    """A CoC of -c is the mask point-reflected: the kernel of the flipped mask, an independent
    computation (rounding of the bilinear table aside)."""
    mask = Mask(CODE.to(dtype))
    for coc in (3.0, 6.5, 11.0):
        near = mask.kernel(-coc)
        torch.testing.assert_close(near, Mask(CODE.flip(0, 1).to(dtype)).kernel(coc),
                                   atol=1e-6, rtol=0)
        torch.testing.assert_close(near, mask.kernel(coc).flip(-2, -1), atol=1e-6, rtol=0)
        assert (near - mask.kernel(coc)).abs().max() > 0.01  # the code is seen the other way


@pytest.mark.parametrize("aperture", ["code", "disk"])
def test_a_depth_and_its_mirror_blur_alike_only_through_a_symmetric_aperture(aperture):
    """One focus plane, a point at 3 m and at its mirror 1.5 m (the same |CoC|): through an
    oriented code the two images are each other's point reflection and differ; through the
    disk (symmetric, the unsigned CoC) they are the same."""
    from optics import Disk

    psf = Mask(CODE.double()) if aperture == "code" else Disk()
    camera = CameraSettings(0.05, 2.0, [2.0], 20e-6).shot(0, psf)
    point = torch.zeros(1, 1, 25, 25, dtype=torch.float64)
    point[..., 12, 12] = 1.0
    far, near = (camera.render(point, torch.full_like(point, d)) for d in (3.0, 1.5))
    assert float(camera.signed_coc_px(torch.tensor(1.5))) == \
        pytest.approx(-float(camera.signed_coc_px(torch.tensor(3.0))))
    torch.testing.assert_close(near, far.flip(-2, -1), atol=1e-7, rtol=0)
    differ = float((near - far).abs().max())
    assert differ > 0.01 if aperture == "code" else differ < 1e-12


def test_signed_coc_gradcheck_through_a_learned_code():
    """float64 gradcheck of the render in a signed CoC map that crosses zero, through an
    oriented learned code (its values' gradients, with depths on both sides of the focus
    planes: `test_render_gradcheck_each_learned_parameter`)."""
    from optics import render_defocus

    gen = torch.Generator().manual_seed(0)
    mask = _perturbed(LearnableMask(torch.rand(4, 4, generator=gen, dtype=torch.float64)))
    image = torch.rand(1, 2, 6, 6, generator=gen, dtype=torch.float64)
    coc = (6 * torch.rand(1, 1, 6, 6, generator=gen, dtype=torch.float64) - 3)
    assert bool((coc < 0).any() and (coc > 0).any())
    assert torch.autograd.gradcheck(lambda c: render_defocus(image, c, mask),
                                    (coc.requires_grad_(),), eps=1e-6, atol=1e-6)


def test_signed_coc_is_refused_where_the_aperture_is_symmetric():
    from optics import Disk, render_defocus

    image = torch.rand(1, 1, 5, 5)
    with pytest.raises(ValueError, match="coc_px must be finite and >= 0"):
        render_defocus(image, torch.full((1, 1, 5, 5), -2.0), Disk())
    with pytest.raises(ValueError, match="coc_px must be finite .signed"):
        render_defocus(image, torch.full((1, 1, 5, 5), float("nan")), Mask(CODE))
    assert torch.isfinite(render_defocus(image, torch.full((1, 1, 5, 5), -2.0), Mask(CODE))).all()


def test_whole_image_evaluation_reads_through_the_learned_camera(tmp_path, scenes):
    """`models.experiment.evaluate_whole_images` (the examples' tables) scores a network that
    learned its camera on the test scenes rendered through that camera, as `Trainer.evaluate`
    does: the same metrics as the scenes rendered first, and not those of the data's own."""
    from models.experiment import evaluate_whole_images
    from models.training import Trainer
    from models.training.learned_camera import rendered_samples

    trainer = Trainer(_config(tmp_path), scenes)
    _perturbed(trainer.camera, scale=2.0)
    test = [scenes[i] for i in range(3)]
    learned, _ = evaluate_whole_images(trainer, test)
    rendered = list(rendered_samples(trainer.camera, test, trainer.config))
    trainer.camera = None
    assert evaluate_whole_images(trainer, rendered)[0] == learned
    assert evaluate_whole_images(trainer, test)[0]["abs_rel"] != learned["abs_rel"]


def test_mask_start_noise_breaks_the_symmetry_at_the_disks_light(tmp_path, scenes):
    """`mask_start_noise`: the learned mask starts off the open disk, without point symmetry,
    seeded, passing the disk's light; 0 starts at the disk itself."""
    from models.training.learned_camera import build_learned_camera

    record = {"focal_length": [0.05], "f_number": [2.8], "focus_distance": [2.0],
              "pixel_pitch": [1.8e-4]}

    def start(noise, seed=0):
        config = _config(tmp_path, learn_optics="mask", mask_start_noise=noise, seed=seed)
        return build_learned_camera(config, record).mask.values().detach()

    disk, coded = start(0.0), start(1.0)
    torch.testing.assert_close(disk, LearnableMask(disk_mask(8)).values().detach())
    torch.testing.assert_close(coded.sum(), disk.sum())
    assert float((coded - coded.flip(0, 1)).abs().mean()) > 0.05
    assert float((disk - disk.flip(0, 1)).abs().max()) < 1e-6
    assert torch.equal(start(1.0), coded) and not torch.equal(start(1.0, seed=1), coded)
    with pytest.raises(ValueError, match="mask_start_noise"):
        _config(tmp_path, mask_start_noise=-1.0)


def test_train_step_benchmark_compares_the_optics_objectives(tmp_path, capsys, load_script):
    """`benchmarks/train_step.py --learn-optics ... --optics-objective loss,contrast`: one row
    per objective and the contrast objective's cost goal, so that the benchmark does not rot."""
    bench = load_script("benchmarks/train_step.py")
    out = tmp_path / "bench.json"
    code = bench.main(["--dataset", "middlebury", "--root", "builtin", "--workers", "0",
                       "--learn-optics", "focus,f-number", "--optics-objective", "loss,contrast",
                       "--steps", "2", "--warmup", "1", "--repeats", "1", "--crop", "24",
                       "--batch-size", "2", "--no-memory", "--json", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "| 0 | loss |" in printed and "| 0 | contrast |" in printed
    results = json.loads(out.read_text())
    assert [row["objective"] for row in results["rows"]] == ["loss", "contrast"]
    assert any("contrast: s/step <= 1.4x" in goal["goal"] for goal in results["goals"])


def test_a_sweeping_network_reads_the_photos_through_the_learned_mask(tmp_path, scenes,
                                                                       monkeypatch):
    """`sweep_inputs`: in training and in scoring the network's cost channels are rendered
    through the mask being learned (a `Mask` has no spec the settings could carry)."""
    import models.networks
    from models.training import Trainer

    seen = []
    real = models.networks.sweep_channels

    def spy(*args):
        seen.append(args[-1])
        return real(*args)

    monkeypatch.setattr(models.networks, "sweep_channels", spy)
    trainer = Trainer(_config(tmp_path, steps=2, sweep_inputs=4), scenes)
    trainer.fit()
    assert len(seen) >= 2 and all(a is trainer.camera.aperture for a in seen)
    seen.clear()
    assert math.isfinite(trainer.evaluate(scenes)["abs_rel"])
    assert seen and all(a is trainer.camera.aperture for a in seen)


def test_a_sweeping_checkpoint_predicts_through_its_learned_mask(tmp_path, scenes):
    """`load_depth_model` of a checkpoint that learned a mask gives its `TrainedNetwork` that
    mask: a network that reads the sweep renders it through the code it was trained with."""
    from models.loading import load_depth_model
    from models.training import Trainer

    trainer = Trainer(_config(tmp_path, steps=1, sweep_inputs=4), scenes)
    trainer.fit()
    model = load_depth_model(tmp_path / "run" / "checkpoints" / "last.pt")
    torch.testing.assert_close(model.aperture.image.float(),
                               trainer.camera.aperture.values().detach().float())
    sample = scenes[0]
    depth = model(sample["image"][None], sample["focused"][None], sample["camera"], 1.0,
                  10.0)["depth"]
    expected = trainer.predict(sample["image"][None], sample["focused"][None], sample["camera"])
    torch.testing.assert_close(depth, expected)
