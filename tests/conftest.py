"""Shared fixtures: tiny shapes, an isolated cache, and a helper to run the real CLI in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"


def _flat(node: dict, prefix: str = "") -> list[str]:
    out = []
    for key, value in node.items():
        if isinstance(value, dict):
            out += _flat(value, f"{prefix}{key}.")
        else:
            out.append(f"{prefix}{key}={str(value).lower() if isinstance(value, bool) else value}")
    return out


#: Overrides that keep every CLI run in the tests small and fast: ``conf/debug/fast.yaml`` (``+debug=fast``), the
#: one place they are written, as key=value overrides so that they win over any experiment a test adds.
FAST = _flat(yaml.safe_load((REPO / "conf" / "debug" / "fast.yaml").read_text()))


def run_cli(args: list[str], cwd: Path, env: dict | None = None, module: str = "qmdf") -> subprocess.CompletedProcess:
    full_env = {**os.environ, **(env or {})}
    full_env.pop("QMDF_RUN_NAME", None)
    return subprocess.run(
        [sys.executable, "-m", module, *args], cwd=cwd, env=full_env, capture_output=True, text=True, timeout=300
    )


def manifests(root: Path) -> list[dict]:
    return [json.loads(p.read_text()) | {"_path": str(p)} for p in sorted(root.rglob("manifest.json"))]


@pytest.fixture
def cli(tmp_path):
    """Run ``python -m qmdf ARGS`` from a fresh working directory; returns (process, cwd)."""

    def _run(*args: str, env: dict | None = None, module: str = "qmdf"):
        return run_cli(list(args), tmp_path, env, module)

    _run.cwd = tmp_path
    return _run


@pytest.fixture
def compose_cfg(tmp_path):
    """Compose a config as the CLI would, with the cache inside the test's folder."""
    from qmdf.api import compose

    def _compose(*overrides: str):
        return compose([f"cache.dir={tmp_path / 'cache'}", *FAST, *overrides])

    return _compose
