"""Progress bars: live on a terminal, a few lines in a log (optics.progress)."""

from __future__ import annotations

import io

from optics.progress import LOG_INTERVAL_S, progress_bar, writes_to_terminal


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _updates(stream: io.StringIO, steps: int = 2000) -> int:
    bar = progress_bar(total=steps, desc="train", file=stream)
    for step in range(steps):
        bar.set_postfix(loss=f"{1 / (step + 1):.4f}", refresh=False)  # as the trainer does
        bar.update(1)
    bar.close()
    text = stream.getvalue()
    return text.count("\r") + text.count("\n")


def test_a_log_gets_a_few_lines_and_a_terminal_a_live_bar():
    assert _updates(io.StringIO()) <= 4  # the first draw, the last and the closing newline
    live = progress_bar(total=10, file=_Terminal())
    logged = progress_bar(total=10, file=io.StringIO())
    assert live.mininterval < 1 and logged.mininterval == LOG_INTERVAL_S


def test_the_last_state_reaches_the_log():
    log = io.StringIO()
    _updates(log, steps=50)
    assert "50/50" in log.getvalue()


def test_terminal_detection():
    assert writes_to_terminal(_Terminal()) and not writes_to_terminal(io.StringIO())
    closed = io.StringIO()
    closed.close()
    assert not writes_to_terminal(closed)
