"""Progress a log can show: at most one line every ``every`` seconds with how far a loop is and the time left, so
a run piped to a file or started by ``make run`` never looks hung, and nothing floods."""

from __future__ import annotations

import time

HEARTBEAT_SECONDS = 15.0


def duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60} min {seconds % 60:02d} s" if seconds >= 60 else f"{seconds} s"


class Heartbeat:
    """``beat(done, detail)`` logs "WHAT: done of total, detail, T left" when ``every`` seconds have passed since
    the last line (and once at the end); the rate counts from the first beat."""

    def __init__(self, log, what: str, total: int, every: float = HEARTBEAT_SECONDS, clock=time.monotonic):
        self.log, self.what, self.total, self.every, self.clock = log, what, total, every, clock
        self.start = self.last = None
        self.first = 0
        self.lines = 0

    def beat(self, done: int, detail: str = "") -> None:
        now = self.clock()
        if self.start is None:
            self.start, self.last, self.first = now, now, done
            return
        if now - self.last < self.every and done < self.total:
            return
        self.last = now
        rate = (now - self.start) / max(1, done - self.first)
        left = duration(rate * max(0, self.total - done))
        self.log.info("%s: %d of %d%s, %s left", self.what, done, self.total, f", {detail}" if detail else "", left)
        self.lines += 1


class Bar:
    """The same ``beat(done, detail)`` as a progress bar with the time left (tqdm), for a terminal."""

    def __init__(self, what: str, total: int, stream=None, min_interval: float = 0.1):
        import sys

        from tqdm import tqdm

        self.bar = tqdm(
            total=total, desc=what, file=stream or sys.stderr, dynamic_ncols=True, leave=False, mininterval=min_interval
        )
        self.done = 0

    def beat(self, done: int, detail: str = "") -> None:
        if detail:
            self.bar.set_postfix_str(detail, refresh=False)
        self.bar.update(done - self.done)
        self.done = done
        if done >= self.bar.total:
            self.bar.close()


def progress(log, what: str, total: int, bar: bool | None = None):
    """A ``Bar`` on a terminal (stderr a TTY, or ``bar=True``), else a ``Heartbeat`` in the log."""
    import sys

    if bar if bar is not None else sys.stderr.isatty():
        return Bar(what, total)
    return Heartbeat(log, what, total)
