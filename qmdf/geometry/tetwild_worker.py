"""Runs fTetWild (pytetwild) in a child process whose working directory is a scratch folder.

fTetWild writes ``_tracked_surface.stl`` into the current working directory; qmdf never changes its own,
so the call runs here, started with ``cwd=`` the stage's scratch folder. Input and output travel as .npz.

    python -m qmdf.geometry.tetwild_worker IN.npz OUT.npz
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np


def tetrahedralize(vertices: np.ndarray, faces: np.ndarray, scratch: Path, **params) -> tuple[np.ndarray, np.ndarray]:
    scratch.mkdir(parents=True, exist_ok=True)
    src, dst = scratch / "tetwild_in.npz", scratch / "tetwild_out.npz"
    np.savez(
        src, vertices=np.asarray(vertices, np.float64), faces=np.asarray(faces, np.int32), params=json.dumps(params)
    )
    proc = subprocess.run(
        [sys.executable, "-m", "qmdf.geometry.tetwild_worker", str(src), str(dst)],
        cwd=scratch,
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0 or not dst.exists():
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"fTetWild failed (exit {proc.returncode}): {last}")
    with np.load(dst) as out:
        return out["vertices"], out["tets"]


def _main(src: str, dst: str) -> None:
    import pytetwild

    with np.load(src) as data:
        v, f, params = data["vertices"], data["faces"], json.loads(str(data["params"]))
    tv, tt = pytetwild.tetrahedralize(v, f, quiet=True, **params)
    np.savez(dst, vertices=np.asarray(tv, np.float64), tets=np.asarray(tt, np.int64))


if __name__ == "__main__":
    _main(sys.argv[1], sys.argv[2])
