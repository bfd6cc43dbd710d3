"""One layer from the covering's solid: a priority-ordered collapse of its cubical complex.

The covering {q < eps} is a thin solid around the medial axis with the shape's homotopy type. Its grid nodes
inside span a cubical complex (a node inside is a vertex; an edge, square or cube whose corner nodes are all
inside is a cell). Elementary collapses (remove a free cell sigma, a face of exactly one cell tau, with tau)
keep the homotopy type, so whatever is left has the solid's Euler characteristic, seams where three sheets
meet included, with no rule about dihedral angles. The order is the field's: the pair whose tau has the
highest q goes first, so the two sides of the solid erode towards q's valley and meet on it.

Cubes always collapse. A square (edge) collapses only where q exceeds ``keep_q``, i.e. off the axis: a sheet
then stops shrinking at its rim, while the flat fins the cubes leave around a curve-like axis, whose cells
all lie above ``keep_q`` away from the curve, go down to a polyline. The cells are addressed on the doubled
grid (a cell's doubled coordinate is odd along each axis it spans), so a cell's faces and cofaces are its
+-1 neighbours along its odd and even axes.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass
class CubicalComplex:
    """What the collapse leaves: grid-node vertices (doubled-grid coordinates / 2 give the node), edges and
    squares as index tuples into ``nodes``."""

    nodes: np.ndarray  # (V, 3) int grid node indices
    edges: np.ndarray  # (E, 2) every remaining 1-cell, the squares' sides included
    squares: np.ndarray  # (S, 4) corner indices in cyclic order
    cubes: int  # cubes left (only around an enclosed void of the solid)
    square_cells: np.ndarray  # (S, 3) each square's doubled-grid address (for ``soften``)
    edge_cells: np.ndarray  # (E, 3) each edge's

    @property
    def euler(self) -> int:
        return int(len(self.nodes) - len(self.edges) + len(self.squares) - self.cubes)


SOFT = 2  # a cell marked so collapses whatever its q (a fin around a curve-like axis)


@njit(cache=True, nogil=True)
def _corner_mean(values, i, j, k):
    """Mean node value over a doubled-grid cell's corners."""
    i0, i1 = i // 2, (i + 1) // 2
    j0, j1 = j // 2, (j + 1) // 2
    k0, k1 = k // 2, (k + 1) // 2
    s = 0.0
    n = 0
    for a in (i0, i1):
        for b in (j0, j1):
            for c in (k0, k1):
                s += values[a, b, c]
                n += 1
    # a cell spans 1, 2, 4 or 8 distinct corners; the loop counted each 8 / distinct times, evenly
    return s / n


@njit(cache=True, nogil=True)
def _key(values, si, sj, sk, ti, tj, tk):
    """Heap key of the pair (sigma, tau), smallest first: the highest q of tau; among ties (both sides of a
    sheet read the same q), the face across q's gradient, so a cube between the two node layers beside a
    sheet goes through its top or bottom, never through a side (which would leave both layers, a pocket);
    then the face with the higher q."""
    vt = _corner_mean(values, ti, tj, tk)
    g = 0.0
    total = 0.0
    t = (ti, tj, tk)
    s = (si, sj, sk)
    along = 0.0
    for ax in range(3):  # scalars, not lists: a list in this loop was a heap allocation per key
        if t[ax] % 2 == 1:
            di, dj, dk = int(ax == 0), int(ax == 1), int(ax == 2)
            g = abs(_corner_mean(values, ti + di, tj + dj, tk + dk) - _corner_mean(values, ti - di, tj - dj, tk - dk))
            total += g
            if s[ax] != t[ax]:
                along = g
    align = along / total if total > 0 else 0.0
    return (-vt, -align, -_corner_mean(values, si, sj, sk))


@njit(cache=True, nogil=True)
def _cofaces(cells, i, j, k, out):
    """Present cofaces of cell (i, j, k) written into out (n, 3); returns how many."""
    n = 0
    sh = cells.shape
    c = (i, j, k)
    for ax in range(3):
        if c[ax] % 2 == 0:
            for d in (-1, 1):
                pi, pj, pk = i + d * (ax == 0), j + d * (ax == 1), k + d * (ax == 2)
                if 0 <= c[ax] + d < sh[ax] and cells[pi, pj, pk]:
                    out[n, 0], out[n, 1], out[n, 2] = pi, pj, pk
                    n += 1
    return n


@njit(cache=True, nogil=True)
def _push_free_faces(cells, values, ci, cj, ck, heap, co, faces):
    """Push (face, its one coface) for each face of cell c that is free."""
    sh = cells.shape
    nf = 0
    c = (ci, cj, ck)
    for ax in range(3):
        if c[ax] % 2 == 1:
            for d in (-1, 1):
                faces[nf, 0], faces[nf, 1], faces[nf, 2] = ci + d * (ax == 0), cj + d * (ax == 1), ck + d * (ax == 2)
                nf += 1
    for f in range(nf):
        fi, fj, fk = faces[f, 0], faces[f, 1], faces[f, 2]
        if cells[fi, fj, fk] and _cofaces(cells, fi, fj, fk, co) == 1:
            a, b, c2 = _key(values, fi, fj, fk, co[0, 0], co[0, 1], co[0, 2])
            s = (fi * sh[1] + fj) * sh[2] + fk
            t = (co[0, 0] * sh[1] + co[0, 1]) * sh[2] + co[0, 2]
            heapq.heappush(heap, (a, b, c2, s, t))


@njit(cache=True, nogil=True)
def _collapse(cells, values, keep_q, seeds):
    """Collapse in place; returns how many pairs were removed. Free cells are looked for everywhere, or, with
    ``seeds`` (cells whose rule changed since the last collapse, which left no collapsible pair), only among
    their faces: only a pair whose coface is a seed can have become collapsible."""
    sh = cells.shape
    co = np.empty((6, 3), np.int64)
    faces = np.empty((6, 3), np.int64)
    heap = [(0.0, 0.0, 0.0, np.int64(0), np.int64(0))]
    heap.pop()

    def flat(i, j, k):
        return (i * sh[1] + j) * sh[2] + k

    if seeds.shape[0] == 0:
        for i in range(sh[0]):
            for j in range(sh[1]):
                for k in range(sh[2]):
                    if cells[i, j, k] and _cofaces(cells, i, j, k, co) == 1:
                        a, b, c = _key(values, i, j, k, co[0, 0], co[0, 1], co[0, 2])
                        heapq.heappush(heap, (a, b, c, flat(i, j, k), flat(co[0, 0], co[0, 1], co[0, 2])))
    for m in range(seeds.shape[0]):
        if cells[seeds[m, 0], seeds[m, 1], seeds[m, 2]]:
            _push_free_faces(cells, values, seeds[m, 0], seeds[m, 1], seeds[m, 2], heap, co, faces)
    removed = 0
    while len(heap):
        negv, _, _, s, t = heapq.heappop(heap)
        si, sj, sk = s // (sh[1] * sh[2]), (s // sh[2]) % sh[1], s % sh[2]
        ti, tj, tk = t // (sh[1] * sh[2]), (t // sh[2]) % sh[1], t % sh[2]
        if not (cells[si, sj, sk] and cells[ti, tj, tk]):
            continue
        if _cofaces(cells, si, sj, sk, co) != 1:
            continue
        dim_t = (ti % 2) + (tj % 2) + (tk % 2)
        if dim_t < 3 and -negv <= _corner_mean(keep_q, ti, tj, tk) and cells[ti, tj, tk] != SOFT:
            continue
        cells[si, sj, sk] = 0
        cells[ti, tj, tk] = 0
        removed += 1
        # faces of sigma and of tau lost a coface: any now free becomes a candidate
        _push_free_faces(cells, values, si, sj, sk, heap, co, faces)
        _push_free_faces(cells, values, ti, tj, tk, heap, co, faces)
    return removed


@njit(cache=True, nogil=True)
def _fill_cells(inside, cells):
    """A doubled-grid cell is present when all its corner nodes are inside."""
    sh = cells.shape
    for i in range(sh[0]):
        for j in range(sh[1]):
            for k in range(sh[2]):
                ok = True
                for a in (i // 2, (i + 1) // 2):
                    for b in (j // 2, (j + 1) // 2):
                        for c in (k // 2, (k + 1) // 2):
                            if not inside[a, b, c]:
                                ok = False
                cells[i, j, k] = ok


def cubical_euler(inside: np.ndarray) -> int:
    """V - E + F - C of the cubical complex of the ``inside`` nodes (a cell wherever all its corners are inside),
    by counting each kind of cell with shifted masks: what any collapse of it keeps."""
    m = np.asarray(inside, bool)
    total = 0
    for spans in np.ndindex(2, 2, 2):  # which axes a cell spans: none (a node), one (an edge), two, three
        cell = np.ones(tuple(n - s for n, s in zip(m.shape, spans)), bool)
        for corner in np.ndindex(*(s + 1 for s in spans)):
            cell &= m[tuple(slice(c, n - s + c) for c, n, s in zip(corner, m.shape, spans))]
        total += (-1) ** sum(spans) * int(cell.sum())
    return total


class Collapse:
    """The cubical complex of the ``inside`` nodes, collapsed highest ``values`` (q) first; squares and edges
    only where their q exceeds ``keep_q`` (a number, or one per node: a cell reads its corners' mean) or where
    ``soften`` marked them. Node indices refer to the given
    arrays. ``run`` may be called again after ``soften``."""

    def __init__(self, inside: np.ndarray, values: np.ndarray, keep_q):
        inside = np.asarray(inside, bool)
        if not inside.any():
            raise ValueError("no node is inside")
        self.lo = np.argwhere(inside).min(0)
        hi = np.argwhere(inside).max(0) + 1
        box = tuple(slice(a, b) for a, b in zip(self.lo, hi))
        sub = inside[box]
        self.values = np.where(sub, values[box], np.inf).astype(np.float64)
        self.cells = np.zeros(tuple(2 * np.array(sub.shape) - 1), np.uint8)
        _fill_cells(sub, self.cells)
        keep = np.broadcast_to(np.asarray(keep_q, np.float64), inside.shape)[box]
        self.keep_q = np.ascontiguousarray(np.where(sub, keep, np.inf))
        self.softened: np.ndarray | None = None  # None until the first run, which scans every cell
        self.present: np.ndarray | None = None  # flat indices of the cells left by the last run

    def run(self) -> CubicalComplex:
        # after the first run only the softened cells can start a collapse (a full scan of the doubled grid
        # took 0.35 s per run on the teacup)
        seeds = np.zeros((0, 3), np.int64) if self.softened is None else self.softened
        if self.softened is None or len(seeds):
            _collapse(self.cells, self.values, self.keep_q, seeds)
        self.softened = np.zeros((0, 3), np.int64)
        # a run only removes cells: after the first, the cells left are found among the last run's (a scan of
        # the whole doubled grid took 0.57 s per run on the teacup, seven runs)
        flat = self.cells.reshape(-1)
        self.present = np.flatnonzero(flat) if self.present is None else self.present[flat[self.present] != 0]
        return _read_complex(self.cells, self.lo, self.present)

    def soften(self, complex_: CubicalComplex, squares: np.ndarray, edges: np.ndarray | None = None) -> None:
        """Let the chosen squares (and edges) of ``complex_`` (masks or indices) collapse whatever their q."""
        for cells in (complex_.square_cells[squares], None if edges is None else complex_.edge_cells[edges]):
            if cells is not None and len(cells):
                cells = np.asarray(cells, np.int64).reshape(-1, 3)
                self.cells[tuple(cells.T)] = SOFT
                self.softened = cells if self.softened is None else np.concatenate([self.softened, cells])


def collapse_to_sheet(inside: np.ndarray, values: np.ndarray, keep_q: float) -> CubicalComplex:
    """``Collapse(inside, values, keep_q).run()``."""
    return Collapse(inside, values, keep_q).run()


def _read_complex(cells: np.ndarray, lo: np.ndarray, present: np.ndarray | None = None) -> CubicalComplex:
    """The complex of the doubled grid's present cells (``present``: their flat indices, in order, when known)."""
    if present is None:
        present = np.flatnonzero(cells)
    idx = np.column_stack(np.unravel_index(present, cells.shape))
    odd = idx % 2
    dim = odd.sum(1)
    shape = np.array(cells.shape)
    verts = idx[dim == 0]
    keys = np.ravel_multi_index(verts.T, shape)  # argwhere's C order: already sorted

    def corner(p):
        return np.searchsorted(keys, np.ravel_multi_index(p.T, shape))

    eye = np.eye(3, dtype=np.int64)
    ep = idx[dim == 1]
    d = eye[np.argmax(ep % 2, axis=1)]
    edges = np.column_stack([corner(ep - d), corner(ep + d)])
    sp = idx[dim == 2]
    so = sp % 2
    u = eye[np.argmax(so, axis=1)]  # the first odd axis
    w = eye[2 - np.argmax(so[:, ::-1], axis=1)]  # the last odd axis
    squares = np.column_stack([corner(sp - u - w), corner(sp + u - w), corner(sp + u + w), corner(sp - u + w)])
    return CubicalComplex(
        verts // 2 + lo,
        edges.astype(np.int64).reshape(-1, 2),
        squares.astype(np.int64).reshape(-1, 4),
        int((dim == 3).sum()),
        sp,
        ep,
    )
