"""The progress reporter: deciles in logs, one line on a terminal, silent when disabled."""

from __future__ import annotations

import io

from perturb.progress import Progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_log_stream_gets_at_most_eleven_lines():
    out = io.StringIO()
    with Progress(1000, "work", stream=out, enabled=True) as bar:
        for _ in range(1000):
            bar.update()
    lines = out.getvalue().splitlines()
    assert 1 <= len(lines) <= 11
    assert lines[-1].startswith("[perturb] work 1000/1000")


def test_terminal_redraws_one_line():
    out = _Tty()
    with Progress(5, "x", stream=out, enabled=True) as bar:
        for _ in range(5):
            bar.update()
    text = out.getvalue()
    assert text.count("\r") == 5 and text.endswith("\n")


def test_disabled_and_closed_streams_are_silent():
    out = io.StringIO()
    with Progress(10, "x", stream=out, enabled=False) as bar:
        bar.update(10)
    assert out.getvalue() == ""
    closed = io.StringIO()
    closed.close()
    with Progress(3, "x", stream=closed, enabled=True) as bar:
        bar.update(3)  # must not raise


def test_no_estimate_of_the_time_left_for_uneven_work():
    # items of uneven cost (seeds of a continuation) make the estimate jump: it is left out
    stream = io.StringIO()
    with Progress(4, "uneven", stream=stream, enabled=True, eta=False) as bar:
        for _ in range(4):
            bar.update()
    assert "left" not in stream.getvalue() and "4/4" in stream.getvalue()
    stream = io.StringIO()
    with Progress(4, "even", stream=stream, enabled=True) as bar:
        bar.update()
    assert "s left" in stream.getvalue()
