"""Each example script trains and evaluates end to end on fixture data in its dataset's format."""

from __future__ import annotations

import importlib.util
import re
import time
from pathlib import Path

import pytest
from test_datasets_fixtures import (
    write_kitti,
    write_lightfield,
    write_make3d,
    write_middlebury,
    write_nyu,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load_example(name: str, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))  # some scripts import helpers beside them
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_lightfield_splits(root: Path) -> None:
    write_lightfield(root, n=2, h=24, w=32)  # native size: no resampling of the views
    (root / "train.txt").write_text("IMG_0000_eslf.png\n")
    (root / "test.txt").write_text("IMG_0001_eslf.png\n")


FIXTURES = {
    "nyu": write_nyu,
    "kitti": write_kitti,
    "make3d": write_make3d,
    "lightfield": write_lightfield_splits,
    "middlebury": write_middlebury,
}


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_example_help(name, monkeypatch, capsys):
    module = load_example(name, monkeypatch)
    with pytest.raises(SystemExit) as exit_info:
        module.main(["--help"])
    assert exit_info.value.code == 0
    help_text = capsys.readouterr().out
    assert "--root" in help_text and "--set" in help_text and "steps =" in help_text
    assert "--root" in module.__doc__ or "root" in module.__doc__  # header says what to put there


#: Options besides the defaults: Make3D's protocol resizes photos to 460x345, which would make a
#: 300k-pixel data set of the 24x18 fixture photos; a tenth of that size keeps the run small.
EXTRA = {"make3d": ["--size", "46", "35"]}
#: The example options of the tests: no progress bars, on the CPU (`defocus train`'s `--set`).
QUIET_CPU = ["--set", "progress=false", "device=cpu"]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_example_trains_and_evaluates(name, tmp_path, monkeypatch, capsys):
    """Each example with its default budget on fixture data: plans, trains, prints the table."""
    root = tmp_path / "data"
    FIXTURES[name](root)
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(tmp_path / "cache"))
    module = load_example(name, monkeypatch)
    argv = ["--root", str(root), "--out", str(tmp_path / "run"), *QUIET_CPU,
            *EXTRA.get(name, [])]
    started = time.perf_counter()
    assert module.main(argv) == 0
    elapsed = time.perf_counter() - started
    out = capsys.readouterr().out
    assert "s/step" in out and "plan:" in out and "ETA" in out and "budget 10 min" in out
    planned = int(re.search(r"plan: (\d+) steps", out).group(1))
    assert 10 <= planned <= 1000
    trained = int(re.search(r"trained (\d+) steps", out).group(1))  # the budget may cut it
    assert "| method" in out and f"ours (small, aif+focused, {trained} steps)" in out
    if name == "lightfield":
        assert "loss" in out
    else:
        assert "abs rel" in out and "best constant depth" in out
    assert (tmp_path / "run" / "train_log.csv").is_file()
    assert elapsed < 600, f"{name} took {elapsed:.0f} s with its defaults"
    if name not in ("dslr", "lightfield"):  # synthesised focal stacks went to the cache
        assert list((tmp_path / "cache" / "focal_stacks").glob("*.pt"))


def run_middlebury(tmp_path, monkeypatch, size, *settings):
    """The Middlebury example on a fixture of `size` (h, w) with `--set` `settings`, quiet, on
    the CPU, into `tmp_path / "run"`; returns the fixture's folder."""
    root = tmp_path / "data"
    write_middlebury(root, h=size[0], w=size[1])
    module = load_example("middlebury", monkeypatch)
    assert module.main(["--root", str(root), "--out", str(tmp_path / "run"), *QUIET_CPU,
                        "cache=false", *settings]) == 0
    return root


@pytest.mark.slow
def test_example_trains_on_crops(tmp_path, monkeypatch, capsys):
    """`--crop` smaller than the images: training sees crops, evaluation whole images."""
    run_middlebury(tmp_path, monkeypatch, (20, 30), "steps=3", "batch_size=2", "width=8",
                   "crop=[8,12]")
    out = capsys.readouterr().out
    assert "random (8, 12) crops of (20, 30) pixels" in out
    assert "plan: 3 steps" in out and "ours (small, aif+focused, 3 steps)" in out


def test_example_passes_the_smoothness_weight_to_the_run(tmp_path, monkeypatch, capsys):
    run_middlebury(tmp_path, monkeypatch, (12, 16), "steps=1", "batch_size=1", "width=4",
                   "smoothness_weight=0.05")
    assert "smoothness_weight: 0.05" in (tmp_path / "run" / "config.yaml").read_text()


def test_example_learns_optics_where_focus_is_synthesised(tmp_path, monkeypatch, capsys):
    """`--set learn_optics=...` on synthesised focus trains the camera with the network (its
    camera.json in the run folder); on real focused photos it is refused before any work."""
    root = run_middlebury(tmp_path, monkeypatch, (12, 16), "steps=1", "batch_size=1",
                          "width=4", "learn_optics=focus")
    assert "ours (small, aif+focused, 1 steps)" in capsys.readouterr().out
    assert "learn_optics: focus" in (tmp_path / "run" / "config.yaml").read_text()
    assert (tmp_path / "run" / "camera.json").is_file()
    write_lightfield_splits(tmp_path / "lf")
    with pytest.raises(SystemExit, match="--learn-optics focus: the lightfield data's focused"):
        load_example("lightfield", monkeypatch).main(
            ["--root", str(tmp_path / "lf"), "--out", str(tmp_path / "lf_run"), *QUIET_CPU,
             "learn_optics=focus"])
    dslr = load_example("dslr", monkeypatch)
    with pytest.raises(SystemExit, match="--learn-optics mask: the dslr data's focused"):
        dslr.main(["--root", str(root), "--out", str(tmp_path / "d_run"),
                   "--set", "learn_optics=mask"])
    assert not (tmp_path / "lf_run").exists() and not (tmp_path / "d_run").exists()


def test_example_rejects_bad_crop(monkeypatch, tmp_path):
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(tmp_path / "cache"))
    module = load_example("middlebury", monkeypatch)
    with pytest.raises(SystemExit, match="crop takes one or two sizes"):
        module.main(["--root", "builtin", "--set", "crop=[1,2,3]", "--out", str(tmp_path)])


# ---- the focal-stack benchmark examples: score a label-free method on fixture files ------------

def _benchmark_fixtures():
    from test_datasets_stacks import write_ddff12, write_fod500, write_mobile_depth, write_zedd

    return {
        "ddff12": (lambda root: write_ddff12(root, n=2, h=24, w=32), ["--shots", "0", "3", "6", "9"]),
        "fod500": (lambda root: write_fod500(root, scenes=(400, 401), size=24), []),
        # a focal length of 60 px: blur that changes by 0.8 px over the depth range (at 20 px,
        # 0.27 px, which estimate_depth refuses as unreadable)
        "zedd": (lambda root: write_zedd(root, scenes=2, h=24, w=36, focal_px=60.0), []),
        "mobile_depth": (lambda root: write_mobile_depth(root, h=48, w=96), []),
    }


BENCHMARK_EXAMPLES = ("ddff12", "fod500", "zedd", "mobile_depth")


@pytest.mark.parametrize("name", BENCHMARK_EXAMPLES)
def test_benchmark_example_scores_fixture_data(name, tmp_path, monkeypatch, capsys):
    """Each benchmark example with its CPU defaults on files in the release format."""
    write, extra = _benchmark_fixtures()[name]
    write(tmp_path / "data")
    module = load_example(name, monkeypatch)
    out = tmp_path / "metrics.json"
    argv = ["--root", str(tmp_path / "data"), "--device", "cpu", "--json", str(out), *extra]
    started = time.perf_counter()
    assert module.main(argv) == 0
    assert time.perf_counter() - started < 120
    text = capsys.readouterr().out
    assert "--root" in module.__doc__ and "--device cuda" in module.__doc__  # GPU command
    if name == "mobile_depth":
        assert "judge the depth maps by eye" in text and not out.exists()
    else:
        assert "| method" in text and "abs rel" in text and "protocol:" in text
        assert out.is_file()


@pytest.mark.parametrize("name", BENCHMARK_EXAMPLES)
def test_benchmark_example_help(name, monkeypatch, capsys):
    module = load_example(name, monkeypatch)
    with pytest.raises(SystemExit) as exit_info:
        module.main(["--help"])
    assert exit_info.value.code == 0
    assert "--root" in capsys.readouterr().out


# ---- the DSLR protocol: calibrate on the training scenes, two networks, predict, constant -------

REAL_DSLR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "dfd_indoor"


def _check_dslr_table(out: str, scenes: int) -> None:
    assert f"DSLR validation ({scenes} scenes, never used to fit or train; real focus; seed 0;" \
        in out
    assert "order ↑ |" in out  # the networks' depth order beside the paper's metrics
    for row in ("[self-supervised", "[depth-supervised]", "label-free predict",
                "[self-supervised, f/8 photo alone (the paper's setting)",
                "[depth-supervised, f/8 photo alone (the paper's setting)]", "best constant depth",
                "bound: the true depth through one focus plane, side beyond"):
        assert row in out
    assert out.count("x the constant's") == 7  # four networks, the constant, bound, predict


def test_dslr_example_help(monkeypatch, capsys):
    module = load_example("dslr", monkeypatch)
    with pytest.raises(SystemExit) as exit_info:
        module.main(["--help"])
    assert exit_info.value.code == 0
    assert "val: 20" in capsys.readouterr().out and "dfd_indoor" in module.__doc__


@pytest.mark.slow
def test_dslr_example_on_a_rendered_release(tmp_path, monkeypatch, capsys):
    """The whole protocol on a release rendered with a known camera (7 scenes, 2 held out)."""
    import json

    from test_dslr import write_rendered_release

    write_rendered_release(tmp_path / "data")
    module = load_example("dslr", monkeypatch)
    argv = ["--root", str(tmp_path / "data"), "--out", str(tmp_path / "run"), "--set",
            *QUIET_CPU[1:], "val=2", "steps=2", "batch_size=2", "width=8", "calibrate_every=1",
            "crop=48", "hint_weight=1", "predict_side=beyond", "predict_pixels=4000",
            "predict_smoothing=300"]
    assert module.main(argv) == 0
    out = capsys.readouterr().out
    _check_dslr_table(out, 2)
    # depth hints of the real pairs: the label-free depth of the photos as taken, side beyond
    assert "[self-supervised, side beyond, depth hints]" in out
    assert "hint,hint_share" in (tmp_path / "run" / "self" / "train_log.csv").read_text()
    assert "camera fitted on 5 training scenes" in out
    assert (tmp_path / "run" / "camera.json").is_file()
    # rendered with the thin lens it was fitted to: the loss agrees with the fitted blur
    matched = json.loads((tmp_path / "run" / "camera_loss.json").read_text())
    assert 0.9 <= matched["loss_blur_scale"] <= 1.1
    assert "the networks train with" in out
    assert (tmp_path / "run" / "self" / "train_log.csv").is_file()
    assert (tmp_path / "run" / "depth" / "train_log.csv").is_file()
    with pytest.raises(SystemExit, match="val must leave training scenes"):
        module.main(["val=7" if arg == "val=2" else arg for arg in argv])


@pytest.mark.slow
def test_dslr_example_trains_on_one_split_and_scores_another(tmp_path, monkeypatch, capsys):
    """--eval-split test: every scene of --split trains, the other split is scored (the paper's
    protocol); --json writes each row of the table."""
    import json

    from test_dslr import write_rendered_release

    write_rendered_release(tmp_path / "data", scenes=5)
    write_rendered_release(tmp_path / "data", scenes=2, split="test")
    module = load_example("dslr", monkeypatch)
    table = tmp_path / "out" / "table.json"
    argv = ["--root", str(tmp_path / "data"), "--out", str(tmp_path / "run"), *QUIET_CPU,
            "eval_split=test", f"json={table}", "steps=2", "batch_size=2", "width=8",
            "calibrate_every=1", "crop=48", "inputs=[aif+focused]", "blur_match=false"]
    assert module.main(argv) == 0
    out = capsys.readouterr().out
    assert not (tmp_path / "run" / "camera_loss.json").exists()
    assert "camera fitted on 5 training scenes" in out
    assert "DSLR test split (2 scenes, never used to fit or train; real focus; seed 0;" in out
    rows = json.loads(table.read_text())
    names = " ".join(rows)
    for row in ("[self-supervised, side beyond]", "[depth-supervised]", "label-free predict",
                "best constant depth",
                # what one focus plane allows on the scored (test) scenes
                "bound: the true depth through one focus plane, side beyond"):
        assert row in names
    assert "the paper's setting" not in names
    check_table_rows(rows)
    assert {(row["input"], row["supervision"]) for row in rows.values()} == {
        ("aif+focused", "self"), ("aif+focused", "depth"), ("aif+focused", "none"),
        ("none", "none")}


def check_table_rows(rows: dict) -> None:
    """Each row of a table JSON: its metrics (the depth metrics and the depth order), what it
    reads, how it learned, the seed."""
    for name, row in rows.items():
        assert set(row) == {"metrics", "input", "supervision", "seed"}, name
        assert set(row["metrics"]) >= {"abs_rel", "rmse", "delta1", "depth_order"}, name
        assert -1 <= row["metrics"]["depth_order"] <= 1 and row["seed"] == 0
        assert row["input"] in ("aif", "aif+focused", "none")
        assert row["supervision"] in ("self", "depth", "none")
        assert (row["supervision"] in ("self", "depth")) == name.startswith("ours"), name


@pytest.mark.slow
def test_dslr_example_synthesized_focus_on_one_split_scores_another(tmp_path, monkeypatch,
                                                                      capsys):
    """--focus synthesized --eval-split test --json: the paper's way on the release layout:
    every scene of the training split trains, the test split is scored; the two focused images
    are rendered from the f/8 photo and the depth, nothing is calibrated."""
    import json

    from test_dslr import write_rendered_release

    root = tmp_path / "data"
    write_rendered_release(root, scenes=3, h=48, w=72)
    write_rendered_release(root, scenes=2, h=48, w=72, split="test")
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(tmp_path / "cache"))
    module = load_example("dslr", monkeypatch)
    table = tmp_path / "table.json"
    argv = ["--root", str(root), "--out", str(tmp_path / "run"), "--focus", "synthesized",
            "--eval-split", "test", *QUIET_CPU, f"json={table}", "steps=1", "batch_size=2",
            "width=4", "crop=32", "predict_pixels=4000", "hint_weight=1"]
    assert module.main(argv) == 0
    out = capsys.readouterr().out
    # the self-supervised networks train with depth hints, their twins without
    assert "[self-supervised, depth hints]" in out and "[depth-supervised]" in out
    assert "hint,hint_share" in (tmp_path / "run" / "self" / "train_log.csv").read_text()
    assert "hint" not in (tmp_path / "run" / "depth" / "train_log.csv").read_text()
    assert "DSLR: 3 training scenes, 2 test split scenes" in out
    assert "rendered with f/2.8 focused at 2, 8 m (focal length 35 mm" in out
    assert "camera fitted" not in out and not (tmp_path / "run" / "camera.json").exists()
    assert "DSLR test split (2 scenes, never used to fit or train; synthesized focus" in out
    rows = json.loads(table.read_text())
    check_table_rows(rows)
    assert not any(name.startswith("bound") for name in rows)  # two planes: no side prior
    assert {(row["input"], row["supervision"]) for row in rows.values()} == {
        ("aif+focused", "self"), ("aif+focused", "depth"), ("aif", "self"), ("aif", "depth"),
        ("aif+focused", "none"), ("none", "none")}
    assert "side beyond" not in " ".join(rows)
    for folder in ("self", "depth", "self-aif", "depth-aif"):
        assert (tmp_path / "run" / folder / "train_log.csv").is_file()
    # the two spellings of one key, and the real photos' keys, are refused before any work
    for extra, message in ((["eval_split=train"], "--eval-split test and --set eval_split"),
                           (["side=beyond"], "--set side=beyond: the real f/2.8 photos'"),
                           (["blur_match=false"], "--set blur_match=False")):
        with pytest.raises(SystemExit, match=message):
            module.main([*argv, *extra, "--overwrite"])


def test_dslr_example_refuses_focus_fractions_of_real_photos(tmp_path, monkeypatch):
    """The focus planes of synthesised focus are refused with the real photos, before any
    work (the real pairs are focused where they were taken)."""
    from test_dslr import write_rendered_release

    write_rendered_release(tmp_path / "data", scenes=3, h=48, w=72)
    module = load_example("dslr", monkeypatch)
    with pytest.raises(SystemExit, match="focus_fractions=.0.2.: where the synthesised"):
        module.main(["--root", str(tmp_path / "data"), "--out", str(tmp_path / "run"),
                     "--set", "focus_fractions=[0.2]"])
    for bad in ("-1", "x", "inf"):
        with pytest.raises(SystemExit, match=f"predict_smoothing must be a finite number >= 0, "
                                             f"got {bad if bad == '-1' else '.*'}"):
            module.main(["--root", str(tmp_path / "data"), "--out", str(tmp_path / "run"),
                         "--set", f"predict_smoothing={bad}"])
    for bad in ("[]", "[stereo]", "aif"):
        with pytest.raises(SystemExit, match="inputs must list aif.focused, aif or both"):
            module.main(["--root", str(tmp_path / "data"), "--out", str(tmp_path / "run"),
                         "--set", f"inputs={bad}"])
    assert not (tmp_path / "run").exists()


def test_code_side_example_tells_the_sides_through_a_code_only(tmp_path, monkeypatch, capsys):
    """One focus plane on a release in its layout: the disk scores chance exactly, a random
    code well above it; a checkpoint without a learned mask and a bad --val are refused."""
    import re

    from test_dslr import write_rendered_release

    write_rendered_release(tmp_path / "data", scenes=3)  # 144 pixels wide: blurs of 1-2 px
    module = load_example("code_side", monkeypatch)
    assert module.main(["--root", str(tmp_path / "data"), "--val", "2", "--quiet",
                        "--focus-fraction", "0.6"]) == 0
    out = capsys.readouterr().out
    assert "focused at 6 m, 2 scenes of train: the share" in out
    assert "open disk: 0.500 of" in out
    assert float(re.search(r"random code \(seed 0\): ([0-9.]+)", out).group(1)) > 0.7
    with pytest.raises(SystemExit, match="--val must be in 1..3"):
        module.main(["--root", str(tmp_path / "data"), "--val", "0"])
    with pytest.raises(SystemExit, match="give --sweep"):
        module.main(["--root", str(tmp_path / "data"), "--val", "1", "--focus-fraction", "0.2",
                     "0.8"])
    assert module.main(["--root", str(tmp_path / "data"), "--val", "1", "--quiet", "--sweep",
                        "--focus-fraction", "0.2", "0.8"]) == 0
    out = capsys.readouterr().out
    assert "focused at 2 and 8 m, 1 scenes of train\n" in out and " of 0 pixels" not in out
    sweeps = re.findall(r": label-free sweep abs rel ([0-9.]+), label-free sweep order", out)
    assert len(sweeps) == 2, out


@pytest.mark.slow
@pytest.mark.skipif(not REAL_DSLR.is_dir(), reason="../shared/data/real/dfd_indoor is absent")
def test_dslr_example_on_five_real_scenes(tmp_path, monkeypatch, capsys):
    module = load_example("dslr", monkeypatch)
    argv = ["--root", str(REAL_DSLR), "--out", str(tmp_path / "run"), *QUIET_CPU,
            "max_scenes=5", "val=2", "steps=2", "calibrate_every=1"]
    assert module.main(argv) == 0
    _check_dslr_table(capsys.readouterr().out, 2)


def test_dslr_example_bounds_each_side_without_a_prior(tmp_path, monkeypatch):
    """The bound rows score the scenes given (the scored split's): with side both, one per
    side; with synthesised focus (two focus planes) none."""
    from test_datasets_fixtures import write_dslr_release

    from datasets import DSLR

    write_dslr_release(tmp_path)
    module = load_example("dslr", monkeypatch)
    scenes = DSLR(tmp_path)
    rows = module.bound_rows(scenes, (0.5, 10.0), "both")
    assert sorted(rows) == [f"bound: the true depth through one focus plane, side {side}"
                            for side in ("before", "beyond")]
    assert all(set(row) >= {"abs_rel", "depth_order"} for row in rows.values())
    assert list(module.bound_rows(scenes, (0.5, 10.0), "beyond")) == [
        "bound: the true depth through one focus plane, side beyond"]
    assert module.bound_rows(DSLR(tmp_path, focus="synthesized"), (0.5, 10.0), "both") == {}


def test_dslr_example_states_the_side_of_training_and_scored_scenes(tmp_path, monkeypatch):
    """`scored=` and `trained=` keep the scenes whose true depth lies on the stated side of
    their focus plane (the bound alone); none kept stops the run, a bad side is refused."""
    import imageio.v3 as iio
    import numpy as np
    from test_datasets_fixtures import write_dslr_release

    written = write_dslr_release(tmp_path)
    depth_dir = tmp_path / "dfd_dataset_indoor_N2_8" / "depth" / "train"
    for far, scene in zip((True, False, True), written.values(), strict=True):
        depth = np.full((12, 16), 6000, np.uint16)  # beyond any focus plane of the lens
        depth[:, :8] = 6000 if far else 1000  # half the scene before it (1.7 m)
        iio.imwrite(depth_dir / scene["depth_file"], depth)
    module = load_example("dslr", monkeypatch)
    stated = {"depth_range": (0.5, 10.0), "tolerance": 0.1}
    assert module.stated_scenes(tmp_path, "train", None, "trained", "beyond", **stated) == [0, 2]
    assert module.stated_scenes(tmp_path, "train", [1, 2], "scored", "beyond",
                                **stated) == [2]
    with pytest.raises(SystemExit, match="scored=before: none of the 2 held-out scenes lies "
                                         "before"):
        module.stated_scenes(tmp_path, "train", [0, 2], "scored", "before", **stated)
    with pytest.raises(SystemExit, match=r"trained=all\|beyond\|before .* trained='sideways'"):
        module.main(["--root", str(tmp_path), "--set", "trained=sideways"])
