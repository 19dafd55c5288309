"""The training side under unusual and bad input: configs (YAML and `key=value` overrides), run
folders whose checkpoints are missing, broken or in the way, checkpoint conversion, and
evaluation on data that does not fit the checkpoint. Nothing is lost and nothing silently
wrong: each refusal names the argument, the value and what is allowed."""

from __future__ import annotations

import functools
import re
import shutil

import pytest
import torch
from training_helpers import tiny_config

from defocus.app.evaluate import EvaluateRequest, run_evaluation
from defocus.cli import main
from models.checkpoints import CheckpointError, convert_checkpoint, load_checkpoint
from models.training import TrainConfig, Trainer

_tiny = functools.partial(tiny_config, supervision="depth", steps=2)


@pytest.fixture(scope="module")
def run(tmp_path_factory, scenes):
    """A finished 2-step run that kept a checkpoint of every step."""
    out = tmp_path_factory.mktemp("run") / "run"
    Trainer(_tiny(out, checkpoint_every=1, keep_checkpoints=0), scenes).fit()
    return out


def _copy(run, tmp_path):
    shutil.copytree(run, tmp_path / "run")
    return tmp_path / "run"


def _error_line(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"defocus {command}: error: ") and "\n" not in err, err
    return err


# -- configs --------------------------------------------------------------------------------
@pytest.mark.parametrize(("change", "message"), [
    ({"seed": 2**50}, r"seed must be an integer in \[0, 4294967295\] \(2\*\*32 - 1\), got "
                      "1125899906842624"),
    ({"focus_distance": float("nan")}, "focus_distance must be a finite number of metres >= 0 "
                                       r"\(0: none\), got nan"),
    ({"focus_distance": -2.0}, "focus_distance must be a finite number of metres >= 0"),
])
def test_config_values_that_fail_later_or_mean_nothing_are_refused(change, message):
    """A seed too large for the batch-order generator used to fail inside `fit` (after the run
    folder was prepared) with "Overflow when unpacking long long"; a NaN focus distance was
    kept in the config and the checkpoint."""
    with pytest.raises(ValueError, match=message):
        TrainConfig(**change)
    assert TrainConfig(seed=2**32 - 1).seed == 2**32 - 1


def test_a_key_given_twice_is_refused_not_silently_the_last(tmp_path):
    with pytest.raises(ValueError, match=r"config key steps is set twice in the overrides "
                                         r"\('steps=3' and ' steps=2'\): give each key once"):
        TrainConfig().override(["steps=3", "lr=0.1", " steps=2"])
    config = tmp_path / "config.yaml"
    config.write_text("steps: 3\nlr: 0.1\nsteps: 2\n")
    with pytest.raises(ValueError, match=r"config.yaml: config key steps is given twice "
                                         r"\(again on line 3\)"):
        TrainConfig.from_yaml(config)


@pytest.mark.parametrize(("text", "message"), [
    (b"steps: [1\n", r"bad.yaml is not valid YAML at line 2, column 1: expected ',' or ']'"),
    (b"\xff\xfesteps: 1\n", r"config .*bad.yaml is not UTF-8 YAML text \(byte 0"),
])
def test_a_config_file_that_is_not_yaml_is_one_line_naming_it(tmp_path, capsys, text, message):
    """Broken YAML was an "unexpected ParserError" (exit 1) spread over several lines."""
    (tmp_path / "bad.yaml").write_bytes(text)
    assert main(["train", "--config", str(tmp_path / "bad.yaml"), "--out",
                 str(tmp_path / "out")]) == 2
    assert re.search(message, _error_line(capsys, "train"))
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("argv", "message"), [
    (["--set", "steps=[1"], "override 'steps=[1' is not valid YAML at line 1, column 3"),
    (["--out", "{out}", "--set", "out_dir=elsewhere"],
     "--set out_dir=elsewhere and --out {out} both name the output folder: give only --out"),
    (["--out", "{out}", "--resume", "--set", "resume=overwrite"],
     "--set resume=overwrite and --resume both say what to do with an earlier run"),
    (["--out", "{out}", "--set", "steps=3", "steps=2"], "config key steps is set twice"),
])
def test_conflicting_or_broken_overrides_are_refused(tmp_path, capsys, argv, message):
    """`--out` silently won over `--set out_dir=...`, `--resume` over `--set resume=...`."""
    out = str(tmp_path / "out")
    argv = [arg.replace("{out}", out) for arg in argv]
    assert main(["train", "--scenes", "2", "--size", "16", "16", *argv]) == 2
    assert message.replace("{out}", out) in _error_line(capsys, "train")
    assert not (tmp_path / "out").exists() and not (tmp_path / "elsewhere").exists()


# -- run folders ----------------------------------------------------------------------------
def test_a_missing_last_checkpoint_continues_from_the_newest_step_file(run, tmp_path, scenes):
    """Without `last.pt` the run restarted at step 0 and deleted every step checkpoint and the
    log's rows: the whole run was lost without a word."""
    out = _copy(run, tmp_path)
    (out / "checkpoints" / "last.pt").unlink()
    trainer = Trainer(_tiny(out, checkpoint_every=1, keep_checkpoints=0), scenes)
    assert trainer.step == 2 and trainer.resumed_from == out / "checkpoints" / "step_000002.pt"
    trainer.fit()
    names = sorted(p.name for p in (out / "checkpoints").iterdir())
    assert names == ["last.pt", "step_000001.pt", "step_000002.pt"]
    assert load_checkpoint(out / "checkpoints" / "last.pt")["step"] == 2
    assert len((out / "train_log.csv").read_text().splitlines()) == 3  # header + 2 steps


def test_a_last_checkpoint_that_is_a_folder_is_refused_and_nothing_deleted(run, tmp_path,
                                                                          scenes):
    out = _copy(run, tmp_path)
    (out / "checkpoints" / "last.pt").unlink()
    (out / "checkpoints" / "last.pt").mkdir()
    before = sorted(p.name for p in (out / "checkpoints").iterdir())
    with pytest.raises(ValueError, match=r"last.pt, which is not a checkpoint file \(a folder"):
        Trainer(_tiny(out, checkpoint_every=1, keep_checkpoints=0), scenes)
    trainer = Trainer(_tiny(out, resume="overwrite"), scenes)  # refused when fit starts too
    with pytest.raises(ValueError, match="not a checkpoint file"):
        trainer.fit()
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == before


def test_a_corrupt_last_checkpoint_names_the_step_file_to_continue_from(run, tmp_path, scenes):
    out = _copy(run, tmp_path)
    last = out / "checkpoints" / "last.pt"
    last.write_bytes(last.read_bytes()[:100])
    with pytest.raises(CheckpointError, match=r"cannot continue the run in .*last.pt is not a "
                                              r"readable PyTorch checkpoint .*the newest step "
                                              r"checkpoint is step_000002.pt: copy it over "
                                              r"last.pt .*--overwrite"):
        Trainer(_tiny(out, checkpoint_every=1, keep_checkpoints=0), scenes)


def test_an_out_dir_below_a_file_is_refused_naming_it(tmp_path, capsys, scenes):
    """It failed with "[Errno 20] Not a directory: 'notes.txt/run'" once the data was read
    (the command) or when `fit` started (the library)."""
    (tmp_path / "notes.txt").write_text("mine")
    out = tmp_path / "notes.txt" / "run"
    assert main(["train", "--out", str(out), "--scenes", "2", "--size", "16", "16"]) == 2
    assert f"--out {out} cannot be a folder: {tmp_path / 'notes.txt'} is a file; choose " \
           "another --out" in _error_line(capsys, "train")
    with pytest.raises(NotADirectoryError, match="out_dir .* cannot be a folder: .*notes.txt is "
                                                 "a file"):
        Trainer(_tiny(out), scenes).fit()
    assert (tmp_path / "notes.txt").read_text() == "mine"


# -- checkpoint files -----------------------------------------------------------------------
def test_a_text_file_is_named_as_no_checkpoint_in_plain_words(tmp_path):
    """The reason used to be "(105)", the str of a KeyError from the unpickler."""
    (tmp_path / "notes.pt").write_text("hi\n")
    with pytest.raises(CheckpointError, match=r"notes.pt is not a readable PyTorch checkpoint "
                                              r"\(neither a zip archive nor a pickle"):
        load_checkpoint(tmp_path / "notes.pt")
    with pytest.raises(CheckpointError, match="neither a zip archive nor a pickle"):
        convert_checkpoint(tmp_path / "notes.pt", tmp_path / "new.pt")


def test_convert_refuses_what_is_no_defocus_checkpoint_before_writing(tmp_path, run, capsys):
    torch.save(torch.nn.Linear(2, 2).state_dict(), tmp_path / "weights.pt")
    with pytest.raises(CheckpointError, match=r"weights.pt is not a defocus checkpoint .*its "
                                              r"keys are \[.bias., .weight.\]\); nothing written: .*new.pt is "
                                              r"left as it was"):
        convert_checkpoint(tmp_path / "weights.pt", tmp_path / "new.pt")
    (tmp_path / "notes.txt").write_text("mine")
    target = tmp_path / "notes.txt" / "new.pt"
    assert main(["convert-checkpoint", "--trust", str(run / "checkpoints" / "last.pt"),
                 str(target)]) == 2
    assert f"cannot write {target}: {tmp_path / 'notes.txt'} is a file, not a folder" in \
        _error_line(capsys, "convert-checkpoint")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "weights.pt"]


def test_convert_names_a_module_the_old_file_needs(tmp_path, monkeypatch):
    """A trusted old file whose class is gone gave an unexpected ModuleNotFoundError."""
    import sys
    import types

    module = types.ModuleType("gone_module")
    thing = type("Thing", (), {"__module__": "gone_module"})
    module.Thing = thing
    monkeypatch.setitem(sys.modules, "gone_module", module)
    torch.save({"model": {}, "config": {}, "x": thing()}, tmp_path / "old.pt")
    monkeypatch.delitem(sys.modules, "gone_module")
    with pytest.raises(CheckpointError, match=r"old.pt could not be unpickled: "
                                              r"ModuleNotFoundError: No module named "
                                              r"'gone_module'.*nothing written"):
        convert_checkpoint(tmp_path / "old.pt", tmp_path / "new.pt")
    assert not (tmp_path / "new.pt").exists()


# -- evaluation on data that does not fit ---------------------------------------------------
def test_evaluate_refuses_samples_the_network_cannot_read(run, scenes):
    checkpoint = run / "checkpoints" / "last.pt"
    three = dict(scenes[0], focused=torch.cat([scenes[0]["focused"]] * 2)[:3])
    with pytest.raises(ValueError, match=r"was trained on n_focus=2 focused photos, but test "
                                         r"sample '3-0' holds focused images of shape "
                                         r"\(3, 3, 16, 16\)"):
        run_evaluation(EvaluateRequest([scenes[1], three], checkpoint))
    without = {k: v for k, v in scenes[0].items() if k != "focused"}
    with pytest.raises(ValueError, match=r"test sample '3-0' has no \['focused'\], which "
                                         r"checkpoint .*input_mode='aif\+focused'\) needs"):
        run_evaluation(EvaluateRequest([without], checkpoint))


def test_evaluate_warns_when_the_ground_truth_lies_outside_the_networks_range(run, scenes):
    """Ground truth 10 times farther than the network's 1.5-6 m gave metrics without a word."""
    checkpoint = run / "checkpoints" / "last.pt"
    warning = run_evaluation(EvaluateRequest([scenes[0]], checkpoint)).warning
    assert warning is None
    far = dict(scenes[0], depth=scenes[0]["depth"] * 10)
    warning = run_evaluation(EvaluateRequest([far], checkpoint)).warning
    assert warning is not None and "100% of the valid ground-truth pixels lie outside the " \
        "depth range of checkpoint" in warning and "(1.5 to 6.0 m)" in warning


def test_overwrite_deletes_only_a_runs_files(run, tmp_path, scenes):
    """`--out . --overwrite` in a project folder used to delete its own config.yaml and logs."""
    project = tmp_path / "project"
    project.mkdir()
    (project / "config.yaml").write_text("model: my-own\n")
    (project / "train_log.csv").write_text("epoch,loss\n1,0.5\n")
    with pytest.raises(ValueError, match=r"holds \['config.yaml', 'train_log.csv'\], named like "
                                         r"a run's files, but no training run"):
        Trainer(_tiny(project, resume="overwrite"), scenes)
    assert (project / "config.yaml").read_text() == "model: my-own\n"
    assert (project / "train_log.csv").is_file()
    again = _copy(run, tmp_path)  # a run's files are still replaced
    Trainer(_tiny(again, resume="overwrite", steps=1), scenes).fit()
    assert len(load_checkpoint(again / "checkpoints" / "last.pt")["history"]) == 1


def test_trainer_evaluate_refuses_a_sample_without_focused_photos(run, scenes):
    """The library's `Trainer.evaluate` used to fail with an AttributeError."""
    trainer = Trainer.from_checkpoint(run / "checkpoints" / "last.pt")
    without = {k: v for k, v in scenes[0].items() if k != "focused"}
    with pytest.raises(ValueError, match=r"test sample '3-0' has no \['focused'\], which the "
                                         r"network \(input_mode='aif\+focused'\) needs"):
        trainer.evaluate([without])


def test_a_whole_number_written_with_an_exponent_is_an_integer():
    """YAML reads `1e3` (no dot) as text: `steps=1e3` used to be refused with "got '1e3'"."""
    config = TrainConfig().override(["steps=1e3", "batch_size=+4"])
    assert (config.steps, config.batch_size) == (1000, 4)
    for value, shown in (("1.5e0", "1.5"), ("abc", "'abc'"), ("nan", "nan")):
        with pytest.raises(ValueError, match=f"config key steps must be of type int, got {shown}"):
            TrainConfig().override([f"steps={value}"])


def test_weights_that_do_not_fit_their_config_are_named_in_one_line(run, tmp_path):
    """A hand-edited checkpoint used to fail with load_state_dict's many-line RuntimeError."""
    from models.loading import load_model

    state = load_checkpoint(run / "checkpoints" / "last.pt")
    name = next(iter(state["model"]))
    state["model"].pop(name)
    edited = tmp_path / "edited.pt"
    torch.save(state, edited)
    for load in (Trainer.from_checkpoint, load_model):
        with pytest.raises(CheckpointError) as caught:
            load(edited)
        message = str(caught.value)
        assert "\n" not in message and message.startswith(f"{edited}: its weights do not fit")
        assert f"missing ['{name}']" in message


@pytest.mark.parametrize(("options", "message"), [
    (["--depth-cap", "0"], r"--depth-cap must be a depth > --min-depth \(0.001\) metres"),
    (["--min-depth", "-1"], "--min-depth must be a finite depth >= 0 metres, got -1.0"),
])
def test_evaluate_names_its_own_depth_options(run, capsys, options, message):
    """The refusal used to name the library's `max_depth` / `min_depth`, after the checkpoint
    and the data were read."""
    assert main(["evaluate", str(run / "checkpoints" / "last.pt"), *options]) == 2
    assert re.search(message, _error_line(capsys, "evaluate"))
