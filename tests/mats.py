"""Hand-made medial axes with closed-form answers (not made by our pipeline)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from qmdf.geometry.ma_format import MedialMesh


def torus_mat(n: int = 400, R: float = 0.35, r: float = 0.15) -> MedialMesh:
    """The torus's medial axis: its core circle, as a closed polyline of cones of constant radius."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    c = np.c_[R * np.cos(t), R * np.sin(t), np.zeros(n)]
    return MedialMesh(c, np.full(n, r), np.c_[np.arange(n), (np.arange(n) + 1) % n], np.zeros((0, 3), int))


def ellipsoid_mat(a: float = 0.5, b: float = 0.35, c: float = 0.25, rings: int = 30, sectors: int = 90) -> MedialMesh:
    """An ellipsoid's medial axis: the disc x^2/A^2 + y^2/B^2 <= 1 in z = 0 with A = (a^2-c^2)/a,
    B = (b^2-c^2)/b, and radius r^2 = c^2 (1 - x^2/(a^2-c^2) - y^2/(b^2-c^2))."""
    A, B = (a * a - c * c) / a, (b * b - c * c) / b
    s = np.linspace(0, 1, rings)[1:]
    t = np.linspace(0, 2 * np.pi, sectors, endpoint=False)
    xy = np.vstack([[0.0, 0.0], np.stack([np.outer(s, np.cos(t)).ravel() * A, np.outer(s, np.sin(t)).ravel() * B], 1)])
    r = c * np.sqrt(np.clip(1 - xy[:, 0] ** 2 / (a * a - c * c) - xy[:, 1] ** 2 / (b * b - c * c), 0, None))
    return MedialMesh(np.c_[xy, np.zeros(len(xy))], r, np.zeros((0, 2), int), Delaunay(xy).simplices)


#: A third-party stage package that "computes" the torus MAT, shifted by a config offset: it stands in for
#: the extraction stages so evaluate and sweeps can be tested end to end.
PLUGIN_SOURCE = '''
from dataclasses import dataclass
import sys
from qmdf.artifacts import MAT, POINTS
from qmdf.schema import param
from qmdf.stage import Stage
sys.path.insert(0, {tests!r})
from mats import torus_mat

@dataclass
class TorusMatConfig:
    radius_offset: float = param(0.0)

class TorusMat(Stage):
    """The torus's exact MAT in the unit box of the torus input."""
    Config = TorusMatConfig
    inputs = {{"points": POINTS}}
    outputs = {{"mat": MAT}}

    def run(self, ctx):
        mat = torus_mat()
        mat.radii = mat.radii + ctx.cfg.radius_offset
        ctx.save("mat", mat)
'''


def install_torus_mat_plugin(site, tests_dir) -> dict:
    pkg = site / "torus_mat_plugin"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(PLUGIN_SOURCE.format(tests=str(tests_dir)))
    info = site / "torus_mat_plugin-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: torus-mat-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[qmdf.stages]\ntorus_mat = torus_mat_plugin:TorusMat\n")
    return {"PYTHONPATH": str(site)}
