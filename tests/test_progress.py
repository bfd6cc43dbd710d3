"""The heartbeat a log shows: at most one line per interval with the count and the time left, one at the end."""

from __future__ import annotations

from qmdf.progress import Heartbeat, duration


class _Log:
    def __init__(self):
        self.lines = []

    def info(self, msg, *args):
        self.lines.append(msg % args)


def test_heartbeat_throttles_and_estimates_the_time_left():
    clock = iter(range(0, 10_000)).__next__  # one second per beat
    log = _Log()
    heart = Heartbeat(log, "train: step", 100, every=15, clock=clock)
    for step in range(1, 101):
        heart.beat(step, f"loss {1.0 / step:.3g}")
    # beats 1..100 take 99 s: a line at 16, 31, 46, 61, 76, 91 s and the last step's
    assert len(log.lines) == 7
    assert log.lines[0] == "train: step: 16 of 100, loss 0.0625, 1 min 24 s left"
    assert log.lines[-1].startswith("train: step: 100 of 100") and log.lines[-1].endswith("0 s left")


def test_duration_reads_as_minutes_and_seconds():
    assert duration(59.4) == "59 s" and duration(61) == "1 min 01 s" and duration(3600) == "60 min 00 s"


def test_a_terminal_gets_a_bar_with_the_time_left_and_a_log_gets_the_heartbeat():
    import io
    import logging

    from qmdf.progress import Bar, Heartbeat, progress

    assert isinstance(progress(logging.getLogger("t"), "contract: iteration", 10, bar=False), Heartbeat)
    stream = io.StringIO()
    bar = Bar("contract: iteration", 100, stream=stream, min_interval=0)
    for done in range(0, 101, 25):
        bar.beat(done, "q 1e-3")
    text = stream.getvalue()
    assert "contract: iteration" in text and "75/100" in text and "q 1e-3" in text and "<00:00" in text  # ETA
