"""Level sets of distance-like fields on a grid, evaluated only where the level set can pass.

A coarse pass finds the coarse cells whose corner values are within a cell diagonal of the level; only the
fine nodes of those cells are evaluated. For a 1-Lipschitz field (any SDF, and unions of them) every other
fine node provably has the sign of its cell's corners, so it is filled with a sign-correct bound and
marching cubes sees exactly the crossings a full evaluation would.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

#: field(points (N, 3), band) -> values (N,), exact within ``band`` of the level, sign-correct beyond it
BandedField = Callable[[np.ndarray, float], np.ndarray]


@dataclass
class GridLevelSet:
    values: np.ndarray  # (nx, ny, nz) field values minus the level
    lo: np.ndarray
    spacing: np.ndarray
    evaluated: int  # fine nodes evaluated exactly

    def mesh(self):
        """Marching cubes of the zero crossing, as an outward-oriented trimesh (None if there is none)."""
        import trimesh
        from skimage.measure import marching_cubes

        v = self.values
        if not (v.min() < 0 < v.max()):
            return None
        verts, faces, _, _ = marching_cubes(v, level=0.0, spacing=tuple(self.spacing))
        mesh = trimesh.Trimesh(verts + self.lo, faces[:, ::-1], process=True)
        if mesh.is_volume and mesh.volume < 0:
            mesh.invert()
        return mesh


def grid_axes(lo: np.ndarray, hi: np.ndarray, resolution: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Nodes over [lo, hi] with ``resolution`` nodes along the longest side and the same step elsewhere."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    step = float((hi - lo).max()) / (resolution - 1)
    counts = np.maximum(np.ceil((hi - lo) / step).astype(int) + 1, 2)
    return [lo[k] + step * np.arange(counts[k]) for k in range(3)], np.full(3, step)


def narrow_band_level_set(field: BandedField, lo, hi, resolution: int, level: float = 0.0, coarse_step: int = 8,
                          chunk: int = 1 << 18) -> GridLevelSet:
    """``field - level`` on a grid of ``resolution`` nodes along the longest side of [lo, hi]."""
    axes, spacing = grid_axes(lo, hi, resolution)
    shape = tuple(len(a) for a in axes)
    f = max(1, int(coarse_step))
    cidx = [np.unique(np.r_[np.arange(0, n, f), n - 1]) for n in shape]
    cpts = np.stack(np.meshgrid(*[axes[k][cidx[k]] for k in range(3)], indexing="ij"), -1).reshape(-1, 3)
    cell_diag = float(np.linalg.norm(spacing * f))
    cvals = _evaluate(field, cpts, cell_diag, level, chunk).reshape([len(c) for c in cidx])

    # coarse cells the level set may cross: some corner within a cell diagonal of the level
    near = np.abs(cvals) < cell_diag
    active = np.zeros([len(c) - 1 for c in cidx], bool)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                active |= near[dx:dx + active.shape[0], dy:dy + active.shape[1], dz:dz + active.shape[2]]
    # each fine node takes its cell's corner value (sign-correct); nodes of active cells are evaluated
    cell_of = [np.minimum(np.searchsorted(c, np.arange(n), side="right") - 1, len(c) - 2) for c, n in zip(cidx, shape)]
    values = cvals[np.ix_(cell_of[0], cell_of[1], cell_of[2])].astype(np.float32)
    mask = np.zeros(shape, bool)
    for i, j, k in zip(*np.nonzero(active)):
        mask[cidx[0][i]:cidx[0][i + 1] + 1, cidx[1][j]:cidx[1][j + 1] + 1, cidx[2][k]:cidx[2][k + 1] + 1] = True
    nodes = np.argwhere(mask)
    if len(nodes):
        pts = np.column_stack([axes[k][nodes[:, k]] for k in range(3)])
        fine_band = 2.0 * float(np.linalg.norm(spacing))
        values[mask] = _evaluate(field, pts, fine_band, level, chunk)
    values[np.ix_(*cidx)] = cvals
    return GridLevelSet(values, np.array([a[0] for a in axes]), spacing, int(len(nodes)))


def _evaluate(field: BandedField, pts: np.ndarray, band: float, level: float, chunk: int) -> np.ndarray:
    out = np.empty(len(pts))
    for s in range(0, len(pts), chunk):
        out[s:s + chunk] = field(pts[s:s + chunk], band) - level
    return out
