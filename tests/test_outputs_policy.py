"""The output policy (issue 39, data lost): inputs are never written, earlier results are kept
unless --overwrite, outputs of one run never collide, nothing is written through a symbolic
link, and a failed write leaves no half file (`defocus.app.outputs`)."""

from __future__ import annotations

import errno
import os
import re

import numpy as np
import pytest
import torch
from PIL import Image

from defocus.app.outputs import OutputPlan, plan_files
from defocus.cli import main
from defocus.errors import OutputError


def _photos(folder, names=("near", "far"), size=(40, 48)):
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in names:
        paths.append(folder / f"{name}.png")
        Image.fromarray((rng.random((*size, 3)) * 255).astype(np.uint8)).save(paths[-1])
    return paths


def _predict(paths, out, *extra):
    return ["predict", "--focused", *map(str, paths), "--focus-distance", "1", "3",
            "--f-number", "2", "--focal-length", "0.05", "--pixel-pitch", "2e-5",
            "--depth-range", "0.5", "5", "--out", str(out), *extra]


def _error(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    return err


# ---- the plan ------------------------------------------------------------------------------
def test_plan_refuses_to_write_an_input(tmp_path):
    photo = tmp_path / "all_in_focus.png"
    photo.write_bytes(b"input")
    with pytest.raises(ValueError, match="input --image .*never written"):
        OutputPlan({"--image": photo}).add(tmp_path / "." / "all_in_focus.png", "photo")
    with pytest.raises(ValueError, match="input --image"):  # even with --overwrite
        OutputPlan({"--image": photo}, overwrite=True).add(photo, "photo")
    assert photo.read_bytes() == b"input"


def test_plan_keeps_an_earlier_result_unless_overwrite(tmp_path):
    (tmp_path / "depth.npy").write_bytes(b"earlier")
    with pytest.raises(FileExistsError, match=r"depth\.npy already exists .*--overwrite"):
        plan_files(tmp_path, {"depth.npy": "depth map"}, overwrite=False)
    plan, paths = plan_files(tmp_path, {"depth.npy": "depth map"}, overwrite=True)
    with plan.writing() as write:
        write(paths["depth.npy"], lambda tmp: tmp.write_bytes(b"new"))
    assert (tmp_path / "depth.npy").read_bytes() == b"new"


def test_plan_refuses_two_outputs_at_one_path(tmp_path):
    plan = OutputPlan()
    plan.add(tmp_path / "fit.png", "calibration JSON")
    with pytest.raises(ValueError, match="would both be written to"):
        plan.add(tmp_path / "fit.png", "calibration figure")


def test_plan_never_writes_through_a_symbolic_link(tmp_path):
    outside = tmp_path / "outside.npy"
    outside.write_bytes(b"keep me")
    out = tmp_path / "out"
    out.mkdir()
    (out / "depth.npy").symlink_to(outside)
    with pytest.raises(ValueError, match="symbolic link"):
        OutputPlan(overwrite=True).add(out / "depth.npy", "depth map")
    assert outside.read_bytes() == b"keep me"


def test_a_failed_write_leaves_no_half_file_and_the_earlier_ones(tmp_path):
    first, second = tmp_path / "a.json", tmp_path / "b.png"
    first.write_text("earlier a")
    plan = OutputPlan(overwrite=True)
    plan.add(first, "table")
    plan.add(second, "figure")

    def full_disk(path):
        path.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OutputError, match=r"cannot write .*b\.png: No space left on device"):
        with plan.writing() as write:
            write(first, lambda tmp: tmp.write_text("new a"))
            write(second, full_disk)
    assert first.read_text() == "earlier a"  # all or nothing: the first is not replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]  # no temporary left


def test_overwrite_removes_the_earlier_outputs_this_run_does_not_write(tmp_path):
    names = {"depth.npy": "depth map", "confidence.png": "confidence map"}
    for name in (*names, "notes.txt"):
        (tmp_path / name).write_bytes(b"earlier")
    plan, paths = plan_files(tmp_path, names, overwrite=True)
    with plan.writing(remove_unwritten=True) as write:
        write(paths["depth.npy"], lambda tmp: tmp.write_bytes(b"new"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["depth.npy", "notes.txt"]
    assert plan.removed == [paths["confidence.png"]]
    assert (tmp_path / "notes.txt").read_bytes() == b"earlier"  # not an output: kept


def test_an_unwritten_output_is_kept_when_the_run_fails(tmp_path):
    (tmp_path / "confidence.png").write_bytes(b"earlier")
    plan, paths = plan_files(tmp_path, {"depth.npy": "depth map",
                                        "confidence.png": "confidence map"}, overwrite=True)
    with pytest.raises(RuntimeError):
        with plan.writing(remove_unwritten=True) as write:
            write(paths["depth.npy"], lambda tmp: tmp.write_bytes(b"new"))
            raise RuntimeError("the run fails before its last output")
    assert (tmp_path / "confidence.png").read_bytes() == b"earlier" and not plan.removed


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0,
                    reason="needs a user whom file permissions bind")
def test_a_read_only_folder_is_one_line(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        plan = OutputPlan()
        plan.add(folder / "m.json", "table")
        with pytest.raises(PermissionError, match="cannot write .*m.json: permission denied"):
            with plan.writing() as write:
                write(folder / "m.json", lambda tmp: tmp.write_text("{}"))
    finally:
        folder.chmod(0o700)


# ---- the commands --------------------------------------------------------------------------
def test_predict_never_writes_over_its_input_photo(tmp_path, capsys):
    out = tmp_path / "out"
    paths = _photos(out, ("all_in_focus", "near", "far"))
    before = paths[0].read_bytes()
    argv = _predict(paths[1:], out, "--image", str(paths[0]), "--overwrite")
    assert main(argv) == 2
    assert "--image" in _error(capsys) and paths[0].read_bytes() == before


def test_predict_keeps_earlier_results_unless_overwrite(tmp_path, capsys):
    paths = _photos(tmp_path)
    out = tmp_path / "out"
    assert main(_predict(paths, out)) == 0
    first = np.load(out / "depth.npy")
    capsys.readouterr()
    assert main(_predict(paths, out)) == 2
    err = _error(capsys)
    assert "depth.npy already exists" in err and "--overwrite" in err
    assert main(_predict(paths, out, "--overwrite")) == 0
    np.testing.assert_array_equal(np.load(out / "depth.npy"), first)  # same depth map
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_predict_overwrite_leaves_no_output_of_the_earlier_run(tmp_path, capsys):
    """A network gives no confidence map: the label-free run's confidence.png goes, so the
    folder never mixes two runs (said in the summary)."""
    from datasets.synthetic import SyntheticScenes
    from models.training import TrainConfig, Trainer

    config = TrainConfig(steps=1, batch_size=1, width=4, out_dir=tmp_path / "run",
                         progress=False, supervision="depth", depth_min=0.6, depth_max=4.5)
    Trainer(config, SyntheticScenes(1, (16, 16), seed=0)).fit()
    paths = _photos(tmp_path, ("aif", "near", "far"))
    out = tmp_path / "out"
    assert main(_predict(paths[1:], out, "--image", str(paths[0]))) == 0
    assert (out / "confidence.png").is_file()
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    argv = ["predict", str(tmp_path / "run" / "checkpoints" / "last.pt"), "--image",
            str(paths[0]), "--focused", *map(str, paths[1:]), "--focus-distance", "1", "3",
            "--f-number", "2", "--focal-length", "0.05", "--pixel-pitch", "2e-5", "--out",
            str(out), "--overwrite", "--quiet"]
    assert main(argv) == 0
    assert "removed confidence.png of the earlier run" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["depth.npy", "depth_mm.png", "depth.png", "all_in_focus.png", "figure.png",
         "notes.txt"])


def test_predict_refuses_a_symbolic_link_in_out(tmp_path, capsys):
    paths = _photos(tmp_path)
    outside = tmp_path / "elsewhere.png"
    outside.write_bytes(b"keep me")
    out = tmp_path / "out"
    out.mkdir()
    (out / "figure.png").symlink_to(outside)
    assert main(_predict(paths, out, "--overwrite")) == 2
    assert "symbolic link" in _error(capsys) and outside.read_bytes() == b"keep me"


def test_calibrate_refuses_a_figure_over_its_json(tmp_path, capsys):
    argv = ["calibrate", "--pair", "a.dng", "b.dng", "2", "--out", str(tmp_path / "fit.png")]
    assert main(argv) == 2
    assert "would both be written" in _error(capsys)


def test_calibrate_never_writes_a_file_of_the_dataset(tmp_path, capsys):
    root = tmp_path / "data"
    root.mkdir()
    (root / "depth.png").write_bytes(b"input depth")
    argv = ["calibrate", "--data", "dslr", "--root", str(root), "--figure",
            str(root / "depth.png"), "--out", str(tmp_path / "fit.json"), "--overwrite"]
    assert main(argv) == 2
    assert "--root" in _error(capsys) and (root / "depth.png").read_bytes() == b"input depth"


def test_evaluate_json_keeps_an_earlier_result_and_the_checkpoint(tmp_path, capsys):
    earlier = tmp_path / "metrics.json"
    earlier.write_text("{}")
    assert main(["evaluate", str(tmp_path / "ck.pt"), "--json", str(earlier)]) == 2
    assert "--overwrite" in _error(capsys) and earlier.read_text() == "{}"
    checkpoint = tmp_path / "ck.pt"
    checkpoint.write_bytes(b"weights")
    assert main(["evaluate", str(checkpoint), "--json", str(checkpoint), "--overwrite"]) == 2
    assert "CHECKPOINT" in _error(capsys) and checkpoint.read_bytes() == b"weights"


def test_convert_checkpoint_keeps_the_target_when_it_fails(tmp_path, capsys):
    source, target = tmp_path / "old.pt", tmp_path / "new.pt"
    torch.save({"not": torch.zeros(1)}, source)  # converts, but is no defocus checkpoint
    target.write_bytes(b"earlier")
    assert main(["convert-checkpoint", str(source), str(target), "--trust"]) == 2
    assert "--overwrite" in _error(capsys)
    assert main(["convert-checkpoint", str(source), str(target), "--trust", "--overwrite"]) == 2
    assert "left as it was" in _error(capsys)
    assert target.read_bytes() == b"earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.pt", "old.pt"]


def test_render_and_demo_keep_earlier_results(tmp_path, capsys):
    (tmp_path / "focus_sweep.png").write_bytes(b"earlier")
    assert main(["render", "--out", str(tmp_path), "--scale", "0.1"]) == 2
    assert "focus_sweep.png already exists" in _error(capsys)
    (tmp_path / "metrics.json").write_text("{}")
    assert main(["demo", "--out", str(tmp_path), "--steps", "1"]) == 2
    assert "--overwrite" in _error(capsys)
    assert (tmp_path / "metrics.json").read_text() == "{}"


# ---- the example scripts' --json and train's run folder -------------------------------------
def test_benchmark_example_json_keeps_an_earlier_table_and_the_dataset(tmp_path, monkeypatch):
    from test_examples import _benchmark_fixtures, load_example

    write, extra = _benchmark_fixtures()["zedd"]
    root = tmp_path / "data"
    write(root)
    module = load_example("zedd", monkeypatch)
    earlier = tmp_path / "metrics.json"
    earlier.write_text("{}")
    argv = ["--root", str(root), "--device", "cpu", *extra, "--json"]
    with pytest.raises(SystemExit, match=r"metrics\.json already exists .*--overwrite"):
        module.main([*argv, str(earlier)])
    assert earlier.read_text() == "{}"
    data_file = next(p for p in sorted(root.rglob("*")) if p.is_file())
    before = data_file.read_bytes()
    with pytest.raises(SystemExit, match="input --root .*never written"):
        module.main([*argv, str(data_file), "--overwrite"])
    assert data_file.read_bytes() == before


def test_dslr_example_json_is_checked_before_any_work(tmp_path, monkeypatch):
    from test_examples import load_example

    module = load_example("dslr", monkeypatch)
    earlier, camera = tmp_path / "table.json", tmp_path / "cam.json"
    earlier.write_text("{}")
    camera.write_text("{}")
    argv = ["--root", str(tmp_path / "absent"), "--out", str(tmp_path / "run"), "--set"]
    with pytest.raises(SystemExit, match=r"table\.json already exists .*--overwrite"):
        module.main([*argv, f"json={earlier}"])  # refused before the missing --root is read
    with pytest.raises(SystemExit, match="input camera"):
        module.main([*argv, f"json={camera}", f"camera={camera}", "--overwrite"])
    assert earlier.read_text() == "{}" and camera.read_text() == "{}"


def test_train_refuses_an_out_that_is_a_file_or_the_dataset(tmp_path, capsys):
    from test_datasets_fixtures import write_nyu

    root = tmp_path / "nyu"
    write_nyu(root)
    before = sorted(p.name for p in root.rglob("*"))
    for out, message in ((root, "--out .* is the input --root"),
                         (root / "run", "--out .* lies inside the input --root")):
        assert main(["train", "--data", "nyu", "--root", str(root), "--out", str(out),
                     "--set", "steps=1", "--overwrite"]) == 2
        assert re.search(message, _error(capsys))
    assert sorted(p.name for p in root.rglob("*")) == before
    a_file = tmp_path / "notes.txt"
    a_file.write_text("mine")
    assert main(["train", "--out", str(a_file), "--set", "steps=1"]) == 2
    assert f"--out {a_file} is a file, not a folder" in _error(capsys)
    assert a_file.read_text() == "mine"


def test_train_overwrite_never_deletes_the_config_it_reads(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("steps: 1  # mine\n")
    assert main(["train", "--config", str(run / "config.yaml"), "--out", str(run),
                 "--overwrite"]) == 2
    assert "which --overwrite deletes" in _error(capsys)
    assert (run / "config.yaml").read_text() == "steps: 1  # mine\n"


def test_depth_beyond_what_depth_mm_holds_is_said(tmp_path):
    from defocus.app.predict import Photos, write_outputs

    depth = torch.full((1, 6, 8), 30.0)
    depth[0, :3] = 100.0  # half the pixels beyond 65.535 m
    out = {"depth": depth, "confidence": None, "all_in_focus": torch.rand(3, 6, 8),
           "depth_range": (10.0, 200.0)}
    photos = Photos(None, torch.rand(1, 3, 6, 8), None, [], tmp_path / "a.png")
    with pytest.warns(UserWarning, match=r"50.0% of the depth lies beyond 65.535 m"):
        write_outputs(tmp_path / "out", out, photos)
    saved = np.asarray(Image.open(tmp_path / "out" / "depth_mm.png"))
    assert saved.max() == 65535 and saved.min() == 30000
    assert np.load(tmp_path / "out" / "depth.npy").max() == 100.0
