"""The manual's commands work as written on a fresh clone (README.md, docs/*.md, docs/tutorials/,
docs/results/).

Every `defocus ...` line of a bash block parses with the command line's own parser (no option
renamed from under it) and names only files a fresh clone has once the page's commands before it
ran: a folder `defocus sample` wrote, results under `runs/`, or files of the repository. A block
that needs data of the user's own (their photos, a downloaded dataset) starts with a comment
`# needs ...` saying what; its commands are only parsed. Then the `defocus sample` and
`defocus predict` commands (without a model file) of each page run, in order, in a fresh folder:
a stale command fails here. To be quick they run on smaller photos: the sample set at `SCALE`
of the scene instead of its default (a `--pixel-pitch` option scaled to match). README.md's
commands run as they are in `test_readme_commands.py`.
"""

from __future__ import annotations

import re
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

from defocus.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
         *sorted((ROOT / "docs" / "tutorials").glob("*.md")),
         *sorted((ROOT / "docs" / "results").glob("*.md"))]
#: Placeholders of files a reader does not have.
PLACEHOLDERS = ("path/to/", "../shared/")
#: The scale of the sample sets the commands run on here (`defocus sample --scale`).
SCALE = 0.2
#: Endings of file names among a command's arguments.
FILE_SUFFIX = re.compile(r"\.(png|jpe?g|tiff?|dng|cr2|nef|arw|json|ya?ml|pt|npy|h5|csv)$", re.I)


@dataclass
class Command:
    page: Path
    argv: list[str]  # after `defocus`
    needs: str | None  # the block's `# needs ...` comment, if any


def page_commands(page: Path) -> list[Command]:
    """The `defocus ...` lines of the page's bash blocks (continuations joined), in order."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S):
        first = block.lstrip().splitlines()[0] if block.strip() else ""
        needs = first[1:].strip() if first.startswith("# needs") else None
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if len(words) > 1 and words[0] == "defocus":
                commands.append(Command(page, words[1:], needs))
    return commands


ALL = [command for page in PAGES for command in page_commands(page)]


def _id(command: Command) -> str:
    return f"{command.page.name}: {' '.join(command.argv)[:60]}"


def _is_file(word: str) -> bool:
    if word.startswith("-"):
        return False
    try:
        float(word)
        return False
    except ValueError:
        return "/" in word or bool(FILE_SUFFIX.search(word))


def _runs(command: Command) -> bool:
    """Whether the command runs here: `sample`, and `predict` without a model file."""
    if command.needs is not None:
        return False
    if command.argv[0] == "sample":
        return True
    return command.argv[0] == "predict" and build_parser().parse_args(
        command.argv).checkpoint is None


def smaller(argv: list[str]) -> list[str]:
    """`argv` for photos at `SCALE` of the scene: `--scale` added to a `sample` command that
    has none, a `--pixel-pitch` value grown by the default scale over `SCALE`."""
    default = build_parser().parse_args(["sample"]).scale
    if argv[0] == "sample" and "--scale" not in argv:
        return [*argv, "--scale", str(SCALE)]
    if argv[0] == "predict" and "--pixel-pitch" in argv:
        at = argv.index("--pixel-pitch") + 1
        return [*argv[:at], f"{float(argv[at]) * default / SCALE:.6g}", *argv[at + 1:]]
    return argv


def test_the_manual_shows_commands_of_both_kinds():
    assert sum(_runs(c) for c in ALL) >= 6 and sum(c.needs is not None for c in ALL) >= 4
    pages = {c.page.name for c in ALL}
    assert {"own_photos.md", "calibration.md", "training.md", "index.md"} <= pages


def test_no_page_names_files_a_reader_does_not_have():
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for placeholder in PLACEHOLDERS:
            assert placeholder not in text, f"{page.relative_to(ROOT)} names {placeholder!r}"


@pytest.mark.parametrize("command", ALL, ids=_id)
def test_every_command_parses(command, capsys):
    try:
        build_parser().parse_args(command.argv)
    except SystemExit as stop:  # --version and --help print and stop with 0
        assert stop.code == 0, (command.argv, capsys.readouterr().err)


def test_commands_name_only_files_a_fresh_clone_has():
    """Unless its block says what it `# needs`, a command reads only what `defocus sample` or
    an earlier command of its page wrote (`runs/`) or what the repository holds."""
    for page in PAGES:
        sampled: list[str] = []
        for command in page_commands(page):
            if command.needs is not None:
                assert len(command.needs.split()) >= 3, f"{_id(command)}: say what it needs"
                continue
            if command.argv[0] == "sample":
                sampled.append(str(build_parser().parse_args(command.argv).folder).rstrip("/"))
            for word in filter(_is_file, command.argv[1:]):
                known = word.startswith("runs/") or (ROOT / word).exists() or any(
                    word == folder or word.startswith(folder + "/") for folder in sampled)
                assert known, f"{_id(command)}: {word} is not in a fresh clone; mark the " \
                              "block '# needs ...' or use the sample set"


@pytest.mark.slow
def test_sample_and_predict_commands_run_as_written(tmp_path, monkeypatch, capsys):
    """Page by page, in a fresh folder each (a sample set written once is copied, a command
    run on one page is not run again), on smaller photos (`smaller`); where a figure hatches
    mirrored depths, its page names them."""
    from models.plotting import figure_mirrored_depths

    written: dict[tuple[str, ...], Path] = {}
    done: set[tuple[str, ...]] = set()
    spans = []
    for index, page in enumerate(PAGES[1:]):
        commands = [c for c in page_commands(page) if _runs(c)]
        if not any(c.argv[0] == "predict" for c in commands):
            continue
        folder = tmp_path / str(index)
        folder.mkdir()
        monkeypatch.chdir(folder)
        for command in commands:
            key = tuple(command.argv)
            if command.argv[0] == "sample" and key in written:
                target = build_parser().parse_args(command.argv).folder
                shutil.copytree(written[key], folder / target)
                continue
            if key in done:
                continue
            assert main([*smaller(command.argv), "--quiet"]) == 0, (_id(command),
                                                                     capsys.readouterr().err)
            done.add(key)
            args = build_parser().parse_args(command.argv)
            if command.argv[0] == "sample":
                written[key] = folder / args.folder
                continue
            span = figure_mirrored_depths(folder / args.out / "figure.png")
            if span is not None:
                spans.append(span)
                assert f"{span[0]:.2f} and {span[1]:.2f} m" in page.read_text(encoding="utf-8"), (
                    _id(command), span)
    assert spans, "no command of the manual shows the depths one focus plane cannot tell"
