"""Shared fixtures: tiny shapes, an isolated cache, and a helper to run the real CLI in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"

#: Overrides that keep every CLI run in the tests small and fast.
FAST = [
    "input.shape_resolution=32",
    "sample.n_points=2000",
    "train.steps=3",
    "train.surface_batch=256",
    "train.volume_batch=256",
    "train.backbone=mlp",
    "train.backbones.mlp.width=32",
    "train.volume_samples=5000",
    "train.poisson_depth=6",
    "train.picture=false",
    "cover.resolution=32",
    "cover.eps=0.05",
    "contract.iterations=5",
    "export.reconstruction_resolution=24",
    "export.picture=false",
    "evaluate.samples=500",
    "evaluate.resolution=24",
    "evaluate.picture=false",
    "pipeline.report=false",
    "sheet.off_axis_wide=0",  # one sheet, not two (the torus chain of test_extraction builds both)
]


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
