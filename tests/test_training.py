"""Trainer: config, files, exact resume, evaluation, DDP with torchrun, and learning."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from training_helpers import tiny_config as _tiny

from datasets.synthetic import SyntheticScenes
from models.loading import load_model
from models.metrics import METRIC_NAMES, best_constant_depth, depth_metrics
from models.training import TrainConfig, Trainer

ROOT = Path(__file__).resolve().parents[1]






def test_config_yaml_and_overrides(tmp_path):
    path = tmp_path / "cfg.yaml"
    path.write_text("steps: 12\nlr: 5.0e-4\ninput_mode: aif\nout_dir: somewhere\n")
    cfg = TrainConfig.from_yaml(path)
    assert (cfg.steps, cfg.lr, cfg.input_mode, cfg.out_dir) == (12, 5e-4, "aif", Path("somewhere"))
    cfg2 = cfg.override(["steps=3", "flip=false", "depth_max=8"])
    assert (cfg2.steps, cfg2.flip, cfg2.depth_max, cfg2.lr) == (3, False, 8.0, 5e-4)
    cfg2.to_yaml(tmp_path / "again.yaml")
    assert TrainConfig.from_yaml(tmp_path / "again.yaml") == cfg2
    with pytest.raises(ValueError, match="unknown config keys"):
        cfg.override(["stepz=3"])
    with pytest.raises(ValueError, match="key=value"):
        cfg.override(["steps"])
    with pytest.raises(ValueError, match="input_mode"):
        cfg.override(["input_mode=stereo"])
    with pytest.raises(ValueError, match="steps must be of type int"):
        cfg.override(["steps=abc"])


def test_fit_writes_logs_checkpoints_figures(tmp_path, scenes):
    cfg = _tiny(tmp_path / "run", checkpoint_every=2)
    trainer = Trainer(cfg, scenes, val_set=[scenes[0]])
    history = trainer.fit()
    assert [row["step"] for row in history] == [1, 2, 3, 4]
    assert all(row["loss"] > 0 for row in history)
    lines = (cfg.out_dir / "train_log.csv").read_text().splitlines()
    assert lines[0].startswith("step,loss,photometric,sharpness,smoothness,lr") and len(lines) == 5
    assert (cfg.out_dir / "val_log.csv").exists()
    assert {p.name for p in (cfg.out_dir / "checkpoints").iterdir()} == {
        "step_000002.pt", "step_000004.pt", "last.pt"}
    assert (cfg.out_dir / "figures" / "step_000004.png").stat().st_size > 1000
    assert TrainConfig.from_yaml(cfg.out_dir / "config.yaml") == trainer.config  # n_focus: 2
    model, loaded = load_model(cfg.out_dir / "checkpoints" / "last.pt")
    image = scenes[0]["image"][None]
    batch = scenes[0]["camera"].batched(1)
    torch.testing.assert_close(model(image, scenes[0]["focused"][None], batch),
                               trainer.predict(image, scenes[0]["focused"][None], batch))
    metrics = trainer.evaluate(scenes)
    assert set(METRIC_NAMES) <= set(metrics)


def test_deeper_network_with_rows_loads_as_trained(tmp_path, scenes):
    """`scales` and `position` reach the network and come back from its checkpoint."""
    cfg = _tiny(tmp_path / "run", scales=4, position=True)
    trainer = Trainer(cfg, scenes)
    trainer.fit()
    model, loaded = load_model(cfg.out_dir / "checkpoints" / "last.pt")
    assert (model.scales, model.position, loaded.scales, loaded.position) == (4, True, 4, True)
    image, batch = scenes[0]["image"][None], scenes[0]["camera"].batched(1)
    torch.testing.assert_close(model(image, scenes[0]["focused"][None], batch),
                               trainer.predict(image, scenes[0]["focused"][None], batch))


def test_learning_rate_follows_the_steps_or_the_time_budget(tmp_path, scenes):
    """Cosine decay over `steps`; with a time budget over max(step / steps, elapsed / budget),
    so a budgeted run with a huge `steps` still ends at the schedule's end value."""
    import math

    history = Trainer(_tiny(tmp_path / "steps"), scenes).fit()
    assert [row["lr"] for row in history] == pytest.approx(
        [1e-3 * 0.5 * (1 + math.cos(math.pi * s / 4)) for s in (1, 2, 3, 4)])
    trainer = Trainer(_tiny(tmp_path / "budget", steps=10**9, minutes=0.005), scenes)
    history = trainer.fit()
    assert trainer.out_of_time and 1 <= len(history) < 10**9
    assert history[-1]["lr"] == 0.0  # the cosine's end: decayed over the budget
    if len(history) > 1:
        assert history[0]["lr"] > history[-1]["lr"]


@pytest.mark.parametrize("supervision", ["self", "depth"])
def test_resume_gives_the_same_losses(tmp_path, scenes, supervision):
    full = Trainer(_tiny(tmp_path / "full", supervision=supervision), scenes).fit()
    cfg = _tiny(tmp_path / "split", supervision=supervision)
    Trainer(cfg, scenes).fit(until=2)
    resumed = Trainer(cfg, scenes)
    assert resumed.step == 2
    history = resumed.fit()
    assert [r["step"] for r in history] == [1, 2, 3, 4]
    for a, b in zip(full, history, strict=True):
        assert a["loss"] == b["loss"]
    rows = (cfg.out_dir / "train_log.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["1", "2", "3", "4"]


def test_iterable_and_monocular(tmp_path, scenes):
    samples = (scenes[i] for i in range(len(scenes)))
    cfg = _tiny(tmp_path / "mono", input_mode="aif", steps=2)
    trainer = Trainer(cfg, list(samples))
    trainer.fit()
    depth = trainer.predict(scenes[0]["image"][None])
    assert depth.shape == (1, 1, 16, 16)


def test_nan_loss_is_an_error(tmp_path, scenes):
    bad = dict(scenes[0])
    bad["image"] = torch.full_like(bad["image"], float("nan"))
    trainer = Trainer(_tiny(tmp_path / "nan", steps=1, batch_size=1, supervision="depth"), [bad])
    with pytest.raises(FloatingPointError, match="loss is not finite at step 1"):
        trainer.fit()
    assert not (tmp_path / "nan" / "checkpoints").exists()  # nothing completed, nothing saved


DDP_SCRIPT = textwrap.dedent("""
    import json, os, sys
    from pathlib import Path
    import torch, torch.distributed as dist
    sys.path.insert(0, os.environ["DEFOCUS_ROOT"])
    from datasets.synthetic import SyntheticScenes
    from models.training import TrainConfig, Trainer

    base = Path(sys.argv[1])
    rank = int(os.environ["RANK"])
    torch.set_num_threads(1)
    # Each rank gets its own out_dir so that anything rank 1 wrote would show up there.
    cfg = TrainConfig(steps=3, batch_size=2, width=4, depth_min=1.5, depth_max=6.0,
                      out_dir=base / f"rank{rank}", progress=False, checkpoint_every=1)
    max_diff = []
    def check(trainer, step, losses):
        flat = torch.cat([p.detach().reshape(-1) for p in trainer.model.parameters()])
        gathered = [torch.zeros_like(flat) for _ in range(trainer.world_size)]
        dist.all_gather(gathered, flat)
        max_diff.append(max(float((g - gathered[0]).abs().max()) for g in gathered))
    trainer = Trainer(cfg, SyntheticScenes(8, (16, 16), seed=1), step_callback=check)
    history = trainer.fit()
    result = {"world": trainer.world_size, "max_diff": max_diff,
              "indices": trainer.sampler.indices(0), "losses": [r["loss"] for r in history]}
    (base / f"result{rank}.json").write_text(json.dumps(result))
    dist.barrier()  # neither rank tears its connections down while the other still uses them
    dist.destroy_process_group()
""")


@pytest.mark.slow
def test_ddp_two_processes_gloo(tmp_path):
    script = tmp_path / "ddp_train.py"
    script.write_text(DDP_SCRIPT)
    env = dict(os.environ, DEFOCUS_ROOT=str(ROOT), OMP_NUM_THREADS="1")
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--standalone",
                "--nproc_per_node=2", str(script), str(tmp_path)]
    proc = subprocess.run(torchrun, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    r0, r1 = (json.loads((tmp_path / f"result{r}.json").read_text()) for r in (0, 1))
    assert r0["world"] == r1["world"] == 2
    assert len(r0["max_diff"]) == 3 and max(r0["max_diff"] + r1["max_diff"]) == 0.0
    assert r0["indices"] != r1["indices"]  # each process trains on its own part of the batch
    assert r0["losses"] == r1["losses"]  # logged losses are averaged over processes
    assert (tmp_path / "rank0" / "checkpoints" / "last.pt").exists()
    assert (tmp_path / "rank0" / "train_log.csv").exists()
    assert not (tmp_path / "rank1").exists()  # only rank 0 writes


@pytest.mark.slow
def test_trained_network_beats_constant_depth(tmp_path):
    """Self-supervised (no depth labels) on synthetic scenes beats the best constant depth (one
    constant for the whole held-out set, chosen on its ground truth) by at least 2x in abs rel.

    CI-sized: 300 steps on 128 scenes of 32x32 pixels, evaluated on 24 unseen scenes (about a
    minute on one core). Measured ratios: 0.462, 0.464 and 0.475 with training seeds 0, 1, 2
    (0.45 with 400 steps; width 16 instead of 32 gave 0.51-0.55, depth-supervised width 16
    0.44-0.47, so the network's capacity, not the self-supervised loss, sets the level).
    """
    torch.manual_seed(0)
    train = SyntheticScenes(128, (32, 32), seed=0)
    test = SyntheticScenes(24, (32, 32), seed=99)
    cfg = _tiny(tmp_path / "learn", steps=300, batch_size=8, lr=3e-3, width=32)
    trainer = Trainer(cfg, train)
    trainer.fit()
    net = trainer.evaluate(test)["abs_rel"]
    everything = torch.cat([s["depth"].reshape(-1) for s in test])
    best = best_constant_depth(target=everything)
    constant = sum(depth_metrics(pred=torch.full_like(s["depth"], best), target=s["depth"])["abs_rel"]
                   for s in test) / len(test)
    print(f"abs rel: network {net:.3f}, best constant ({best:.2f} m) {constant:.3f}, "
          f"ratio {net / constant:.3f}")
    assert net <= 0.5 * constant
