"""The front door as a newcomer meets it: `predict` asks for its photos before it looks at an
earlier run's files, the line `defocus sample` suggests runs again and again, and the commands
share one vocabulary (`--focus-distance`, progress unless `--quiet`, help that says what the
demo uses and names only the choices a command has)."""

from __future__ import annotations

import shlex

import pytest

from defocus.cli import COMMANDS, build_parser, main


@pytest.fixture
def earlier_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "predict").mkdir(parents=True)
    (tmp_path / "runs" / "predict" / "depth.npy").write_bytes(b"an earlier run")
    return tmp_path


@pytest.mark.parametrize(("argv", "message"), [
    (["predict"], "give --image (an all-in-focus photo), or 2 or more --focused photos"),
    (["predict", "--image", "missing.png"], "depth from defocus needs --focused photos"),
    (["predict", "--image", "missing.png", "--focused", "{photo}", "--depth-range", "1", "5"],
     "missing file 'missing.png': expected a photo"),
    (["predict", "--focused", "a.png", "b.png", "--depth-range", "1", "5"],
     "missing file 'a.png': expected a photo"),
    (["predict", "--image", "{photo}", "--depth-range", "1", "5"],
     "depth from defocus needs --focused photos"),
])
def test_predict_checks_its_inputs_before_its_outputs(earlier_run, capsys, argv, message):
    photo = earlier_run / "photo.png"
    photo.write_bytes(b"")
    assert main([word.format(photo=photo) for word in argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "already exists" not in err, err
    assert (earlier_run / "runs" / "predict" / "depth.npy").read_bytes() == b"an earlier run"


@pytest.mark.slow
def test_the_line_sample_suggests_runs_twice(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["sample", "samples", "--scale", "0.1"]) == 0
    line = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("try: "))
    argv = shlex.split(line.removeprefix("try: "))
    assert argv[:2] == ["defocus", "predict"] and "--out" in argv
    assert argv[argv.index("--out") + 1] == "samples/predict"  # into the sample folder
    for _ in range(2):
        assert main([*argv[1:], "--quiet"]) == 0, capsys.readouterr().err
    assert (tmp_path / "samples" / "predict" / "depth.npy").is_file()


def test_render_and_predict_name_the_focus_distance_alike():
    for command in ("render", "predict", "calibrate"):
        options = build_parser(command).commands[command].options
        assert "--focus-distance" in options and "--focus" not in options, command


def test_progress_shows_unless_quiet_on_every_command():
    for command in COMMANDS:
        options = build_parser(command).commands[command].options
        assert "--quiet" in options and "--progress" not in options, command


def test_calibrate_shows_progress_unless_quiet(tmp_path, monkeypatch):
    import defocus.app.calibrate as calibrate

    seen = []

    def fake(*args, progress=False):
        seen.append(progress)
        raise RuntimeError("stop here")

    monkeypatch.setattr(calibrate, "calibrate_from_dataset",
                        lambda *args: fake(*args[:-1], progress=args[-1]))
    base = ["calibrate", "--data", "dslr", "--root", str(tmp_path),
            "--out", str(tmp_path / "fit.json")]
    assert main(base) == 1 and main([*base, "--quiet"]) == 1
    assert seen == [True, False]


def test_one_option_names_the_data_of_every_command(capsys):
    """`--data` names what a command reads, in every command (evaluate's focal-stack benchmarks
    among its choices); `--dataset` is no option, and its closest option is named."""
    for command in ("train", "evaluate", "calibrate"):
        options = build_parser(command).commands[command].options
        assert "--data" in options and "--dataset" not in options, command
    evaluate = build_parser("evaluate").commands["evaluate"].options["--data"]
    assert {"ddff12", "zedd", "motorcycle", "nyu"} <= set(evaluate.choices)
    assert "depth metrics" in evaluate.help and "own protocol" in evaluate.help
    with pytest.raises(SystemExit) as stop:
        main(["evaluate", "--dataset", "zedd", "--root", "x"])
    err = capsys.readouterr().err
    assert stop.value.code == 2
    assert len(err.strip().splitlines()) == 1 and "--data" in err, err


def test_train_help_names_only_its_choices_and_what_the_demo_uses(capsys):
    from defocus.app.train import training_config

    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = capsys.readouterr().out
    assert "motorcycle" not in text
    demo = build_parser("demo").commands["demo"].parse_args([])
    overrides = shlex.split("steps=" + text.split("--set steps=", 1)[1].split("--scenes")[0])
    config = training_config(overrides=overrides)
    assert (config.steps, config.width, config.lr, config.batch_size) == \
        (demo.steps, demo.width, demo.lr, demo.batch_size)
    assert f"--scenes {demo.scenes} --size {demo.size} {demo.size}" in text
