"""Progress of long work: a tqdm bar on a terminal, plain periodic log lines elsewhere.

A tqdm bar redrawn with carriage returns is noise in a CI log, a pipe or a DCC's
console. :func:`progress_bar` returns a tqdm bar when the stream it draws on
(stderr) is a terminal, and otherwise a :class:`LogLines` that prints one line
every ``every_seconds`` (and at the end): ``desc: step/total (pct%), key=value ...,
elapsed, ETA``. Both take the same calls: ``update(n)``, ``set_postfix(**values)``,
``close()``, and have ``n`` and ``total``.
"""

from __future__ import annotations

import sys
import time

LOG_EVERY_SECONDS = 30.0
"""Seconds between two plain progress lines when the output is not a terminal."""


def _clock(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"


class LogLines:
    """A tqdm-like progress reporter that prints plain lines (no carriage returns) to ``file``."""

    def __init__(self, total: int, initial: int = 0, desc: str = "", file=None,
                 every_seconds: float = LOG_EVERY_SECONDS, clock=time.monotonic):
        self.total, self.n, self.desc = total, initial, desc
        self.file = file if file is not None else sys.stderr
        self.every = every_seconds
        self._clock = clock
        self._start = self._last = clock()
        self._initial = initial
        self._postfix: dict[str, str] = {}
        self._closed = False

    def set_postfix(self, **values) -> None:
        self._postfix = {k: str(v) for k, v in values.items()}

    def line(self) -> str:
        """The current progress as one line (elapsed and ETA from the rate since the start)."""
        elapsed = self._clock() - self._start
        done = self.n - self._initial
        pct = f" ({100.0 * self.n / self.total:.0f}%)" if self.total else ""
        eta = _clock((self.total - self.n) * elapsed / done) if done > 0 and self.total else "?"
        post = "".join(f", {k}={v}" for k, v in self._postfix.items())
        head = f"{self.desc}: " if self.desc else ""
        return f"{head}{self.n}/{self.total}{pct}{post}, elapsed {_clock(elapsed)}, ETA {eta}"

    def update(self, n: int = 1) -> None:
        self.n += n
        now = self._clock()
        if now - self._last >= self.every:
            self._last = now
            print(self.line(), file=self.file, flush=True)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            print(self.line(), file=self.file, flush=True)


class _Silent:
    """The reporter when progress is off: accepts every call, prints nothing."""

    def __init__(self, total: int, initial: int = 0):
        self.total, self.n = total, initial

    def update(self, n: int = 1) -> None:
        self.n += n

    def set_postfix(self, **values) -> None:
        pass

    def close(self) -> None:
        pass


def is_terminal(stream=None) -> bool:
    stream = stream if stream is not None else sys.stderr
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # closed or not a real stream
        return False


def progress_bar(total: int, initial: int = 0, enabled: bool = True, desc: str = "", position: int | None = None,
                 file=None):
    """A progress reporter for ``total`` steps: tqdm on a terminal, :class:`LogLines` otherwise,
    a silent one when not ``enabled``."""
    if not enabled:
        return _Silent(total, initial)
    file = file if file is not None else sys.stderr
    if is_terminal(file):
        from tqdm import tqdm  # only a terminal draws a bar

        return tqdm(total=total, initial=initial, desc=desc or None, position=position, unit="it",
                    dynamic_ncols=True, leave=True, file=file)
    return LogLines(total, initial, desc, file=file)
