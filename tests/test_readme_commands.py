"""The README's `defocus sample` and `defocus predict` commands run as written, in order, in a
fresh folder (the sample set they read is the one `defocus sample` writes)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from defocus.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_commands(subcommands: tuple[str, ...]) -> list[list[str]]:
    """The `defocus SUBCOMMAND ...` lines of the README's bash blocks (continuations joined)."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line.split("  #")[0])
            if len(words) > 1 and words[0] == "defocus" and words[1] in subcommands:
                commands.append(words[1:])
    return commands


def test_the_readme_shows_the_sample_commands():
    commands = readme_commands(("sample", "predict"))
    assert commands[0][0] == "sample" and sum(c[0] == "predict" for c in commands) >= 2


@pytest.mark.slow
def test_readme_sample_and_predict_commands_run_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for argv in readme_commands(("sample", "predict")):
        assert main([*argv, "--quiet"]) == 0, (argv, capsys.readouterr().err)
    truth = np.load(tmp_path / "samples" / "depth.npy")
    constant = np.median(truth)
    stated = readme_expected_figures()
    for run in ("runs/predict", "runs/predict_stack"):
        depth = np.load(tmp_path / run / "depth.npy")
        error = np.mean(np.abs(depth - truth) / truth)
        assert error < 0.6 * np.mean(np.abs(constant - truth) / truth), (run, error)
        assert abs(error - stated[run]) <= 0.02, (run, error, stated[run])  # what users see
        assert (tmp_path / run / "depth.png").is_file()
    # the best constant depth, as the README names it: no other constant scores lower
    best = min((np.mean(np.abs(c - truth) / truth), c) for c in np.arange(1.5, 8.0, 0.01))
    assert abs(best[0] - stated["constant"]) <= 0.005 and abs(best[1] - stated["depth"]) <= 0.02


def readme_expected_figures() -> dict[str, float]:
    """The abs rel the README tells users to expect of its two predict commands, and the best
    constant depth with its abs rel."""
    text = " ".join(README.read_text().split())
    found = re.search(r"about (\d+\.\d+) for `runs/predict` .*? about (\d+\.\d+) for "
                      r"`runs/predict_stack` .*?\((\d+\.\d+) m, chosen on the truth\), scores "
                      r"(\d+\.\d+)", text)
    assert found, "the README states what to expect of the sample commands"
    pair, stack, depth, constant = (float(v) for v in found.groups())
    return {"runs/predict": pair, "runs/predict_stack": stack, "depth": depth,
            "constant": constant}


def test_the_readme_says_what_to_expect_of_the_sample_and_of_make_test():
    figures = readme_expected_figures()
    assert 0 < figures["runs/predict"] < figures["constant"]
    assert "`make test` take about" in " ".join(README.read_text().split())
