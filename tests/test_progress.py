"""fgnav.progress: silent when stderr is not a terminal or quiet=True, a bar on a TTY."""

from __future__ import annotations

import io
import sys

from fgnav.progress import progress


class FakeTTY(io.StringIO):
    def isatty(self):
        return True


def test_silent_when_not_a_tty(capsys):
    # pytest's capture replaces stderr with a non-TTY stream
    assert list(progress(range(50), desc="epochs", unit="epoch")) == list(range(50))
    with progress(total=10, desc="manual") as bar:
        for _ in range(10):
            bar.update(1)
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


def test_bar_on_a_tty_and_quiet_silences_it(monkeypatch):
    fake = FakeTTY()
    monkeypatch.setattr(sys, "stderr", fake)
    assert sum(progress(range(20), desc="smoothing", unit="epoch", mininterval=0)) == sum(range(20))
    text = fake.getvalue()
    assert "smoothing" in text and "20/20" in text and "epoch" in text

    fake2 = FakeTTY()
    monkeypatch.setattr(sys, "stderr", fake2)
    assert list(progress(iter(range(5)), total=5, quiet=True)) == list(range(5))
    assert fake2.getvalue() == ""


def test_generator_without_len(monkeypatch):
    fake = FakeTTY()
    monkeypatch.setattr(sys, "stderr", fake)
    out = list(progress((i * i for i in range(4)), desc="gen", mininterval=0))
    assert out == [0, 1, 4, 9]
    assert "gen" in fake.getvalue() and "4it" in fake.getvalue()


def test_periodic_log_lines_when_not_a_tty(monkeypatch):
    """Not a terminal: a line every LOG_INTERVAL_S at most, a closing line, no bar."""
    import fgnav.progress as fp

    out = io.StringIO()
    monkeypatch.setattr(sys, "stderr", out)
    clock = iter(range(0, 1000, 4))                     # 4 s per call of the clock
    monkeypatch.setattr(fp.time, "monotonic", lambda: float(next(clock)))
    with progress(total=10, desc="batch", unit="iter") as bar:
        for _ in range(10):
            bar.set_postfix_str("update 3 m")
            bar.update(1)
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert len(lines) == 4 and all(line.startswith("fgnav: batch: ") for line in lines)
    assert lines[0].startswith("fgnav: batch: 3/10 iter (30%), 12 s, update 3 m")
    assert lines[-1].endswith(", done") and "10/10" in lines[-1]
    out2 = io.StringIO()
    monkeypatch.setattr(sys, "stderr", out2)
    assert list(progress(range(5), desc="x", quiet=True)) == list(range(5))
    assert out2.getvalue() == ""
