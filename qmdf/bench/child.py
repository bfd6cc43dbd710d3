"""Run one pipeline in a child process and measure it: its own wall time and peak memory."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path


def run_child(cmd: list[str], run_dir: Path, timeout: float) -> tuple[int, float, float | None]:
    """(exit code, wall seconds, peak RSS in MB) of ``cmd``; its output goes to run_dir/bench.std{out,err}.
    The peak is an upper bound: Linux carries the parent's RSS at fork into the child's ru_maxrss, so a
    pipeline's own VmHWM (``peak_rss_mb`` in its manifest) is the figure to prefer."""
    run_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with open(run_dir / "bench.stdout", "w") as so, open(run_dir / "bench.stderr", "w") as se:
        proc = subprocess.Popen(cmd, stdout=so, stderr=se)
        deadline = t0 + timeout
        while True:  # wait4 (not communicate) so the child's own peak RSS comes back with its status
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                proc.kill()
                _, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
    return os.waitstatus_to_exitcode(status), time.perf_counter() - t0, usage.ru_maxrss / 1024


def last_error(run_dir: Path) -> str:
    """The run's own error (manifest) or the last line it printed."""
    import json

    manifest = run_dir / "manifest.json"
    if manifest.exists():
        err = json.loads(manifest.read_text()).get("error")
        if err:
            return err.splitlines()[0][:160]
    lines = (run_dir / "bench.stderr").read_text().strip().splitlines() if (run_dir / "bench.stderr").exists() else []
    return (lines or ["no output"])[-1][:160]


def fmt(value, spec: str) -> str:
    """A table cell: '-' where there is no value."""
    return "-" if value is None else format(value, spec)
