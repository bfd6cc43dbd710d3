"""Simplify a medial mesh by edge collapse under the spherical quadric error (SQEM, Q-MAT: Li et al. 2015),
never changing its topology.

Each vertex is a sphere m = (x, r). A face's three spheres have two common tangent planes (its slab's sides,
n . x + r = d with |n| = 1): their squared residuals (n . x + r - d)^2, weighted by the face's area, are the
face's quadric; a vertex starts with the sum over its faces, so a collapse that keeps the envelope where it was
costs nothing. A rim (an edge of one face) adds the plane through it perpendicular to its face, weighted by
``boundary_weight``, so the rims stay where they are; a lone edge (a curve-like axis) adds the distance to its
line; feature tips get a large point quadric. The new sphere minimises the summed quadric.

A collapse must satisfy the link condition Lk(a) & Lk(b) = Lk(ab), which keeps the homotopy type of any
simplicial complex, seams and lone edges included (Dey et al. 1999; Attali, Lieutier & Salinas 2012), and must
not turn any surviving face over by more than ``max_turn_deg``.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from qmdf.geometry.metrics import rim_sides
from qmdf.geometry.rows import unique_rows
from qmdf.geometry.triangles import face_areas
from qmdf.schema import param


@dataclass
class SimplifySettings:
    """The sheet's ``simplify`` step (``sheet.step.simplify``) and ``simplify_medial_mesh``'s defaults."""

    boundary_weight: float = param(
        1.0, ge=0, doc="weight of the rims' planes in the quadric (keeps the sheet's free boundary in place)"
    )
    max_turn_deg: float = param(60.0, gt=0, le=180, doc="refuse a collapse that turns a face by more than this")
    deviation: float = param(
        0.0,
        ge=0,
        doc="collapse only where the envelope moves by at most this share of sheet.tolerance (root mean square over "
        "the planes a collapse merges), so the vertex count follows the shape and sheet.target_vertices is a cap; "
        "0: down to sheet.target_vertices, a fixed budget",
    )


_DEFAULT = SimplifySettings()


@njit(cache=True, nogil=True)
def _best(QA, Qb, Qc, m, a, b):
    """(cost, sphere) of merging a and b: the minimiser of the summed quadric (the midpoint if singular)."""
    A = QA[a] + QA[b]
    rhs = Qb[a] + Qb[b]
    c = Qc[a] + Qc[b]
    M = A.copy()
    x = rhs.copy()
    ok = True
    for col in range(4):  # Gaussian elimination with partial pivoting
        piv = col
        for row in range(col + 1, 4):
            if abs(M[row, col]) > abs(M[piv, col]):
                piv = row
        if abs(M[piv, col]) < 1e-300:
            ok = False
            break
        if piv != col:
            for k in range(4):
                M[col, k], M[piv, k] = M[piv, k], M[col, k]
            x[col], x[piv] = x[piv], x[col]
        for row in range(col + 1, 4):
            f = M[row, col] / M[col, col]
            for k in range(col, 4):
                M[row, k] -= f * M[col, k]
            x[row] -= f * x[col]
    if ok:
        for col in range(3, -1, -1):
            for k in range(col + 1, 4):
                x[col] -= M[col, k] * x[k]
            x[col] /= M[col, col]
    else:
        x = 0.5 * (m[a] + m[b])
    if x[3] < 0:
        x[3] = 0.0
    cost = c - 2 * (rhs @ x) + x @ (A @ x)
    return max(cost, 0.0), x


@njit(cache=True, nogil=True)
def _cross_norm2(p, k):
    """The cross product of triangle k's two sides from its corner 0 (p: (K, 3, 3)), and its squared length."""
    ax, ay, az = p[k, 1, 0] - p[k, 0, 0], p[k, 1, 1] - p[k, 0, 1], p[k, 1, 2] - p[k, 0, 2]
    bx, by, bz = p[k, 2, 0] - p[k, 0, 0], p[k, 2, 1] - p[k, 0, 1], p[k, 2, 2] - p[k, 0, 2]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return nx, ny, nz, nx * nx + ny * ny + nz * nz


@njit(cache=True, nogil=True)
def _turns_within(p, q, min_cos):
    """Whether no triangle turns by more than acos(min_cos) from p (K, 3, 3) to q (nor collapses to a line).
    Scalars throughout: a small array per triangle was a heap allocation in the collapse loop's hottest test."""
    for k in range(p.shape[0]):
        x0, y0, z0, s0 = _cross_norm2(p, k)
        x1, y1, z1, s1 = _cross_norm2(q, k)
        l0 = np.sqrt(s0)
        l1 = np.sqrt(s1)
        if l0 < 1e-20:
            continue
        if l1 < 1e-20 or (x0 * x1 + y0 * y1 + z0 * z1) < min_cos * l0 * l1:
            return False
    return True


def _initial_costs(Q: _Quadrics, faces: np.ndarray, edges: np.ndarray):
    """(cost, a, b) of merging the ends of every edge (a < b), all 4x4 systems solved at once."""
    e = np.concatenate([edges, faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = unique_rows(np.sort(e, axis=1))
    e = e[e[:, 0] != e[:, 1]]
    if not len(e):
        return np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64)
    A = Q.A[e[:, 0]] + Q.A[e[:, 1]]
    b = Q.b[e[:, 0]] + Q.b[e[:, 1]]
    c = Q.c[e[:, 0]] + Q.c[e[:, 1]]
    x = np.linalg.solve(A, b[:, :, None])[:, :, 0]
    x[:, 3] = np.maximum(x[:, 3], 0.0)
    cost = np.maximum(np.einsum("ki,kij,kj->k", x, A, x) - 2 * (b * x).sum(1) + c, 0.0)
    return cost, e[:, 0].astype(np.int64), e[:, 1].astype(np.int64)


# Adjacency as lists used as sets (a vertex has few faces): numba's own sets can hang after many removals
# (numba issue 8627).
@njit(cache=True, nogil=True)
def _add(items, x):
    for y in items:
        if y == x:
            return
    items.append(x)


@njit(cache=True, nogil=True)
def _discard(items, x):
    for i in range(len(items)):
        if items[i] == x:
            items[i] = items[len(items) - 1]
            items.pop()
            return


@njit(cache=True, nogil=True)
def _has(fv, f, w):
    return fv[f, 0] == w or fv[f, 1] == w or fv[f, 2] == w


@njit(cache=True, nogil=True)
def _neighbours(v, face_of, lone, fv):
    out = [np.int64(x) for x in range(0)]
    for u in lone[v]:
        _add(out, u)
    for f in face_of[v]:
        for k in range(3):
            if fv[f, k] != v:
                _add(out, fv[f, k])
    return out


@njit(cache=True, nogil=True)
def _other_pair(fv, f, v, n):
    """The face's two corners other than v, as one number."""
    lo, hi = -1, -1
    for k in range(3):
        w = fv[f, k]
        if w != v:
            if lo < 0:
                lo = w
            else:
                hi = w
    return min(lo, hi) * n + max(lo, hi)


@njit(cache=True, nogil=True)
def _link_ok(a, b, shared, face_of, lone, fv, n):
    """Lk(a) & Lk(b) = Lk(ab): the common neighbours are exactly the opposite corners of the faces on ab (the
    ``shared`` faces), and no edge of two other corners lies in a face of a and in a face of b."""
    opposite = [np.int64(x) for x in range(0)]
    for f in shared:
        for k in range(3):
            w = fv[f, k]
            if w != a and w != b:
                _add(opposite, w)
    nb = _neighbours(b, face_of, lone, fv)
    common = 0
    for w in _neighbours(a, face_of, lone, fv):
        if w in nb:
            if w not in opposite:
                return False
            common += 1
    if common != len(opposite):
        return False
    ea = [np.int64(x) for x in range(0)]
    for f in face_of[a]:
        if f not in shared:
            ea.append(_other_pair(fv, f, a, n))
    for f in face_of[b]:
        if f not in shared and _other_pair(fv, f, b, n) in ea:
            return False
    return True


@njit(cache=True, nogil=True)
def _turns_ok(a, b, x, face_of, fv, m, min_cos):
    """No face of a or b but those on ab turns by more than acos(min_cos) when a and b move to x."""
    rows = [np.int64(f) for f in face_of[a] if not _has(fv, f, b)]
    for f in face_of[b]:
        if not _has(fv, f, a):
            rows.append(f)
    if len(rows) == 0:
        return True
    p = np.empty((len(rows), 3, 3))
    q = np.empty((len(rows), 3, 3))
    for i in range(len(rows)):
        for k in range(3):
            w = fv[rows[i], k]
            for d in range(3):
                p[i, k, d] = m[w, d]
                q[i, k, d] = x[d] if (w == a or w == b) else m[w, d]
    return _turns_within(p, q, min_cos)


@njit(cache=True, nogil=True)
def _contract_connectivity(a, b, shared, face_of, lone, fv, face_alive):
    """Edge (a, b) collapsed into a: the faces it shares die, b's faces and lone edges pass to a, and a shared
    face's side that no face holds any more stays as a lone edge."""
    for f in shared:
        face_alive[f] = False
        for k in range(3):
            _discard(face_of[fv[f, k]], f)
    for f in face_of[b]:
        for k in range(3):
            if fv[f, k] == b:
                fv[f, k] = a
        _add(face_of[a], f)
    face_of[b].clear()
    for w in lone[b]:
        _discard(lone[w], b)
        if w != a:
            _add(lone[w], a)
            _add(lone[a], w)
    _discard(lone[a], b)
    lone[b].clear()
    # a face's side that no face holds any more stays as a lone edge
    for f in shared:
        for k in range(3):
            w = fv[f, k]
            if w != a and w != b:
                held = False
                for g in face_of[a]:
                    if _has(fv, g, w):
                        held = True
                        break
                if not held:
                    _add(lone[a], w)
                    _add(lone[w], a)


@njit(cache=True, nogil=True)
def _alive_lone_edges(alive, lone):
    """The lone edges between live vertices, each once, as an (E, 2) array."""
    n = len(alive)
    count = 0
    for v in range(n):
        if alive[v]:
            for u in lone[v]:
                if v < u:
                    count += 1
    out = np.empty((count, 2), np.int64)
    count = 0
    for v in range(n):
        if alive[v]:
            for u in lone[v]:
                if v < u:
                    out[count, 0], out[count, 1] = v, u
                    count += 1
    return out


@njit(cache=True, nogil=True)
def _collapse_loop(m, fv, lone_pairs, tips, quadrics, heap_cost, heap_a, heap_b, target, min_cos, limit):
    """The collapse loop of ``simplify_medial_mesh`` (see there): cheapest first, link condition, turn test, and
    with ``limit`` > 0 no collapse whose cost exceeds ``limit`` times the two vertices' summed plane weights (its
    weighted mean squared move of the envelope); ``m`` (spheres), ``fv`` (faces), ``tips`` and the ``quadrics``
    (A, b, c, plane weights, and the pull's w, b, c) are updated in place. Returns (alive, face_alive, lone edges,
    collapses, link-rejected, turn-rejected, refused by the limit)."""
    QA, Qb, Qc, Qw, Rw, Rb, Rc = quadrics
    n = m.shape[0]
    face_of = [[np.int64(x) for x in range(0)] for _ in range(n)]
    lone = [[np.int64(x) for x in range(0)] for _ in range(n)]
    for f in range(fv.shape[0]):
        for k in range(3):
            _add(face_of[fv[f, k]], f)
    for k in range(lone_pairs.shape[0]):
        i, j = lone_pairs[k, 0], lone_pairs[k, 1]
        if i != j:
            _add(lone[i], j)
            _add(lone[j], i)
    face_alive = np.ones(fv.shape[0], np.bool_)
    alive = np.ones(n, np.bool_)
    stamp = np.zeros(n, np.int64)
    heap = [(heap_cost[k], heap_a[k], heap_b[k], np.int64(0), np.int64(0)) for k in range(len(heap_cost))]
    heapq.heapify(heap)
    remaining = n
    collapses = rejected = flipped = over = 0
    while remaining > target and len(heap) > 0:
        cost, a, b, sa, sb = heapq.heappop(heap)
        if not (alive[a] and alive[b]) or stamp[a] != sa or stamp[b] != sb:
            continue
        if tips[a] and tips[b]:
            continue
        _, x = _best(QA, Qb, Qc, m, a, b)
        if limit > 0:
            # the planes' part of the cost (the weak pull to where the vertices were is no move of the envelope)
            pull = (Rw[a] + Rw[b]) * (x @ x) - 2 * ((Rb[a] + Rb[b]) @ x) + Rc[a] + Rc[b]
            if cost - pull > limit * (Qw[a] + Qw[b]):
                over += 1  # dropped, not stopped: a neighbour's collapse pushes this edge again with its new cost
                continue
        shared = [np.int64(f) for f in face_of[a] if _has(fv, f, b)]
        if not _link_ok(a, b, shared, face_of, lone, fv, n):
            rejected += 1
            continue
        if not _turns_ok(a, b, x, face_of, fv, m, min_cos):
            flipped += 1
            continue
        _contract_connectivity(a, b, shared, face_of, lone, fv, face_alive)
        QA[a] += QA[b]
        Qb[a] += Qb[b]
        Qc[a] += Qc[b]
        Qw[a] += Qw[b]
        Rw[a] += Rw[b]
        Rb[a] += Rb[b]
        Rc[a] += Rc[b]
        m[a] = x
        tips[a] = tips[a] or tips[b]
        alive[b] = False
        stamp[a] += 1
        remaining -= 1
        collapses += 1
        for u in _neighbours(a, face_of, lone, fv):
            i, j = (a, u) if a < u else (u, a)
            c, _ = _best(QA, Qb, Qc, m, i, j)
            heapq.heappush(heap, (c, i, j, stamp[i], stamp[j]))
    out = _alive_lone_edges(alive, lone)
    return alive, face_alive, out, collapses, rejected, flipped, over


@dataclass
class SimplifyResult:
    vertices: np.ndarray
    radii: np.ndarray
    edges: np.ndarray  # lone edges
    faces: np.ndarray
    stats: dict = field(default_factory=dict)
    fixed: np.ndarray | None = None  # the kept vertices that were fixed (or merged with a fixed one)


def slab_planes(c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two planes n . x = d (|n| = 1) tangent to each face's three spheres (c (F, 3, 3), r (F, 3)), every
    sphere on the side n . x <= d, i.e. n . c_i + r_i = d: normals (F, 2, 3), offsets (F, 2) and a mask of the
    faces that have them (not when one sphere nearly contains the others' span or the centres are collinear)."""
    e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    m = np.cross(e1, e2)
    mn = np.linalg.norm(m, axis=1)
    # n = a e1 + b e2 + g m:  n . e1 = r0 - r1,  n . e2 = r0 - r2
    g11, g12, g22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    det = g11 * g22 - g12 * g12
    ok = (mn > 1e-14) & (det > 1e-28)
    det = np.where(ok, det, 1.0)
    r1, r2 = r[:, 0] - r[:, 1], r[:, 0] - r[:, 2]
    a = (g22 * r1 - g12 * r2) / det
    b = (g11 * r2 - g12 * r1) / det
    t = a[:, None] * e1 + b[:, None] * e2
    rest = 1.0 - (t * t).sum(1)
    ok &= rest >= 0
    g = np.sqrt(np.maximum(rest, 0.0))[:, None] * m / np.where(ok, mn, 1.0)[:, None]
    n = np.stack([t + g, t - g], 1)
    d = (n * c[:, None, 0]).sum(2) + r[:, :1]
    return n, d, ok


class _Quadrics:
    """Per vertex, the 4D quadric x^T A x - 2 b . x + c over spheres x = (centre, radius)."""

    def __init__(self, n: int):
        self.A = np.zeros((n, 4, 4))
        self.b = np.zeros((n, 4))
        self.c = np.zeros(n)
        self.w = np.zeros(n)  # the summed weights of its planes: cost / w is a mean squared residual
        # the weak pull to where each vertex was, apart (w |x - m|^2 summed): not a move of the envelope
        self.pull_w, self.pull_b, self.pull_c = np.zeros(n), np.zeros((n, 4)), np.zeros(n)

    def add_planes(self, vertices: np.ndarray, n4: np.ndarray, d: np.ndarray, w: np.ndarray) -> None:
        """w (n4 . x - d)^2 added to each of ``vertices`` (K, j) for plane k."""
        A = w[:, None, None] * n4[:, :, None] * n4[:, None, :]
        b = (w * d)[:, None] * n4
        c = w * d * d
        for col in range(vertices.shape[1]):
            np.add.at(self.A, vertices[:, col], A)
            np.add.at(self.b, vertices[:, col], b)
            np.add.at(self.c, vertices[:, col], c)
            np.add.at(self.w, vertices[:, col], w)


def initial_quadrics(
    m: np.ndarray, faces: np.ndarray, edges: np.ndarray, boundary_weight: float, tips: np.ndarray, regular: float
) -> _Quadrics:
    Q = _Quadrics(len(m))
    x, r = m[:, :3], m[:, 3]
    if len(faces):
        tri = x[faces]
        area = face_areas(x, faces)
        n, d, ok = slab_planes(tri, r[faces])
        for side in (0, 1):
            Q.add_planes(faces[ok], np.column_stack([n[ok, side], np.ones(int(ok.sum()))]), d[ok, side], area[ok])
        # rims: the plane through the edge, perpendicular to its one face
        if boundary_weight > 0:
            e, owner = rim_sides(faces)
            fn = np.cross(tri[owner, 1] - tri[owner, 0], tri[owner, 2] - tri[owner, 0])
            t = x[e[:, 1]] - x[e[:, 0]]
            pn = np.cross(t, fn)
            length = np.linalg.norm(pn, axis=1)
            good = length > 1e-14
            pn = pn[good] / length[good, None]
            Q.add_planes(
                e[good],
                np.column_stack([pn, np.zeros(int(good.sum()))]),
                (pn * x[e[good, 0]]).sum(1),
                boundary_weight * (t[good] * t[good]).sum(1),
            )
    # lone edges: the distance to the edge's line, and the radius along it, at both ends
    if len(edges):
        t = x[edges[:, 1]] - x[edges[:, 0]]
        length2 = (t * t).sum(1)
        good = length2 > 1e-28
        t = t[good] / np.sqrt(length2[good])[:, None]
        P = np.zeros((len(t), 4, 4))
        P[:, :3, :3] = np.eye(3) - t[:, :, None] * t[:, None, :]
        P[:, 3, 3] = 1.0
        P *= length2[good, None, None]
        for col in (0, 1):
            v = edges[good, col]
            p4 = m[v]
            np.add.at(Q.A, v, P)
            np.add.at(Q.b, v, np.einsum("kij,kj->ki", P, p4))
            np.add.at(Q.c, v, np.einsum("ki,kij,kj->k", p4, P, p4))
            np.add.at(Q.w, v, length2[good])
    # every vertex: a weak pull to where it is (keeps the 4x4 systems solvable); tips: a strong one
    w = regular * np.where(tips, 1e6, 1.0)
    Q.A += w[:, None, None] * np.eye(4)
    Q.b += w[:, None] * m
    Q.c += w * (m * m).sum(1)
    Q.pull_w += w
    Q.pull_b += w[:, None] * m
    Q.pull_c += w * (m * m).sum(1)
    return Q


def simplify_medial_mesh(
    vertices: np.ndarray,
    radii: np.ndarray,
    edges: np.ndarray,
    faces: np.ndarray,
    target_vertices: int,
    boundary_weight: float = _DEFAULT.boundary_weight,
    max_turn_deg: float = _DEFAULT.max_turn_deg,
    tips: np.ndarray | None = None,
    max_deviation: float = 0.0,
) -> SimplifyResult:
    """Collapse edges, cheapest SQEM first, until ``target_vertices`` remain or no allowed collapse is left.
    ``tips``: a mask of vertices to keep in place (sharp-feature tips). ``max_deviation`` > 0: no collapse that
    moves the envelope by more than this, as the root mean square over the planes it merges (each face's two slab
    sides weighted by its area, a rim's plane and a lone edge's line by their length squared): the MAT stays as
    large as its shape needs, ``target_vertices`` a cap."""
    m = np.column_stack([np.asarray(vertices, np.float64), np.asarray(radii, np.float64)])
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    n = len(m)
    tips = np.zeros(n, bool) if tips is None else np.array(tips, bool)  # merged tips are marked in it
    mean_area = float(face_areas(m[:, :3], faces).mean()) if len(faces) else 0.0
    if mean_area == 0 and len(edges):
        mean_area = float(np.mean(np.sum((m[edges[:, 0], :3] - m[edges[:, 1], :3]) ** 2, 1)))
    Q = initial_quadrics(m, faces, edges, boundary_weight, tips, 1e-3 * max(mean_area, 1e-12))
    cost, ea, eb = _initial_costs(Q, faces, edges)
    fv = faces.copy()
    alive, face_alive, lone, collapses, rejected, flipped, over = _collapse_loop(
        m,
        fv,
        edges,
        tips,
        (Q.A, Q.b, Q.c, Q.w, Q.pull_w, Q.pull_b, Q.pull_c),
        cost,
        ea,
        eb,
        int(target_vertices),
        math.cos(math.radians(max_turn_deg)),
        float(max_deviation) ** 2,
    )
    index = np.full(n, -1)
    index[alive] = np.arange(int(alive.sum()))
    out_faces = index[fv[face_alive]].reshape(-1, 3)
    out_edges = unique_rows(index[lone].reshape(-1, 2)) if len(lone) else np.zeros((0, 2), np.int64)
    stats = {
        "vertices_before": n,
        "vertices": int(alive.sum()),
        "collapses": int(collapses),
        "link_rejected": int(rejected),
        "turn_rejected": int(flipped),
        "over_deviation": int(over),
    }
    return SimplifyResult(m[alive, :3], m[alive, 3], out_edges, out_faces, stats, tips[alive])
