"""Checkpoints: opening one never runs code (issue #14), old files, conversion, the store, logs.

The attack is real: `torch.save` pickles an object whose `__reduce__` calls `os.system` (or
`open`) to create a marker file. A sanity check shows that `torch.load(weights_only=False)` does
create it; `defocus predict`, `defocus evaluate`, `defocus train` (resume), `Trainer` (resume),
`Trainer.from_checkpoint` and `load_model` must refuse the file in one line and leave no marker.
"""

from __future__ import annotations

import os
import pathlib
import shlex

import numpy as np
import pytest
import torch
from training_helpers import tiny_config as _tiny

from defocus.cli import main
from models.checkpoints import (
    CheckpointError,
    CheckpointStore,
    check_plain,
    load_checkpoint,
    save_checkpoint,
    to_plain,
)
from models.loading import load_model
from models.training import Trainer
from models.training.run_log import CsvLog


class ShellPayload:
    """Unpickling this runs a shell command that creates `marker`."""

    def __init__(self, marker: pathlib.Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {shlex.quote(str(self.marker))}",))


class OpenPayload:
    """Unpickling this calls `open(marker, "w")`, which creates `marker`."""

    def __init__(self, marker: pathlib.Path):
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


PAYLOADS = {"os.system": ShellPayload, "open": OpenPayload}






def _evil(path: pathlib.Path, marker: pathlib.Path, payload: str = "os.system") -> pathlib.Path:
    """A checkpoint-shaped dict with a payload among plain entries, pickled by `torch.save`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    config = _tiny("runs/evil").to_dict()
    torch.save({"model": {"w": torch.ones(2)}, "config": config, "step": 1,
                "payload": PAYLOADS[payload](marker)}, path)
    return path


def _one_line_error(capsys, command: str, path: pathlib.Path) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"defocus {command}: error: ") and str(path) in err, err
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize("payload", list(PAYLOADS))
def test_the_attack_is_real_with_weights_only_false(tmp_path, payload):
    marker = tmp_path / "pwned"
    evil = _evil(tmp_path / "evil.pt", marker, payload)
    torch.load(evil, weights_only=False)  # what the old code did
    assert marker.exists()


@pytest.mark.parametrize("payload", list(PAYLOADS))
def test_malicious_checkpoint_is_refused_by_every_command(tmp_path, capsys, payload):
    marker = tmp_path / "pwned"
    evil = _evil(tmp_path / "evil.pt", marker, payload)
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"\x89PNG\r\n\x1a\n")

    assert main(["predict", str(evil), "--image", str(photo), "--out", str(tmp_path / "p")]) == 2
    err = _one_line_error(capsys, "predict", evil)
    assert "refused" in err and "nothing in it was run" in err and "--trust" in err
    assert main(["evaluate", str(evil), "--data", "motorcycle", "--scale", "0.05"]) == 2
    _one_line_error(capsys, "evaluate", evil)

    run = tmp_path / "run"
    last = _evil(run / "checkpoints" / "last.pt", marker, payload)
    assert main(["train", "--out", str(run), "--scenes", "2", "--size", "8", "8", "--set",
                 "steps=1", "batch_size=1", "width=4", "progress=false"]) == 2
    _one_line_error(capsys, "train", last)
    assert main(["convert-checkpoint", str(evil), str(tmp_path / "new.pt")]) == 2  # no --trust
    _one_line_error(capsys, "convert-checkpoint", evil)
    assert not (tmp_path / "new.pt").exists()
    assert not marker.exists()


def test_malicious_checkpoint_is_refused_by_the_library(tmp_path, scenes):
    marker = tmp_path / "pwned"
    cfg = _tiny(tmp_path / "run")
    last = _evil(cfg.out_dir / "checkpoints" / "last.pt", marker)
    with pytest.raises(CheckpointError, match="refused to open checkpoint .*last.pt"):
        Trainer(cfg, scenes)  # resume
    with pytest.raises(CheckpointError, match="posix.system|os.system"):
        Trainer.from_checkpoint(last)
    with pytest.raises(CheckpointError):
        load_model(last)
    with pytest.raises(CheckpointError):
        load_checkpoint(last)
    assert not marker.exists()
    assert Trainer(_tiny(cfg.out_dir, resume=False), scenes).step == 0  # resume=False: not read


@pytest.mark.parametrize("content", [b"\x89PNG\r\n\x1a\n" + bytes(64), b"", b"PK\x03\x04junk"])
def test_a_file_that_is_no_checkpoint_is_one_clean_line(tmp_path, capsys, content):
    path = tmp_path / "photo.png"
    path.write_bytes(content)
    assert main(["predict", str(path), "--image", str(path)]) == 2
    assert "is not a readable PyTorch checkpoint" in _one_line_error(capsys, "predict", path)
    torch.save({"weights": torch.ones(1)}, tmp_path / "other.pt")
    assert main(["evaluate", str(tmp_path / "other.pt")]) == 2
    assert "not a defocus checkpoint" in _one_line_error(capsys, "evaluate", tmp_path / "other.pt")
    assert main(["predict", str(tmp_path / "missing.pt"), "--image", str(path)]) == 2
    _one_line_error(capsys, "predict", tmp_path / "missing.pt")


def test_checkpoints_hold_only_tensors_and_plain_data(tmp_path, scenes):
    cfg = _tiny(tmp_path / "run", steps=2)
    trainer = Trainer(cfg, scenes)
    trainer.fit()
    state = trainer.state_dict()
    check_plain(state)
    assert state["config"]["out_dir"] == str(cfg.out_dir)
    assert state["rng"]["torch"].dtype == torch.uint8
    loaded = load_checkpoint(cfg.out_dir / "checkpoints" / "last.pt")
    assert set(loaded) == set(state) and loaded["step"] == 2


def test_resume_uses_weights_only_and_gives_the_same_losses(tmp_path, scenes, monkeypatch):
    full = Trainer(_tiny(tmp_path / "full", supervision="depth"), scenes).fit()
    calls = []
    original = torch.load

    def recording_load(*args, **kwargs):
        calls.append(kwargs.get("weights_only"))
        return original(*args, **kwargs)

    monkeypatch.setattr(torch, "load", recording_load)
    cfg = _tiny(tmp_path / "split", checkpoint_every=1, supervision="depth")
    Trainer(cfg, scenes).fit(until=2)
    resumed = Trainer(cfg, scenes)
    assert resumed.step == 2 and calls == [True]
    history = resumed.fit()
    assert [a["loss"] for a in full] == [b["loss"] for b in history]
    Trainer.from_checkpoint(cfg.out_dir / "checkpoints" / "last.pt")
    load_model(cfg.out_dir / "checkpoints" / "step_000002.pt")
    assert calls == [True, True, True]


def _old_state(trainer: Trainer) -> dict:
    """What the code before issue #14 saved (no `format`, no `rng`)."""
    state = trainer.state_dict()
    del state["format"], state["rng"]
    return state


def test_old_plain_checkpoint_still_loads_and_resumes(tmp_path, scenes):
    full = Trainer(_tiny(tmp_path / "full", supervision="depth"), scenes).fit()
    cfg = _tiny(tmp_path / "old", supervision="depth")
    trainer = Trainer(cfg, scenes)
    trainer.fit(until=2)
    torch.save(_old_state(trainer), cfg.out_dir / "checkpoints" / "last.pt")
    resumed = Trainer(cfg, scenes)
    assert resumed.step == 2
    assert [a["loss"] for a in full] == [b["loss"] for b in resumed.fit()]


def test_old_checkpoint_with_objects_is_refused_then_converted(tmp_path, scenes, capsys):
    cfg = _tiny(tmp_path / "run", steps=2)
    trainer = Trainer(cfg, scenes)
    trainer.fit()
    old = _old_state(trainer)
    old["config"]["out_dir"] = pathlib.Path(old["config"]["out_dir"])  # objects, as older code
    old["history"][0]["loss"] = np.float64(old["history"][0]["loss"])
    old["extra"] = {"tags": {"a"}, "mean": np.zeros(3, dtype=np.float32)}
    torch.save(old, tmp_path / "old.pt")
    with pytest.raises(CheckpointError, match=r"pathlib\.\w*Path.*convert-checkpoint --trust"):
        Trainer.from_checkpoint(tmp_path / "old.pt")

    new = tmp_path / "new.pt"
    assert main(["convert-checkpoint", str(tmp_path / "old.pt"), str(new), "--trust"]) == 0
    assert str(new) in capsys.readouterr().out
    state = load_checkpoint(new)
    assert state["config"]["out_dir"] == str(cfg.out_dir) and state["extra"]["tags"] == ["a"]
    assert isinstance(state["extra"]["mean"], torch.Tensor)
    converted = Trainer.from_checkpoint(new)
    image, focused = scenes[0]["image"][None], scenes[0]["focused"][None]
    camera = scenes[0]["camera"].batched(1)
    torch.testing.assert_close(converted.predict(image, focused, camera),
                               trainer.predict(image, focused, camera))
    assert main(["convert-checkpoint", str(new), str(new), "--trust"]) == 2


def test_to_plain_and_check_plain():
    value = {"p": pathlib.Path("a/b"), "n": np.int64(3), "t": (1, [2.0, None]),
             "a": np.arange(3)}
    plain = to_plain(value)
    check_plain(plain)
    assert plain["p"] == "a/b" and plain["n"] == 3 and plain["t"] == (1, [2.0, None])
    assert torch.equal(plain["a"], torch.arange(3))
    with pytest.raises(ValueError, match="pathlib"):
        check_plain(value)
    with pytest.raises(ValueError, match=r"cannot convert checkpoint\['x'\]"):
        to_plain({"x": object()})
    with pytest.raises(ValueError, match="not a tensor or plain data"):
        save_checkpoint({"model": {}, "config": {}, "x": object()}, "never.pt")
    assert not pathlib.Path("never.pt").exists()


def test_store_saves_atomically_lists_and_prunes(tmp_path):
    store = CheckpointStore(tmp_path / "ck", keep=2)
    assert store.list() == [] and not store.exists()
    for step in (1, 2, 3):
        store.save({"model": {}, "config": {}, "step": step}, step)
    assert [p.name for p in store.list()] == ["step_000002.pt", "step_000003.pt"]
    assert sorted(p.name for p in store.directory.iterdir()) == [
        "last.pt", "step_000002.pt", "step_000003.pt"]  # no temporary files left
    assert store.load()["step"] == 3 and store.load(store.path(2))["step"] == 2
    assert store.prune(keep=1) == [store.path(2)]
    assert CheckpointStore(tmp_path / "ck").prune() == []  # keep=0: keep all


def test_trainer_keeps_the_newest_checkpoints(tmp_path, scenes):
    cfg = _tiny(tmp_path / "run", checkpoint_every=1, keep_checkpoints=2, supervision="depth")
    Trainer(cfg, scenes).fit()
    assert {p.name for p in (cfg.out_dir / "checkpoints").iterdir()} == {
        "step_000003.pt", "step_000004.pt", "last.pt"}


def test_csv_log_appends_and_truncates(tmp_path):
    log = CsvLog(tmp_path / "log.csv")
    assert log.rows() == []
    log.truncate(3)
    for step in range(1, 5):
        log.append({"step": step, "loss": step / 10})
    log.truncate(2)
    assert [r["step"] for r in log.rows()] == ["1", "2"]
    assert log.path.read_text().splitlines()[0] == "step,loss"
