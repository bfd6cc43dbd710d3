"""Compiled per-pair envelope distances for the union's inner loop.

They mirror ``sphere_sdf``/``cone_sdf``/``slab_sdf`` in envelope.py (the tested reference, which also returns
the feet); numba runs the candidate pairs in one loop instead of numpy's ~50 temporaries per pair.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from qmdf.geometry._bvh import node_bound

_EPS = 1e-12


@njit(cache=True, nogil=True, fastmath=False)
def _cone(px, py, pz, ax, ay, az, ra, bx, by, bz, rb):
    dx, dy, dz = bx - ax, by - ay, bz - az
    dr = rb - ra
    qx, qy, qz = px - ax, py - ay, pz - az
    a = dx * dx + dy * dy + dz * dz
    da = math.sqrt(qx * qx + qy * qy + qz * qz) - ra
    db = math.sqrt((px - bx) ** 2 + (py - by) ** 2 + (pz - bz) ** 2) - rb
    if not (a > _EPS and a - dr * dr > _EPS * max(a, 1.0)):
        return min(da, db)
    qd = qx * dx + qy * dy + qz * dz
    h2 = qx * qx + qy * qy + qz * qz - qd * qd / a
    h = math.sqrt(h2) if h2 > 0.0 else 0.0
    t = qd / a + dr * h / math.sqrt(max(a * (a - dr * dr), _EPS))
    t = min(max(t, 0.0), 1.0)
    ex, ey, ez = qx - t * dx, qy - t * dy, qz - t * dz
    return math.sqrt(ex * ex + ey * ey + ez * ez) - (ra + t * dr)


@njit(cache=True, nogil=True, fastmath=False)
def _slab(px, py, pz, c, r, i1, i2, i3):
    x1, y1, z1, r1 = c[i1, 0], c[i1, 1], c[i1, 2], r[i1]
    x2, y2, z2, r2 = c[i2, 0], c[i2, 1], c[i2, 2], r[i2]
    x3, y3, z3, r3 = c[i3, 0], c[i3, 1], c[i3, 2], r[i3]
    e2x, e2y, e2z = x2 - x1, y2 - y1, z2 - z1
    e3x, e3y, e3z = x3 - x1, y3 - y1, z3 - z1
    d2, d3 = r2 - r1, r3 - r1
    g22 = e2x * e2x + e2y * e2y + e2z * e2z
    g23 = e2x * e3x + e2y * e3y + e2z * e3z
    g33 = e3x * e3x + e3y * e3y + e3z * e3z
    det = g22 * g33 - g23 * g23
    if det > 1e-10 * max(g22 * g33, _EPS):
        alpha = (-d2 * g33 + d3 * g23) / det
        beta = (-d3 * g22 + d2 * g23) / det
        ux, uy, uz = alpha * e2x + beta * e3x, alpha * e2y + beta * e3y, alpha * e2z + beta * e3z
        par2 = ux * ux + uy * uy + uz * uz
        if par2 < 1.0 - 1e-12:
            nx, ny, nz = e2y * e3z - e2z * e3y, e2z * e3x - e2x * e3z, e2x * e3y - e2y * e3x
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            nx, ny, nz = nx / nn, ny / nn, nz / nn
            side = (px - x1) * nx + (py - y1) * ny + (pz - z1) * nz
            un = math.sqrt(max(1.0 - par2, 0.0)) * (1.0 if side >= 0 else -1.0)
            t = side / un if abs(un) > _EPS else 0.0
            fx, fy, fz = px - t * (ux + un * nx) - x1, py - t * (uy + un * ny) - y1, pz - t * (uz + un * nz) - z1
            w2 = fx * e2x + fy * e2y + fz * e2z
            w3 = fx * e3x + fy * e3y + fz * e3z
            l2 = (w2 * g33 - w3 * g23) / det
            l3 = (w3 * g22 - w2 * g23) / det
            if l2 >= 0 and l3 >= 0 and 1.0 - l2 - l3 >= 0:
                return t - (r1 + l2 * d2 + l3 * d3)
    v = _cone(px, py, pz, x1, y1, z1, r1, x2, y2, z2, r2)
    v = min(v, _cone(px, py, pz, x2, y2, z2, r2, x3, y3, z3, r3))
    return min(v, _cone(px, py, pz, x1, y1, z1, r1, x3, y3, z3, r3))


@njit(cache=True, nogil=True)
def _prim_sdf(px, py, pz, j, prims, kind, c, r):
    a = prims[j, 0]
    if kind[j] == 0:
        return math.sqrt((px - c[a, 0]) ** 2 + (py - c[a, 1]) ** 2 + (pz - c[a, 2]) ** 2) - r[a]
    if kind[j] == 1:
        b = prims[j, 1]
        return _cone(px, py, pz, c[a, 0], c[a, 1], c[a, 2], r[a], c[b, 0], c[b, 1], c[b, 2], r[b])
    return _slab(px, py, pz, c, r, a, prims[j, 1], prims[j, 2])


@njit(cache=True, nogil=True, parallel=True)
def union_min(p, best, stop, arg, tree, shapes):
    """best[i] = min(best[i], min over primitives of their sdf at p[i]), arg[i] its primitive (kept where
    nothing went below best). Nearest nodes first, pruned by their lower bound; a point stops as soon as its
    best is below stop[i] (its sign is then all the caller needs). ``tree``: the BVH's (order, lo, hi, rho_max,
    left, right, start, count); ``shapes``: the primitives' (prims, kind, c, r, anchor, rho)."""
    order, lo, hi, rho_max, left, right, start, count = tree
    prims, kind, c, r, anchor, rho = shapes
    for i in prange(p.shape[0]):
        stack = np.empty(64, np.int64)  # depth-first: at most two nodes per level of the tree
        px, py, pz = p[i, 0], p[i, 1], p[i, 2]
        b = best[i]
        stack[0] = 0
        top = 1
        while top > 0 and b >= stop[i]:
            top -= 1
            node = stack[top]
            if node_bound(px, py, pz, lo, hi, rho_max, node) > b:
                continue
            if left[node] < 0:
                for m in range(start[node], start[node] + count[node]):
                    j = order[m]
                    lb = math.sqrt((px - anchor[j, 0]) ** 2 + (py - anchor[j, 1]) ** 2 + (pz - anchor[j, 2]) ** 2)
                    if lb - rho[j] > b:
                        continue
                    v = _prim_sdf(px, py, pz, j, prims, kind, c, r)
                    if v <= b:
                        b = v
                        arg[i] = j
                continue
            bl = node_bound(px, py, pz, lo, hi, rho_max, left[node])
            br = node_bound(px, py, pz, lo, hi, rho_max, right[node])
            # the nearer child on top of the stack, searched first
            near, far = (left[node], right[node]) if bl <= br else (right[node], left[node])
            stack[top] = far
            stack[top + 1] = near
            top += 2
        best[i] = b
