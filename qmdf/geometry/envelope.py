"""Exact signed distances to the envelopes of medial primitives, and to their union (the MAT's shape).

A medial mesh reconstructs its shape as the union of the envelopes of its primitives (Li et al., Q-MAT):
spheres (isolated vertices), cones (the convex hull of the two spheres of an edge) and slabs (of the three
spheres of a face). Each primitive's SDF is ``min over the primitive's centre set of |p - c| - r`` with c and
r interpolated linearly; the minimisation is convex and solved in closed form here. All functions are
vectorised over pairs of points and primitives: arrays of shape (N, 3) and (N,).
"""

from __future__ import annotations

import numpy as np

from qmdf.geometry.metrics import edges_off_polygons
from qmdf.geometry.rows import unique_rows

_EPS = 1e-12


def sphere_sdf(p: np.ndarray, c: np.ndarray, r: np.ndarray):
    return np.linalg.norm(p - c, axis=-1) - r, c, r


def cone_sdf(p: np.ndarray, c1: np.ndarray, r1: np.ndarray, c2: np.ndarray, r2: np.ndarray):
    """Distance to the convex hull of spheres (c1, r1) and (c2, r2): min over t in [0,1] of |p - c(t)| - r(t).

    Returns (distance, foot centre, foot radius): the minimising sphere, whose boundary holds the nearest
    point of the envelope, ``foot_c + foot_r * (p - foot_c) / |p - foot_c|``."""
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
    # Improper cone (one sphere holds the other) or coincident centres: the minimum is at an end.
    end_t = np.where(np.linalg.norm(q, axis=1) - r1 <= np.linalg.norm(p - c2, axis=1) - r2, 0.0, 1.0)
    t = np.where(proper & (a > _EPS), t, end_t)
    foot_c = c1 + t[:, None] * d
    foot_r = r1 + t * dr
    return np.linalg.norm(p - foot_c, axis=1) - foot_r, foot_c, foot_r


def slab_sdf(p, c1, r1, c2, r2, c3, r3):
    """Distance to the convex hull of three spheres: min over barycentric l of |p - c(l)| - r(l).
    Returns (distance, foot centre, foot radius) as ``cone_sdf`` does.

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
    foot_r = r1 + l2 * d2 + l3 * d3
    best, best_c, best_r = np.where(inside, t - foot_r, np.inf), foot, foot_r
    # With an interior stationary point, convexity makes it the minimum; only the others need the cones.
    edge = np.flatnonzero(~inside)
    if len(edge):
        pe = p[edge]
        for a, ra, b, rb in ((c1, r1, c2, r2), (c2, r2, c3, r3), (c1, r1, c3, r3)):
            val, fc, fr = cone_sdf(pe, a[edge], ra[edge], b[edge], rb[edge])
            better = val < best[edge]
            sel = edge[better]
            best[sel], best_c[sel], best_r[sel] = val[better], fc[better], fr[better]
    return best, best_c, best_r


class EnvelopeUnion:
    """The shape a medial mesh reconstructs: the union of its slabs (faces), cones (edges in no face) and
    spheres (vertices in neither). ``sdf`` is its exact signed distance outside and its exact zero set;
    inside, min over primitives bounds the depth from below (as for any union of SDFs).

    A bounding-volume hierarchy over the primitives' bounding balls makes it fast: each point visits the
    nearest nodes first and skips every node whose balls cannot go below its best value so far, in one
    compiled loop (``_envelope_kernels.union_min``).
    """

    def __init__(
        self, centers: np.ndarray, radii: np.ndarray, edges: np.ndarray, faces: np.ndarray, leaf_size: int = 4
    ):
        from qmdf.geometry._bvh import build_bvh

        self.c = np.asarray(centers, np.float64)
        self.r = np.asarray(radii, np.float64)
        if len(self.c) == 0:
            raise ValueError("a medial mesh without vertices has no envelope")
        faces = np.asarray(faces, np.int64).reshape(-1, 3)
        edges = np.asarray(edges, np.int64).reshape(-1, 2)
        edges = edges[edges[:, 0] != edges[:, 1]]
        edges = unique_rows(np.sort(edges, axis=1))
        lone = edges[edges_off_polygons(edges, faces)]
        used = np.zeros(len(self.c), bool)
        used[faces.ravel()] = True
        used[lone.ravel()] = True
        # kind 0: sphere, 1: cone, 2: slab; each primitive as 3 vertex indices (repeated for lower kinds)
        spheres = np.flatnonzero(~used)
        self.prims = np.concatenate(
            [
                np.repeat(spheres[:, None], 3, 1),
                np.column_stack([lone, lone[:, 1]]),
                faces,
            ]
        ).astype(np.int64)
        self.kind = np.concatenate([np.zeros(len(spheres)), np.ones(len(lone)), np.full(len(faces), 2)]).astype(np.int8)
        pc = self.c[self.prims]  # (P, 3, 3)
        self.anchor = pc.mean(1)
        self.rho = (np.linalg.norm(pc - self.anchor[:, None], axis=2) + self.r[self.prims]).max(1)
        self._bvh = build_bvh(self.anchor, self.rho, leaf_size)

    @classmethod
    def from_mat(cls, mat) -> "EnvelopeUnion":
        return cls(mat.vertices, mat.radii, mat.edges, mat.faces)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return (self.c - self.r[:, None]).min(0), (self.c + self.r[:, None]).max(0)

    def eval_prims(self, p: np.ndarray, prim: np.ndarray):
        """(distance, foot centre, foot radius) of primitive ``prim[i]`` at point ``p[i]``."""
        ids = self.prims[prim]
        c, r = self.c[ids], self.r[ids]
        out_d = np.empty(len(p))
        out_c = np.empty((len(p), 3))
        out_r = np.empty(len(p))
        kind = self.kind[prim]
        for k, fn in (
            (0, lambda q, cc, rr: sphere_sdf(q, cc[:, 0], rr[:, 0])),
            (1, lambda q, cc, rr: cone_sdf(q, cc[:, 0], rr[:, 0], cc[:, 1], rr[:, 1])),
            (2, lambda q, cc, rr: slab_sdf(q, cc[:, 0], rr[:, 0], cc[:, 1], rr[:, 1], cc[:, 2], rr[:, 2])),
        ):
            sel = kind == k
            if sel.any():
                out_d[sel], out_c[sel], out_r[sel] = fn(p[sel], c[sel], r[sel])
        return out_d, out_c, out_r

    def sdf(self, points: np.ndarray, band: float | None = None, return_argmin: bool = False):
        """Signed distance of ``points`` to the union. With ``band``, points provably farther than ``band``
        from the surface get a bound of the right sign instead of the exact value (enough for meshing): just
        over ``band`` outside, below ``-band`` inside. With ``return_argmin``, also the index of the primitive
        attaining the minimum (-1 where bounded outside)."""
        from qmdf.geometry._envelope_kernels import union_min

        points = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
        arg = np.full(len(points), -1, np.int64)
        if band is None:
            best, stop = np.full(len(points), np.inf), np.full(len(points), -np.inf)
        else:
            best = np.full(len(points), np.nextafter(float(band), np.inf))
            stop = np.full(len(points), -float(band))
        union_min(
            points, best, stop, arg, tuple(self._bvh), (self.prims, self.kind, self.c, self.r, self.anchor, self.rho)
        )
        return (best, arg) if return_argmin else best

    def snap(self, points: np.ndarray, argmin: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Project points onto the boundary of the primitive that attains the union's minimum there (for a
        point inside, the deepest one). Returns (projected points, their union SDF: ~0 where exposed)."""
        arg = self.sdf(points, return_argmin=True)[1] if argmin is None else argmin
        has = arg >= 0
        out = points.copy()
        _, fc, fr = self.eval_prims(points[has], arg[has])
        v = points[has] - fc
        n = np.linalg.norm(v, axis=1, keepdims=True)
        out[has] = fc + fr[:, None] * v / np.maximum(n, _EPS)
        return out, self.sdf(out)


def reconstruct_mesh(union: EnvelopeUnion, resolution: int = 256):
    """The union's boundary as a triangle mesh (marching cubes on a narrow-band grid)."""
    from qmdf.geometry.grid import narrow_band_level_set

    lo, hi = union.bounds
    pad = 3.0 * float((hi - lo).max()) / (resolution - 1)
    grid = narrow_band_level_set(lambda p, band: union.sdf(p, band=band), lo - pad, hi + pad, resolution)
    return grid.mesh()


def sample_union_surface(
    union: EnvelopeUnion, count: int, rng: np.random.Generator, resolution: int = 128, mesh=None
) -> np.ndarray:
    """``count`` points exactly on the union's boundary, nearly uniform by area: uniform samples of the
    marching-cubes surface, each snapped onto the primitive that attains the union there."""
    from qmdf.geometry.sampling import sample_surface

    mesh = mesh if mesh is not None else reconstruct_mesh(union, resolution)
    if mesh is None:
        raise ValueError("the medial mesh reconstructs to an empty surface")
    out = np.empty((0, 3))
    tol = 1e-9 * max(1.0, float(np.abs(mesh.vertices).max()))
    for _ in range(8):
        need = count - len(out)
        raw = sample_surface(np.asarray(mesh.vertices), np.asarray(mesh.faces), int(need * 1.3) + 16, rng).points
        snapped, d = union.snap(raw)
        out = np.vstack([out, snapped[np.abs(d) <= tol]])
        if len(out) >= count:
            return out[:count]
    raise ValueError("could not snap enough samples onto the envelope")
