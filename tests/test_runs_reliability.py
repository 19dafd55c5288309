"""Training runs that fail safely (issue #11): one run per folder, checkpoints on signals and
failures, config checks, bad data, non-finite steps and collapsed predictions."""

from __future__ import annotations

import csv
import functools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from training_helpers import tiny_config

from defocus.cli import main
from models.checkpoints import load_checkpoint
from models.training import DepthCollapseWarning, TrainConfig, Trainer

_tiny = functools.partial(tiny_config, supervision="depth")

ROOT = Path(__file__).resolve().parents[1]






def _log_steps(out_dir: Path) -> list[int]:
    with (out_dir / "train_log.csv").open(newline="") as handle:
        return [int(row["step"]) for row in csv.DictReader(handle)]


def _log_column(out_dir: Path, name: str) -> list[str]:
    with (out_dir / "train_log.csv").open(newline="") as handle:
        return [row[name] for row in csv.DictReader(handle)]


# -- case 2: one run per folder ---------------------------------------------------------------
def test_another_run_in_the_folder_is_refused_naming_the_keys(tmp_path, scenes):
    run = tmp_path / "run"
    Trainer(_tiny(run), scenes).fit()
    with pytest.raises(ValueError, match=r"another run \(step 4\).*steps \(there 4, here 8\), "
                                         r"lr \(there 0.001, here 0.5\).*--resume.*--overwrite"):
        Trainer(_tiny(run, steps=8, lr=0.5), scenes)
    assert TrainConfig.from_yaml(run / "config.yaml").lr == 1e-3  # config.yaml not rewritten
    with pytest.raises(ValueError, match=r"cannot resume.*lr \(there 0.001, here 0.5\)"):
        Trainer(_tiny(run, steps=8, lr=0.5, resume="resume"), scenes)
    with pytest.raises(ValueError, match=r"steps \(there 4, here 2\)"):
        Trainer(_tiny(run, steps=2, resume="resume"), scenes)
    with pytest.raises(ValueError, match="holds no run to continue"):
        Trainer(_tiny(tmp_path / "empty", resume="resume"), scenes)
    # the same config continues (nothing left to do); device, progress, checkpoints may differ
    same = Trainer(_tiny(run, progress=True, checkpoint_every=1, device="cpu"), scenes)
    assert same.step == 4 and same.resumed_from == run / "checkpoints" / "last.pt"


def test_resume_to_more_steps_continues_the_old_run(tmp_path, scenes):
    full = Trainer(_tiny(tmp_path / "full", steps=6, lr_schedule="constant"), scenes).fit()
    run = tmp_path / "run"
    Trainer(_tiny(run, lr_schedule="constant"), scenes).fit()
    longer = Trainer(_tiny(run, steps=6, lr_schedule="constant", resume="resume"), scenes)
    assert longer.step == 4
    assert [r["loss"] for r in longer.fit()] == [r["loss"] for r in full]
    assert _log_steps(run) == [1, 2, 3, 4, 5, 6]
    assert TrainConfig.from_yaml(run / "config.yaml").steps == 6


def test_overwrite_removes_the_old_run_and_nothing_else(tmp_path, scenes):
    for resume in ("overwrite", False):  # False: the old resume=False, now a clean start
        run = tmp_path / str(resume)
        Trainer(_tiny(run, steps=3, checkpoint_every=1, keep_checkpoints=0), scenes,
                val_set=[scenes[0]]).fit()
        (run / "notes.txt").write_text("mine")
        trainer = Trainer(_tiny(run, steps=2, lr=0.5, resume=resume), scenes)
        assert trainer.step == 0
        assert (run / "checkpoints" / "step_000003.pt").exists()  # deleted only by fit
        trainer.fit()
        assert sorted(p.name for p in (run / "checkpoints").iterdir()) == [
            "last.pt", "step_000002.pt"]
        assert _log_steps(run) == [1, 2] and not (run / "val_log.csv").exists()
        assert sorted(p.name for p in (run / "figures").iterdir()) == ["step_000002.png"]
        assert load_checkpoint(run / "checkpoints" / "last.pt")["config"]["lr"] == 0.5
        assert (run / "notes.txt").read_text() == "mine"


def test_cli_refuses_another_run_then_resume_and_overwrite(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    run = tmp_path / "R"
    base = ["train", "--out", str(run), "--scenes", "2", "--size", "16", "16", "--set",
            "batch_size=1", "width=4", "progress=false", "supervision=depth"]
    assert main([*base, "steps=2"]) == 0
    capsys.readouterr()
    assert main([*base, "steps=3", "lr=0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("defocus train: error: out_dir") and "\n" not in err
    assert "lr (there 0.001, here 0.5)" in err and "steps (there 2, here 3)" in err
    assert main([*base, "steps=3", "lr=0.5", "--resume"]) == 2
    assert "cannot resume" in capsys.readouterr().err
    assert main([*base, "steps=3", "--resume"]) == 0
    assert "from step 2 of 3" in capsys.readouterr().out
    assert _log_steps(run) == [1, 2, 3]
    assert main([*base, "steps=1", "lr=0.5", "--overwrite"]) == 0
    assert _log_steps(run) == [1]


# -- case 1: checkpoints by default, on failures and signals; logs cut back -------------------
def test_default_keeps_few_checkpoints_and_saves_by_time(tmp_path, scenes):
    cfg = _tiny(tmp_path / "run", steps=5, checkpoint_minutes=1e-9)  # every step is "late"
    assert TrainConfig().keep_checkpoints == 3 and TrainConfig().checkpoint_minutes > 0
    Trainer(cfg, scenes).fit()
    assert sorted(p.name for p in (cfg.out_dir / "checkpoints").iterdir()) == [
        "last.pt", "step_000003.pt", "step_000004.pt", "step_000005.pt"]  # no temporaries


def test_a_failing_step_saves_the_last_good_one_and_resume_is_exact(tmp_path, scenes):
    full = Trainer(_tiny(tmp_path / "full"), scenes).fit()
    cfg = _tiny(tmp_path / "run", checkpoint_minutes=0)

    def fail(trainer, step, losses):
        if step == 3:
            raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        Trainer(cfg, scenes, step_callback=fail).fit()
    assert load_checkpoint(cfg.out_dir / "checkpoints" / "last.pt")["step"] == 3
    resumed = Trainer(cfg, scenes)
    assert resumed.step == 3
    assert [r["loss"] for r in resumed.fit()] == [r["loss"] for r in full]
    assert _log_steps(cfg.out_dir) == [1, 2, 3, 4]


def test_a_run_killed_before_any_checkpoint_restarts_with_a_clean_log(tmp_path, scenes):
    cfg = _tiny(tmp_path / "run")
    Trainer(cfg, scenes).fit()
    for path in (cfg.out_dir / "checkpoints").iterdir():  # as after SIGKILL before a save
        path.unlink()
    trainer = Trainer(cfg, scenes)
    assert trainer.step == 0
    trainer.fit()
    assert _log_steps(cfg.out_dir) == [1, 2, 3, 4]


def test_sigint_saves_and_the_run_resumes_exactly(tmp_path):
    """`defocus train` in a subprocess, SIGINT once the log shows steps, then `--resume`: the
    log's steps strictly increase and its losses equal those of an uninterrupted run."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.pop("DEFOCUS_DEBUG", None)
    total_steps = 300

    # 300 steps of about 2 ms: the signal, sent once two steps are logged, lands before the last
    # one even when this loop is slow to see the log
    def command(out: Path, *extra: str) -> list[str]:
        return [sys.executable, "-m", "defocus.cli", "train", "--out", str(out), "--scenes", "4",
                "--size", "16", "16", *extra, "--set", f"steps={total_steps}", "batch_size=1", "width=4",
                "progress=false", "supervision=depth", "checkpoint_minutes=0"]

    interrupted = tmp_path / "interrupted"
    # SIGINT as a terminal delivers it: a shell that started these tests in the background
    # (`cmd &` without job control) left SIGINT ignored, which the child would inherit and keep
    proc = subprocess.Popen(command(interrupted), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    log = interrupted / "train_log.csv"
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        if log.exists() and len(log.read_text().splitlines()) >= 3:  # header + 2 steps
            proc.send_signal(signal.SIGINT)
            break
        time.sleep(0.01)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (out, err)
    assert "defocus train: interrupted: stopped by SIGINT after step" in err, err
    assert "Traceback" not in err
    saved = load_checkpoint(interrupted / "checkpoints" / "last.pt")
    assert 2 <= saved["step"] < total_steps
    assert _log_steps(interrupted) == list(range(1, saved["step"] + 1))
    assert not list((interrupted / "checkpoints").glob(".*"))  # no stray temporaries

    resumed = subprocess.run(command(interrupted, "--resume"), env=env, capture_output=True,
                             text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    reference = subprocess.run(command(tmp_path / "reference"), env=env, capture_output=True,
                               text=True, timeout=300)
    assert reference.returncode == 0, reference.stderr
    steps = _log_steps(interrupted)
    assert steps == list(range(1, total_steps + 1))  # strictly increasing, no duplicates
    assert _log_column(interrupted, "loss") == _log_column(tmp_path / "reference", "loss")


# -- case 3: config fields and data checked up front ------------------------------------------
@pytest.mark.parametrize(("change", "message"), [
    ({"width": 0}, "width must be an integer >= 1, got 0"),
    ({"log_every": 0}, "log_every must be an integer >= 1, got 0"),
    ({"ssim_window": 4}, "ssim_window must be a positive odd number of pixels, got 4"),
    ({"max_kernel_size": 0}, "max_kernel_size must be a positive odd"),
    ({"render_mode": "fast"}, r"render_mode must be one of \('gather', 'scatter', 'layered'\)"),
    ({"lr": float("nan")}, "lr must be a finite number > 0, got nan"),
    ({"lr": float("inf")}, "lr must be a finite number > 0, got inf"),
    ({"lr": -1.0}, "lr must be a finite number > 0"),
    ({"grad_clip": -1.0}, "grad_clip must be a finite number >= 0"),
    ({"checkpoint_every": -1}, "checkpoint_every must be an integer >= 0"),
    ({"checkpoint_minutes": -1.0}, "checkpoint_minutes must be a finite number >= 0"),
    ({"device": "cuda:99"}, "device 'cuda:99' is not available"),
    ({"device": "gpu"}, "device must be 'auto' or a torch device"),
    ({"resume": "maybe"}, r"resume must be one of \('auto', 'resume', 'overwrite'\)"),
    ({"width": "4"}, "config key width must be of type int, got '4'"),
    ({"flip": 1}, "config key flip must be of type bool"),
    ({"ssim_weight": 2.0}, r"ssim_weight must be in \[0, 1\]"),
])
def test_every_config_field_is_checked(change, message):
    with pytest.raises(ValueError, match=message):
        TrainConfig(**change)


def test_config_overrides_reject_bools_for_numbers():
    with pytest.raises(ValueError, match="width must be of type int, got True"):
        TrainConfig().override(["width=true"])
    assert TrainConfig().override(["resume=false"]).resume == "overwrite"
    assert TrainConfig().override(["resume=true"]).resume == "auto"


def test_data_is_checked_against_the_config(tmp_path, scenes):
    with pytest.raises(ValueError, match="train_set holds no samples"):
        Trainer(_tiny(tmp_path / "a"), []).fit()
    with pytest.raises(ValueError, match=r"n_focus is 3 but sample '3-0' holds focused images of "
                                         r"shape \(2, 3, 16, 16\)"):
        Trainer(_tiny(tmp_path / "b", n_focus=3, supervision="self"), scenes)
    no_depth = [{k: v for k, v in scenes[0].items() if k != "depth"}]
    with pytest.raises(ValueError, match=r"has no \['depth'\]"):
        Trainer(_tiny(tmp_path / "c"), no_depth)


@pytest.mark.parametrize("value", [-2.0, 0.0, float("nan"), float("inf")])
def test_bad_ground_truth_depth_is_refused_naming_the_sample(tmp_path, scenes, value):
    bad = dict(scenes[1], id="scene-17")
    depth = bad["depth"].clone()
    depth[..., 3, 4] = value
    bad["depth"] = depth
    trainer = Trainer(_tiny(tmp_path / "run", steps=1, batch_size=1), [bad])
    with pytest.raises(ValueError, match=r"sample 'scene-17' \(train_set\[0\]\) has ground-truth "
                                         r"depth that is not finite and > 0 at 1 of its valid"):
        trainer.fit()
    masked = dict(bad, mask=torch.isfinite(depth) & (depth > 0))  # masked out: fine
    history = Trainer(_tiny(tmp_path / "ok", steps=1, batch_size=1), [masked]).fit()
    assert history[0]["loss"] > 0


# -- case 4: non-finite steps stop, collapsed predictions warn --------------------------------
def test_a_non_finite_gradient_stops_before_the_weights_change(tmp_path, scenes, monkeypatch):
    cfg = _tiny(tmp_path / "run", grad_clip=0.0)
    trainer = Trainer(cfg, scenes)

    def poison(trainer, step, losses):
        if step == 2:  # from step 3 on, one weight's gradient is NaN
            next(trainer.model.parameters()).register_hook(lambda grad: grad * float("nan"))

    trainer.step_callback = poison
    with pytest.raises(FloatingPointError, match="gradient is not finite at step 3"):
        trainer.fit()
    state = load_checkpoint(cfg.out_dir / "checkpoints" / "last.pt")
    assert state["step"] == 2  # the last good step, finite
    assert all(torch.isfinite(t).all() for t in state["model"].values() if t.is_floating_point())


def test_huge_lr_collapse_warns_in_the_log_and_the_summary(tmp_path, scenes, capsys,
                                                             monkeypatch):
    cfg = _tiny(tmp_path / "run", steps=3, lr=10.0)
    trainer = Trainer(cfg, scenes, val_set=[scenes[0]])
    with pytest.warns(DepthCollapseWarning, match="collapsed to its depth limits"):
        trainer.fit()
    assert trainer.warnings and "lr, here 10.0" in trainer.warnings[0]
    assert "collapsed" in (cfg.out_dir / "warnings.log").read_text()
    assert float(_log_column(cfg.out_dir, "at_depth_limits")[-1]) >= 0.9
    assert trainer.last_validation["at_depth_limits"] >= 0.9

    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    assert main(["train", "--out", str(tmp_path / "cli"), "--scenes", "2", "--size", "16", "16",
                 "--set", "steps=3", "batch_size=2", "width=4", "progress=false",
                 "supervision=depth", "lr=1000"]) == 0
    out = capsys.readouterr().out
    assert "warning:" in out and "collapsed to its depth limits" in out


def test_log_of_an_older_version_gains_the_new_columns(tmp_path):
    from models.training.run_log import CsvLog

    log = CsvLog(tmp_path / "train_log.csv")
    log.append({"step": 1, "loss": 0.5})
    log.append({"step": 2, "loss": 0.4, "at_depth_limits": 0.0})
    log.append({"step": 3, "loss": 0.3, "at_depth_limits": 0.1})
    assert log.path.read_text().splitlines() == [
        "step,loss,at_depth_limits", "1,0.5,", "2,0.4,0.0", "3,0.3,0.1"]
    log.truncate(2)
    assert [r["step"] for r in log.rows()] == ["1", "2"] and not list(tmp_path.glob(".*"))


def test_sigterm_in_process_saves_and_raises(tmp_path, scenes):
    from models.training import TrainingInterrupted

    cfg = _tiny(tmp_path / "run", steps=4, checkpoint_minutes=0)

    def terminate(trainer, step, losses):
        if step == 2:
            os.kill(os.getpid(), signal.SIGTERM)

    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(TrainingInterrupted, match="stopped by SIGTERM after step 2") as info:
        Trainer(cfg, scenes, step_callback=terminate).fit()
    assert signal.getsignal(signal.SIGTERM) is previous  # handlers restored
    assert info.value.signal == signal.SIGTERM and info.value.step == 2
    assert load_checkpoint(info.value.checkpoint)["step"] == 2
    assert _log_steps(cfg.out_dir) == [1, 2]


def test_a_signal_after_the_last_steps_check_still_stops_the_run(tmp_path, scenes):
    """SIGTERM caught between the last step's check and the end of the loop (simulated: the
    flag is set right after that check) stops the run instead of being ignored."""
    from models.training import TrainingInterrupted

    cfg = _tiny(tmp_path / "run", steps=3, checkpoint_minutes=0)
    trainer = Trainer(cfg, scenes)
    check = trainer._stop_requested

    def late_signal() -> int:
        signum = check()
        if trainer.step == 3 and trainer.signals.signal is None:
            trainer.signals.signal = signal.SIGTERM  # arrives just after this check
        return signum

    trainer._stop_requested = late_signal
    with pytest.raises(TrainingInterrupted, match="stopped by SIGTERM after step 3"):
        trainer.fit()
    assert load_checkpoint(cfg.out_dir / "checkpoints" / "last.pt")["step"] == 3


def test_cli_reports_an_interrupted_run_in_one_line(capsys, monkeypatch):
    import defocus.commands.train as train
    from models.training import TrainingInterrupted

    def interrupted(args):
        raise TrainingInterrupted(signal.SIGTERM, 7, Path("R/checkpoints/last.pt"))

    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    monkeypatch.setattr(train, "run", interrupted)
    assert main(["train"]) == 128 + signal.SIGTERM
    err = capsys.readouterr().err.strip()
    assert err.startswith("defocus train: interrupted: stopped by SIGTERM after step 7 (saved "
                          "R/checkpoints/last.pt)") and "\n" not in err


def test_non_finite_weights_are_never_saved(tmp_path, scenes):
    trainer = Trainer(_tiny(tmp_path / "run"), scenes)
    with torch.no_grad():
        next(trainer.model.parameters()).fill_(float("nan"))
    with pytest.raises(FloatingPointError, match="weights are not finite"):
        trainer.save_checkpoint()
    with pytest.raises(FloatingPointError):
        trainer.save_checkpoint(tmp_path / "x.pt")
    assert not (tmp_path / "run" / "checkpoints").exists() and not (tmp_path / "x.pt").exists()
