"""Q-MDF on a fine lattice, evaluated lazily: what lets the contraction take thousands of steps cheaply.

The contraction queries q and grad q at the same vertices every iteration while they move a few lattice
cells in total. Each vertex interpolates (trilinear) the q values at the 8 corners of its cell; a corner is
evaluated by the field once, the first time any vertex needs it, and kept in blocks of 4^3 nodes allocated on
demand (blocks of 8^3 were 7% full around the teacup's thin covering: a 537 MB pool, against 134 MB). A
learned field then costs about as many forward passes as there are lattice nodes near the covering, instead
of iterations x vertices forward and backward passes.

Accuracy: trilinear interpolation puts the minimum of q's kink (the medial axis) at most half a lattice step
off, so the spacing (1e-3 of the unit box by default) bounds the error that this adds.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_B = 4  # nodes per block side (the kernels index with shifts by 2 and masks of 3)


@njit(cache=True)
def _gather(cells, block_id, dims, pool, n_blocks, out):
    """Corner values of each cell into out (M, 8), NaN where not evaluated yet; allocates missing blocks.
    Returns the new block count, or -1 - count when the pool filled up (the caller grows it and calls again;
    blocks allocated so far stay allocated, so the count must be kept either way)."""
    for m in range(cells.shape[0]):
        for c in range(8):
            i = cells[m, 0] + (c >> 2 & 1)
            j = cells[m, 1] + (c >> 1 & 1)
            k = cells[m, 2] + (c & 1)
            b = ((i >> 2) * dims[1] + (j >> 2)) * dims[2] + (k >> 2)  # indices are >= 0: shifts, not floor division
            if block_id[b] < 0:
                if n_blocks >= pool.shape[0]:
                    return -1 - n_blocks
                block_id[b] = n_blocks
                n_blocks += 1
            out[m, c] = pool[block_id[b], ((i & 3) << 4) | ((j & 3) << 2) | (k & 3)]
    return n_blocks


@njit(cache=True)
def _store(nodes, values, block_id, dims, pool):
    for m in range(nodes.shape[0]):
        i, j, k = nodes[m, 0], nodes[m, 1], nodes[m, 2]
        b = ((i >> 2) * dims[1] + (j >> 2)) * dims[2] + (k >> 2)
        pool[block_id[b], ((i & 3) << 4) | ((j & 3) << 2) | (k & 3)] = values[m]


@njit(cache=True, parallel=True)
def _locate(x, lo, h, n_nodes, cell, t, cells, corners):
    """Each point's cell and local coordinates; then make slot 0 hold that cell: keep it, swap in slot 1,
    or (need) load it anew after moving slot 0 to slot 1. Points off the lattice get cell 0 (inside False)."""
    need = np.zeros(cell.shape[0], np.bool_)
    inside = np.ones(cell.shape[0], np.bool_)
    for n in prange(cell.shape[0]):
        for k in range(3):
            u = (x[n, k] - lo[k]) / h
            i = math.floor(u)
            if i < 0 or i >= n_nodes[k] - 1:
                inside[n] = False
            cell[n, k] = i
            t[n, k] = u - i
        if not inside[n]:
            for k in range(3):
                cell[n, k] = 0
        if cell[n, 0] == cells[n, 0, 0] and cell[n, 1] == cells[n, 0, 1] and cell[n, 2] == cells[n, 0, 2]:
            continue
        for k in range(3):
            cells[n, 0, k], cells[n, 1, k] = cells[n, 1, k], cells[n, 0, k]
        for c in range(8):
            corners[n, 0, c], corners[n, 1, c] = corners[n, 1, c], corners[n, 0, c]
        if not (cell[n, 0] == cells[n, 0, 0] and cell[n, 1] == cells[n, 0, 1] and cell[n, 2] == cells[n, 0, 2]):
            need[n] = True
    return need, inside


@njit(cache=True, parallel=True)
def _interpolate(t, c, h, q, g):
    """Trilinear value and gradient from corner values c (N, 8; corner bits x, y, z) at local coords t."""
    for n in prange(t.shape[0]):
        tx, ty, tz = t[n, 0], t[n, 1], t[n, 2]
        c000, c001, c010, c011 = c[n, 0], c[n, 1], c[n, 2], c[n, 3]
        c100, c101, c110, c111 = c[n, 4], c[n, 5], c[n, 6], c[n, 7]
        # blend along z, then y, then x
        a00 = c000 + (c001 - c000) * tz
        a01 = c010 + (c011 - c010) * tz
        a10 = c100 + (c101 - c100) * tz
        a11 = c110 + (c111 - c110) * tz
        b0 = a00 + (a01 - a00) * ty
        b1 = a10 + (a11 - a10) * ty
        q[n] = b0 + (b1 - b0) * tx
        g[n, 0] = (b1 - b0) / h
        dy0, dy1 = a01 - a00, a11 - a10
        g[n, 1] = (dy0 + (dy1 - dy0) * tx) / h
        dz00, dz01, dz10, dz11 = c001 - c000, c011 - c010, c101 - c100, c111 - c110
        e0 = dz00 + (dz01 - dz00) * ty
        e1 = dz10 + (dz11 - dz10) * ty
        g[n, 2] = (e0 + (e1 - e0) * tx) / h


class LatticeQ:
    """q and grad q of the trilinear interpolant of ``field``'s q on a lattice of spacing ``spacing``,
    over the box [lo, hi] (points outside it are evaluated exactly)."""

    def __init__(self, field, spacing: float, lo, hi):
        self.field, self.h = field, float(spacing)
        self.lo = np.floor(np.asarray(lo, np.float64) / spacing) * spacing  # nodes on the global lattice h Z^3
        self.n_nodes = np.ceil((np.asarray(hi, np.float64) - self.lo) / self.h).astype(np.int64) + 2
        self.dims = (self.n_nodes + _B - 1) // _B
        self.block_id = np.full(int(np.prod(self.dims)), -1, np.int32)
        self.pool = np.full((64, _B**3), np.nan)
        self.n_blocks = 0
        self.evaluated = 0
        # per point, two cells with their corner values: the current one and the last one, since points that
        # reach the axis settle on a lattice plane (the interpolant's kink) and step back and forth across it
        self.cells: np.ndarray | None = None
        self.corners: np.ndarray | None = None

    def _corners(self, cells: np.ndarray) -> np.ndarray:
        out = np.empty((len(cells), 8))
        while True:
            n = _gather(cells, self.block_id, self.dims, self.pool, self.n_blocks, out)
            self.n_blocks = n if n >= 0 else -1 - n
            if n >= 0:
                break
            grown = np.full((2 * len(self.pool), _B**3), np.nan)
            grown[: len(self.pool)] = self.pool
            self.pool = grown
        missing = np.isnan(out)
        if missing.any():
            rows, corner = np.nonzero(missing)
            wanted = cells[rows] + np.stack([corner >> 2 & 1, corner >> 1 & 1, corner & 1], -1)
            # each node once, by its linear index (np.unique over rows sorts lexicographically: 5x slower)
            key, inverse = np.unique(np.ravel_multi_index(tuple(wanted.T), tuple(self.n_nodes)), return_inverse=True)
            nodes = np.column_stack(np.unravel_index(key, tuple(self.n_nodes)))
            vals = self.field.evaluate(self.lo + nodes * self.h)["q"].astype(np.float64)
            _store(nodes, vals, self.block_id, self.dims, self.pool)
            self.evaluated += len(nodes)
            out[rows, corner] = vals[inverse.ravel()]
        return out

    def __call__(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, grad q) at points x (N, 3)."""
        if self.cells is None or len(self.cells) != len(x):
            self.cells, self.corners = np.full((len(x), 2, 3), -1, np.int64), np.empty((len(x), 2, 8))
        cell, t = np.empty((len(x), 3), np.int64), np.empty((len(x), 3))
        need, inside = _locate(x, self.lo, self.h, self.n_nodes, cell, t, self.cells, self.corners)
        if need.any():
            self.corners[need, 0] = self._corners(cell[need])
            self.cells[need, 0] = cell[need]
        q, g = np.empty(len(x)), np.empty((len(x), 3))
        _interpolate(t, self.corners[:, 0], self.h, q, g)
        if not inside.all():
            out = self.field.evaluate(x[~inside], grad=True)
            q[~inside], g[~inside] = out["q"], out["q_grad"]
            self.evaluated += int((~inside).sum())
        return q, g
