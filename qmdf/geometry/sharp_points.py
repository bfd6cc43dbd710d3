"""Sharp convex edges of a point cloud, from each point's neighbourhood split into two planes.

A learned SDF rounds a sharp edge off: its gradients turn gradually across a band around the edge (on the
box, the two clusters of gradients met at 43 degrees, not 90). They still tell which face each neighbour
belongs to, and the neighbours' positions are exact: a plane fitted to each side (k-planes, seeded by the
two clusters of gradients) gives the faces' normals, and the two planes' intersection the edge itself.
A sparse sample of a curved patch splits into two planes too (the block's 1,000-point cloud: 48 of 386 fits
more than 0.02 from any sharp edge, and a quarter of the feature points); one circle across the edge fits
those better than the two planes, while no circle follows a V.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def two_cluster_means(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """g (N, K, 3) unit normals -> the unit means (N, 3) of their two clusters (2-means on the sphere, seeded
    by the most different pair): the normals of the two faces that meet at the feature."""
    cos = np.einsum("nik,njk->nij", g, g)
    n, k = g.shape[:2]
    i, j = np.unravel_index(cos.reshape(n, -1).argmin(1), (k, k))
    c1, c2 = g[np.arange(n), i], g[np.arange(n), j]
    for _ in range(3):
        to1 = np.einsum("nik,nk->ni", g, c1) >= np.einsum("nik,nk->ni", g, c2)
        m1 = (g * to1[..., None]).sum(1)
        m2 = (g * ~to1[..., None]).sum(1)
        c1 = m1 / np.maximum(np.linalg.norm(m1, axis=1, keepdims=True), 1e-12)
        c2 = np.where(
            np.linalg.norm(m2, axis=1, keepdims=True) > 0,
            m2 / np.maximum(np.linalg.norm(m2, axis=1, keepdims=True), 1e-12),
            c1,
        )
    return c1, c2


def _edge_direction(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """(N, 3) unit direction n1 x n2 of the line where two planes meet."""
    t = np.cross(n1, n2)
    return t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)


def _plane(x: np.ndarray, w: np.ndarray, orient: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares planes (normal, centroid) through the points x (N, K, 3) weighted by w (N, K), the
    normal turned to agree with ``orient`` (N, 3)."""
    count = np.maximum(w.sum(1), 1e-12)
    c = np.einsum("nk,nki->ni", w, x) / count[:, None]
    d = x - c[:, None, :]
    _, vecs = np.linalg.eigh(np.einsum("nk,nki,nkj->nij", w, d, d))
    n = vecs[:, :, 0]
    return n * np.where(np.einsum("ni,ni->n", n, orient) < 0, -1.0, 1.0)[:, None], c


@dataclass(frozen=True)
class EdgeFit:
    """Per query point: the nearest point of the two fitted planes' intersection, the planes' normals, how
    many neighbours each plane holds, and whether the edge is convex."""

    point: np.ndarray  # (N, 3)
    n1: np.ndarray  # (N, 3) unit, outward
    n2: np.ndarray  # (N, 3)
    count1: np.ndarray  # (N,) neighbours within the tolerance of plane 1 (and nearer to it than to plane 2)
    count2: np.ndarray  # (N,)
    convex: np.ndarray  # (N,) bool
    shift: np.ndarray  # (N,) distance from the query point to ``point``
    reach: np.ndarray  # (N,) distance to the farthest neighbour
    span: np.ndarray  # (N, 2) along the edge from ``point``: where both planes hold neighbours
    rms_planes: np.ndarray  # (N,) RMS distance of the planes' neighbours to their own plane
    rms_arc: np.ndarray  # (N,) RMS distance of the same neighbours to one circle fitted across the edge

    @property
    def mean_normal(self) -> np.ndarray:
        """(n1 + n2) / 2: the inward bisector's direction, its length the cosine of half the faces' angle."""
        return 0.5 * (self.n1 + self.n2)

    @property
    def direction(self) -> np.ndarray:
        """(N, 3) unit direction of the edge, n1 x n2."""
        return _edge_direction(self.n1, self.n2)

    def sharp(self, dihedral_deg: float, min_count: int, arc_ratio: float = 0.0) -> np.ndarray:
        """Convex edges whose normals turn by more than ``dihedral_deg``, each plane held by at least
        ``min_count`` neighbours, the edge within the neighbourhood; with ``arc_ratio`` > 0, the two planes
        must also fit the neighbours better than one circular arc by that factor (RMS): a sparse sample of a
        curved surface splits into two planes too, but an arc fits it better than two planes do, whereas no
        arc follows a V."""
        turn = np.einsum("ni,ni->n", self.n1, self.n2) < np.cos(np.deg2rad(dihedral_deg))
        held = np.minimum(self.count1, self.count2) >= min_count
        ok = turn & self.convex & held & (self.shift <= self.reach)
        return ok & (self.rms_planes <= arc_ratio * self.rms_arc) if arc_ratio > 0 else ok

    def segments(self, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End points (a, b) of the edge pieces the selected fits see: on a sparse cloud the nearest points
        alone leave gaps between input points; the pieces stop where one of the faces has no more points,
        so not past a corner."""
        t = self.direction[mask]
        return self.point[mask] + self.span[mask, :1] * t, self.point[mask] + self.span[mask, 1:] * t


def _arc_rms(x: np.ndarray, w: np.ndarray, e: np.ndarray, t: np.ndarray) -> np.ndarray:
    """RMS distance of the points x (N, K, 3) weighted by w (N, K) to the circle fitted to them (Kasa's
    algebraic fit) in the plane through e (N, 3) normal to the edge direction t (N, 3)."""
    u = np.cross(t, np.where(np.abs(t[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    v = np.cross(t, u)
    d = x - e[:, None]
    X, Y = np.einsum("nki,ni->nk", d, u), np.einsum("nki,ni->nk", d, v)
    a = np.stack([X, Y, np.ones_like(X)], -1) * w[..., None]
    ata = np.einsum("nki,nkj->nij", a, a) + 1e-15 * np.eye(3)
    coef = np.linalg.solve(ata, np.einsum("nki,nk->ni", a, -(X * X + Y * Y) * w)[..., None])[..., 0]
    cx, cy = -coef[:, 0] / 2, -coef[:, 1] / 2
    r = np.sqrt(np.maximum(cx * cx + cy * cy - coef[:, 2], 0.0))
    off = np.hypot(X - cx[:, None], Y - cy[:, None]) - r[:, None]
    return np.sqrt((w * off * off).sum(1) / np.maximum(w.sum(1), 1.0))


def fit_edges(
    query: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    k: int,
    tolerance: float,
    normal_deg: float = 45.0,
    iterations: int = 3,
    chunk: int = 20_000,
) -> EdgeFit:
    """Two planes through the k nearest ``points`` of each query point: the neighbours split by their
    ``normals`` (2-means), then ``iterations`` rounds of k-planes. A neighbour belongs to a plane within
    ``tolerance`` * the neighbourhood's radius whose normal is within ``normal_deg`` of its own (a learned
    field's gradients turn by up to about 45 degrees across a rounded edge), the nearer one if both; the others
    (a corner's third face, noise, the far side of a curved patch) are left out. Without the normals' say,
    a few points of two faces near a corner can fit one plane."""
    from scipy.spatial import cKDTree

    query = np.asarray(query, np.float64).reshape(-1, 3)
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    tree = cKDTree(points)
    k = min(k, len(points))
    min_cos = np.cos(np.deg2rad(normal_deg))
    parts = []
    for s in range(0, len(query), chunk):
        p = query[s : s + chunk]
        dist, idx = tree.query(p, k=k)
        x, g = points[idx], normals[idx]
        reach = dist[:, -1]
        g1, g2 = two_cluster_means(g)
        w1 = (np.einsum("nki,ni->nk", g, g1) >= np.einsum("nki,ni->nk", g, g2)).astype(np.float64)
        w2 = 1.0 - w1
        for _ in range(iterations):
            n1, c1 = _plane(x, w1, g1)
            n2, c2 = _plane(x, w2, g2)
            d1 = np.abs(np.einsum("nki,ni->nk", x - c1[:, None], n1))
            d2 = np.abs(np.einsum("nki,ni->nk", x - c2[:, None], n2))
            near = tolerance * reach[:, None]
            can1 = (d1 <= near) & (np.einsum("nki,ni->nk", g, n1) >= min_cos)
            can2 = (d2 <= near) & (np.einsum("nki,ni->nk", g, n2) >= min_cos)
            w1 = (can1 & (~can2 | (d1 <= d2))).astype(np.float64)
            w2 = (can2 & ~w1.astype(bool)).astype(np.float64)
        n1, c1 = _plane(x, w1, g1)
        n2, c2 = _plane(x, w2, g2)
        # nearest point of the two planes' intersection: the two plane terms fix the point across the edge,
        # a weak pull toward p fixes it along the edge
        reg = 1e-6
        a = np.einsum("ni,nj->nij", n1, n1) + np.einsum("ni,nj->nij", n2, n2) + reg * np.eye(3)
        b = n1 * np.einsum("ni,ni->n", n1, c1)[:, None] + n2 * np.einsum("ni,ni->n", n2, c2)[:, None] + reg * p
        e = np.linalg.solve(a, b[..., None])[..., 0]
        # convex: each plane's points lie behind the other plane
        behind1 = np.einsum("nk,nk->n", w1, np.einsum("nki,ni->nk", x - e[:, None], n2))
        behind2 = np.einsum("nk,nk->n", w2, np.einsum("nki,ni->nk", x - e[:, None], n1))
        # the edge exists where both faces do: the overlap of the two planes' points along its direction
        along = np.einsum("nki,ni->nk", x - e[:, None], _edge_direction(n1, n2))
        on1, on2 = w1.astype(bool), w2.astype(bool)
        lo = np.maximum(np.where(on1, along, np.inf).min(1), np.where(on2, along, np.inf).min(1))
        hi = np.minimum(np.where(on1, along, -np.inf).max(1), np.where(on2, along, -np.inf).max(1))
        span = np.where((lo <= hi)[:, None], np.stack([lo, hi], 1), 0.0)
        own = np.where(on1, np.einsum("nki,ni->nk", x - c1[:, None], n1), np.einsum("nki,ni->nk", x - c2[:, None], n2))
        held = w1 + w2
        rms_planes = np.sqrt((held * own * own).sum(1) / np.maximum(held.sum(1), 1.0))
        rms_arc = _arc_rms(x, held, e, _edge_direction(n1, n2))
        parts.append(
            (
                e,
                n1,
                n2,
                w1.sum(1),
                w2.sum(1),
                (behind1 < 0) & (behind2 < 0),
                np.linalg.norm(e - p, axis=1),
                reach,
                span,
                rms_planes,
                rms_arc,
            )
        )
    if not parts:
        return EdgeFit(
            *[np.zeros((0, 3))] * 3,
            np.zeros(0),
            np.zeros(0),
            np.zeros(0, bool),
            np.zeros(0),
            np.zeros(0),
            np.zeros((0, 2)),
            np.zeros(0),
            np.zeros(0),
        )
    return EdgeFit(*[np.concatenate(c) for c in zip(*parts)])


def thin(points: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of one point per cell of a ``spacing`` grid (the first one met)."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    _, first = np.unique(np.floor(points / spacing).astype(np.int64), axis=0, return_index=True)
    return np.sort(first)
