"""Exact signed distances to the envelopes of medial primitives, and to their union (the MAT's shape).

A medial mesh reconstructs its shape as the union of the envelopes of its primitives (Li et al., Q-MAT):
spheres (isolated vertices), cones (the convex hull of the two spheres of an edge) and slabs (of the three
spheres of a face). Each primitive's SDF is ``min over the primitive's centre set of |p - c| - r`` with c and
r interpolated linearly; the minimisation is convex and solved in closed form here. All functions are
vectorised over pairs of points and primitives: arrays of shape (N, 3) and (N,).
"""
from __future__ import annotations

import numpy as np

_EPS = 1e-12


def sphere_sdf(p: np.ndarray, c: np.ndarray, r: np.ndarray) -> np.ndarray:
    return np.linalg.norm(p - c, axis=-1) - r


def cone_sdf(p: np.ndarray, c1: np.ndarray, r1: np.ndarray, c2: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Distance to the convex hull of spheres (c1, r1) and (c2, r2): min over t in [0,1] of |p - c(t)| - r(t)."""
    d = c2 - c1
    dr = r2 - r1
    q = p - c1
    a = np.einsum("ij,ij->i", d, d)
    qd = np.einsum("ij,ij->i", q, d)
    safe_a = np.maximum(a, _EPS)
    t0 = qd / safe_a
    h = np.sqrt(np.maximum(np.einsum("ij,ij->i", q, q) - qd * qd / safe_a, 0.0))  # distance to the axis
    # Stationary point of the convex function t -> |q - t d| - r1 - t dr, then clamped to the segment.
    proper = a - dr * dr > _EPS * np.maximum(a, 1.0)
    shift = np.where(proper, dr * h / np.sqrt(np.maximum(safe_a * (a - dr * dr), _EPS)), 0.0)
    t = np.clip(t0 + shift, 0.0, 1.0)
    along = np.linalg.norm(q - t[:, None] * d, axis=1) - (r1 + t * dr)
    # Improper cone (one sphere holds the other) or coincident centres: the minimum is at an end.
    ends = np.minimum(np.linalg.norm(q, axis=1) - r1, np.linalg.norm(p - c2, axis=1) - r2)
    return np.where(proper & (a > _EPS), along, ends)


def slab_sdf(p, c1, r1, c2, r2, c3, r3) -> np.ndarray:
    """Distance to the convex hull of three spheres: min over barycentric l of |p - c(l)| - r(l).

    At an interior minimum the unit vector u from the foot c(l) to p satisfies u . e_k = -dr_k (k = 2, 3):
    its in-plane part follows from a 2x2 Gram system, its normal part from |u| = 1 (on p's side), and the
    foot from intersecting the ray p - t u with the triangle's plane. When the foot falls outside the
    triangle, or no unit u exists, the minimum of the convex problem is on the boundary: the three cones.
    """
    e2, e3 = c2 - c1, c3 - c1
    d2, d3 = r2 - r1, r3 - r1
    g22 = np.einsum("ij,ij->i", e2, e2)
    g23 = np.einsum("ij,ij->i", e2, e3)
    g33 = np.einsum("ij,ij->i", e3, e3)
    det = g22 * g33 - g23 * g23
    scale = np.maximum(g22 * g33, _EPS)
    ok = det > 1e-10 * scale  # a proper triangle
    sdet = np.where(ok, det, 1.0)
    # in-plane part of u: u_par = alpha e2 + beta e3 with G [alpha, beta] = [-d2, -d3]
    alpha = (-d2 * g33 + d3 * g23) / sdet
    beta = (-d3 * g22 + d2 * g23) / sdet
    u_par = alpha[:, None] * e2 + beta[:, None] * e3
    par2 = np.einsum("ij,ij->i", u_par, u_par)
    ok &= par2 < 1.0 - 1e-12
    n = np.cross(e2, e3)
    n /= np.maximum(np.linalg.norm(n, axis=1), _EPS)[:, None]
    side = np.einsum("ij,ij->i", p - c1, n)
    un = np.sqrt(np.maximum(1.0 - par2, 0.0)) * np.where(side >= 0, 1.0, -1.0)
    u = u_par + un[:, None] * n
    t = np.where(np.abs(un) > _EPS, side / np.where(np.abs(un) > _EPS, un, 1.0), 0.0)  # |p - foot|
    foot = p - t[:, None] * u
    # barycentric coordinates of the foot
    w = foot - c1
    w2 = np.einsum("ij,ij->i", w, e2)
    w3 = np.einsum("ij,ij->i", w, e3)
    l2 = (w2 * g33 - w3 * g23) / sdet
    l3 = (w3 * g22 - w2 * g23) / sdet
    l1 = 1.0 - l2 - l3
    inside = ok & (l1 >= 0) & (l2 >= 0) & (l3 >= 0)
    interior = t - (r1 + l2 * d2 + l3 * d3)
    edges = np.minimum(np.minimum(cone_sdf(p, c1, r1, c2, r2), cone_sdf(p, c2, r2, c3, r3)), cone_sdf(p, c1, r1, c3, r3))
    return np.where(inside, np.minimum(interior, edges), edges)
