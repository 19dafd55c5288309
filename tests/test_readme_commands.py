"""The README's code blocks run as a user runs them: its bash blocks (but `make demo` and
`make test`, which are too slow here) and its Python snippets, in a fresh `bash` whose `PATH`
holds no virtual environment, in a fresh folder where `.venv` is the environment that runs these
tests (as `make demo` leaves it). Only the README's own set-up lines (`source .venv/bin/activate`)
make `defocus` and the project's `python` reachable: a README without them fails here."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
#: A README line that sets up the shell (the others are the commands a user runs).
SETUP = re.compile(r"^(source|\.)\s+\S*\.venv/bin/activate\b")


def readme_blocks(language: str) -> list[str]:
    """The README's code blocks in `language`, in order."""
    return re.findall(rf"```{language}\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def readme_commands(subcommands: tuple[str, ...]) -> list[list[str]]:
    """The `defocus SUBCOMMAND ...` lines of the README's bash blocks (continuations joined)."""
    commands = []
    for block in readme_blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if len(words) > 1 and words[0] == "defocus" and words[1] in subcommands:
                commands.append(words[1:])
    return commands


def user_blocks() -> list[str]:
    """The bash blocks a user runs after `make demo`: every block but the `make` ones."""
    return [block for block in readme_blocks("bash")
            if not any(line.lstrip().startswith("make ") for line in block.splitlines())]


def setup_lines() -> list[str]:
    """The README's set-up lines of the user's blocks (activating `.venv`)."""
    return [line for block in user_blocks() for line in block.splitlines()
            if SETUP.match(line.strip())]


def fresh_shell(folder: Path) -> dict[str, str]:
    """The environment of a new terminal: the virtual environment that runs the tests neither
    active nor on `PATH`; `folder/.venv` is that environment (as `make demo` leaves it)."""
    venv = Path(sys.prefix)
    if venv == Path(sys.base_prefix) or not (venv / "bin" / "defocus").is_file():
        pytest.skip("the tests do not run in a virtual environment with `defocus` installed")
    (folder / ".venv").symlink_to(venv, target_is_directory=True)
    bins = {str(venv / "bin"), str(venv.resolve() / "bin")}
    env = {name: value for name, value in os.environ.items() if name != "VIRTUAL_ENV"}
    env["PATH"] = os.pathsep.join(part for part in env.get("PATH", "").split(os.pathsep)
                                  if part.rstrip("/") not in bins)
    return env


def bash(script: str, folder: Path, env: dict[str, str], timeout: float = 1200):
    return subprocess.run(["bash", "-c", f"set -e\n{script}"], cwd=folder, env=env, text=True,
                          capture_output=True, timeout=timeout)


def test_the_readme_shows_the_sample_commands_after_its_set_up_line():
    commands = readme_commands(("sample", "predict"))
    assert commands[0][0] == "sample" and sum(c[0] == "predict" for c in commands) >= 2
    block = next(block for block in user_blocks() if "defocus sample" in block)
    assert SETUP.match(block.splitlines()[0]), "the block must start by activating .venv"


def test_without_the_set_up_lines_the_commands_are_not_found(tmp_path):
    env = fresh_shell(tmp_path)
    if shutil.which("defocus", path=env["PATH"]) is not None:
        pytest.skip("another `defocus` is on PATH outside the virtual environment")
    done = bash("defocus sample samples", tmp_path, env, timeout=60)
    assert done.returncode == 127 and "not found" in done.stderr, done.stderr
    done = bash(f"{setup_lines()[0]}\ndefocus --version", tmp_path, env, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("defocus "), done.stderr


@pytest.mark.slow
def test_readme_blocks_run_as_written_in_a_fresh_shell(tmp_path):
    env = fresh_shell(tmp_path)
    for block in user_blocks():
        done = bash(block, tmp_path, env)
        assert done.returncode == 0, (block, done.stderr[-2000:])
    setup = "\n".join(setup_lines())
    for snippet in readme_blocks("python"):
        done = bash(f"{setup}\npython - <<'README'\n{snippet}README\n", tmp_path, env, timeout=300)
        assert done.returncode == 0, (snippet, done.stderr[-2000:])
        if "runs/predict" in snippet:
            assert "abs rel" in done.stdout, done.stdout
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
