"""``python -m qmdf.warmup``: compile the numba kernels ahead, so that a user's first run is as fast as the next.

The kernels are compiled on first use and cached on disk beside their modules (``cache=True``); on a fresh clone
that first use was inside the user's first run (the teacup's sheet stage 58.7 s against 48.3 s the second time).
``make setup`` runs this once: the whole pipeline on the embedded teacup at ``+debug=fast`` (tiny grids, a few
steps) with the default grid backbone and a sheet small enough to be simplified, whose kernels take the same
argument types as a full run's, and the ellipsoid's points without their normals for the cloud route's; its outputs
go to a temporary folder and the cache is off."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time


def main() -> int:
    t0 = time.perf_counter()
    # the mesh route with the grid backbone (the default's kernels; +debug=fast trains the MLP) and a budget small
    # enough that the sheet is simplified; the raw-cloud route (orientation, Poisson surface) on a degraded shape
    routes = {
        "mesh": ["train.model.backbone=grid", "sheet.target_vertices=50"],
        "cloud": ["input.shape=ellipsoid", "+sample.degradations.drop_normals.enabled=true"],
    }
    with tempfile.TemporaryDirectory() as tmp:
        for name, extra in routes.items():
            cmd = [sys.executable, "-m", "qmdf", "+debug=fast", "cache.enabled=false", f"hydra.run.dir={tmp}/{name}"]
            proc = subprocess.run(cmd + extra, capture_output=True, text=True)
            if proc.returncode != 0:
                sys.stderr.write(proc.stderr[-2000:])
                print(f"qmdf.warmup: the {name} run failed (exit {proc.returncode}); kernels compile on first use")
                return proc.returncode
    print(f"qmdf.warmup: numba kernels compiled and cached in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
