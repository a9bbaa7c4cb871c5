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
