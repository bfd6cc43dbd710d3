"""The contraction: collapse the covering's volume onto the medial axis (paper Sec. 4.2, Fig. 8).

Energy over vertex positions, connectivity kept:
    mean over surface vertices of q(v)  +  lambda_volume * max(Vol, 0) / A0  +  lambda_laplacian * mean_i w_i |L v_i|^2
with Vol the enclosed volume (of the tets, or of the closed surface), A0 the initial surface area (so the
volume term is a mean thickness, comparable to q), L the uniform umbrella Laplacian and w_i inversely
proportional to the area around v_i (DCUDF). After ``feature_detect`` (the sharp-feature pass) one more term,
not in the paper, keeps the covering's tips on the feature points: each feature point pulls its nearest
vertex, ``feature_weight`` * sum_j |v_k(j) - p_j| / N; without it the tips slid back along the retrained
field's shallow valley (measured on the box: sharp-edge samples within 0.01 of the covering 0.97, of the
membrane 0.32). Near the feature points, ``zip_weight`` also pulls each vertex toward the facing
layer (``LayerZip``), a local volume term that closes the tips the global one leaves open in a V. Not in the
paper either: the vertices read q + ``outside_weight`` * max(sdf, 0) (``InsideQ``), so q does not fall
outside the shape and the vertices of thin parts stay in. Steps: a per-vertex ("vector") Adam with cosine decay.
q is read from a lazily evaluated fine lattice (``lattice``), so thousands of iterations cost seconds, not minutes.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from dataclasses import dataclass

from qmdf.errors import QmdfError
from qmdf.geometry.rows import unique_rows
from qmdf.geometry.triangles import face_areas
from qmdf.schema import param


@dataclass
class ContractionSettings:
    """``contract``'s settings: the ``contract`` stage's config (``contract.*``), one source for both."""

    iterations: int = param(
        3000,
        ge=1,
        doc="optimisation steps, cosine-decayed (paper: about 3k); 1,000 kept CD / HD but left the bunny's body a "
        "tangle of lone edges (676 against 342, docs/results.md)",
    )
    lr: float = param(5e-4, gt=0, doc="step length in the unit box (DCUDF: 5e-4), cosine-decayed")
    lr_final: float = param(1e-6, gt=0)
    lambda_volume: float = param(1.0, ge=0, doc="weight of the enclosed volume (per initial area)")
    lambda_laplacian: float = param(100.0, ge=0, doc="weight of the area-weighted Laplacian smoothness")
    lattice: float = param(
        1e-3,
        ge=0,
        doc="spacing of the lazily evaluated q lattice the vertices read (its error "
        "is below half of it); 0: evaluate the field at every vertex in every iteration",
    )
    feature_weight: float = param(
        10.0,
        ge=0,
        doc="pull of each feature point on its nearest vertex, where a "
        "feature_detect stage ran before (0: the paper's energy)",
    )
    feature_reach: float = param(
        0.02,
        gt=0,
        doc="feature points farther than this from the covering pull nothing "
        "(the covering never reached them; unit box)",
    )
    zip_weight: float = param(
        1000.0,
        ge=0,
        doc="near the feature points, pull of each vertex toward the facing "
        "layer within zip_reach: a local volume term that closes the tips (0: the paper's energy; "
        "acts only where a feature_detect stage ran before)",
    )
    zip_reach: float = param(
        0.02,
        gt=0,
        doc="how far the facing layer may be (unit box; 0.01 folded 4 to 13 points fewer "
        "of the sharp-edge samples on the procedural and well-fitted CAD shapes)",
    )
    zip_near: float = param(0.05, gt=0, doc="vertices within this of a feature point are zipped (unit box)")
    outside_weight: float = param(
        2.0,
        ge=0,
        doc="the vertices minimise q + outside_weight * max(sdf, 0): 2 continues "
        "q = mf - |sdf| as mf + sdf outside the shape, so q rises there instead of falling "
        "(0: the paper's q everywhere, which let the vertices of thin parts leave the shape)",
    )
    log_every: int = param(25, ge=1)


class InsideQ:
    """``field`` with q replaced by q + weight * max(sdf, 0), the contraction's objective. Inside the shape it
    is q. Outside, q = mf - |sdf| falls as the distance grows, and vertices of thin parts walked out along it
    (abc_00000329, a 0.02-thick plate: 1386 of 15077 membrane vertices ended more than 0.02 outside the learned
    surface, the largest at 0.097, and their spheres set the reconstruction's HD); with weight 2 it continues
    as mf + sdf, which rises outward wherever mf does not fall faster than the distance grows."""

    def __init__(self, field, weight: float):
        self.field, self.weight = field, float(weight)
        self.normalization = getattr(field, "normalization", None)

    def evaluate(self, points: np.ndarray, grad: bool = False) -> dict[str, np.ndarray]:
        out = self.field.evaluate(points, grad=grad)
        outside = out["sdf"] > 0
        out["q"] = out["q"] + self.weight * np.where(outside, out["sdf"], 0).astype(out["q"].dtype)
        if grad:
            out["q_grad"] = out["q_grad"] + self.weight * outside[:, None] * out["sdf_grad"]
        return out


def umbrella(n_vertices: int, faces: np.ndarray):
    """Sparse uniform Laplacian L = I - D^-1 A of a triangle mesh (scipy CSR)."""
    from scipy import sparse

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = unique_rows(np.sort(e, axis=1))
    rows = np.concatenate([e[:, 0], e[:, 1]])
    cols = np.concatenate([e[:, 1], e[:, 0]])
    deg = np.bincount(rows, minlength=n_vertices).astype(np.float64)
    A = sparse.csr_matrix((1.0 / np.maximum(deg[rows], 1), (rows, cols)), shape=(n_vertices, n_vertices))
    return (sparse.diags((deg > 0).astype(np.float64)) - A).tocsr()


def area_weights(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """w_i = max_j sqrt(A_j) / sqrt(A_i), A_i the area of the faces around vertex i (DCUDF)."""
    area = face_areas(v, faces)
    a = np.bincount(faces.ravel(), np.repeat(area, 3), minlength=len(v))
    a = np.maximum(a, 1e-20)
    return np.sqrt(a.max()) / np.sqrt(a)


class EnclosedVolume:
    """Enclosed volume (of the tets, else of the closed surface by the divergence theorem) and its gradient,
    closed-form: per triangle (v1 x v2, v2 x v0, v0 x v1) / 6, per tet likewise; one sparse product sums the
    corner contributions into the vertices."""

    def __init__(self, n_vertices: int, faces: np.ndarray | None, tets: np.ndarray | None):
        from scipy import sparse

        self.cells = np.asarray(tets if tets is not None else faces)
        self.sum_corners = sparse.csr_matrix(
            (np.ones(self.cells.size), (self.cells.T.ravel(), np.arange(self.cells.size))),
            shape=(n_vertices, self.cells.size),
        )
        # per vertex, the next two vertices of each face it is a corner of (column slot * n_cells + cell), for
        # the surface kernel's per-vertex sums
        self.corner_ptr = self.sum_corners.indptr.astype(np.int64)
        cell, slot = self.sum_corners.indices % len(self.cells), self.sum_corners.indices // len(self.cells)
        if self.cells.shape[1] == 3:
            self.corner_next = np.stack(
                [self.cells[cell, (slot + 1) % 3], self.cells[cell, (slot + 2) % 3]], -1
            ).astype(np.int64)

    def __call__(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        c = self.cells
        if c.shape[1] == 3:
            grad = np.empty_like(x)
            return _surface_volume(x, c, self.corner_ptr, self.corner_next, grad), grad
        if c.shape[1] == 4:
            a, b, cc, d = (x[c[:, k]] for k in range(4))
            ab, ac, ad = b - a, cc - a, d - a
            gb, gc, gd = np.cross(ac, ad) / 6, np.cross(ad, ab) / 6, np.cross(ab, ac) / 6
            vol = float((gd * ad).sum())
            return vol, self.sum_corners @ np.vstack([-(gb + gc + gd), gb, gc, gd])
        v0, v1, v2 = (x[c[:, k]] for k in range(3))
        g0, g1, g2 = np.cross(v1, v2) / 6, np.cross(v2, v0) / 6, np.cross(v0, v1) / 6
        return float((v0 * g0).sum()), self.sum_corners @ np.vstack([g0, g1, g2])


@njit(cache=True, parallel=True)
def _surface_volume(x, faces, corner_ptr, corner_next, grad):
    """The divergence-theorem volume of a closed surface; its gradient written into grad, each vertex's summed
    over its corners (``corner_ptr``/``corner_next``: per vertex, CSR, the next two vertices of each face it is a
    corner of, in the face's order), so the vertices run in parallel with no shared writes."""
    vol = 0.0
    for f in prange(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        vol += (
            x[i, 0] * (x[j, 1] * x[k, 2] - x[j, 2] * x[k, 1])
            + x[i, 1] * (x[j, 2] * x[k, 0] - x[j, 0] * x[k, 2])
            + x[i, 2] * (x[j, 0] * x[k, 1] - x[j, 1] * x[k, 0])
        ) / 6
    for v in prange(x.shape[0]):
        gx = gy = gz = 0.0
        for m in range(corner_ptr[v], corner_ptr[v + 1]):
            j, k = corner_next[m, 0], corner_next[m, 1]  # the corner's gradient is (x_j x x_k) / 6
            gx += (x[j, 1] * x[k, 2] - x[j, 2] * x[k, 1]) / 6
            gy += (x[j, 2] * x[k, 0] - x[j, 0] * x[k, 2]) / 6
            gz += (x[j, 0] * x[k, 1] - x[j, 1] * x[k, 0]) / 6
        grad[v, 0], grad[v, 1], grad[v, 2] = gx, gy, gz
    return vol


@njit(cache=True, inline="always")  # inlined in numba's IR: as a call it ran 1.6x slower
def _row_product(ptr, idx, val, y, i):
    """Row i of a CSR matrix times the n x 3 array y, the three coordinates in one pass over the row (each sum in
    scipy's order)."""
    ax = ay = az = 0.0
    for m in range(ptr[i], ptr[i + 1]):
        j, v = idx[m], val[m]
        ax += v * y[j, 0]
        ay += v * y[j, 1]
        az += v * y[j, 2]
    return ax, ay, az


@njit(cache=True, parallel=True)
def _add_smoothness_gradient(l_ptr, l_idx, l_val, t_ptr, t_idx, t_val, x, w, coef, g, lap, weighted):
    """lap = L x, weighted = W lap and g += coef * L^T weighted, the Laplacian energy's gradient, in one pass per
    product (L^T as its own CSR, summed in scipy's order, so the result is scipy's to the bit; two scipy
    products and the temporaries took 5 s of the teacup's 3,000 iterations). Rows run in parallel: each row's
    sum keeps its order."""
    for i in prange(x.shape[0]):
        ax, ay, az = _row_product(l_ptr, l_idx, l_val, x, i)
        lap[i, 0], lap[i, 1], lap[i, 2] = ax, ay, az
        weighted[i, 0], weighted[i, 1], weighted[i, 2] = w[i] * ax, w[i] * ay, w[i] * az
    for i in prange(x.shape[0]):
        ax, ay, az = _row_product(t_ptr, t_idx, t_val, weighted, i)
        g[i, 0] += coef * ax
        g[i, 1] += coef * ay
        g[i, 2] += coef * az


@njit(cache=True, parallel=True)
def _vector_adam(x, g, m, s, lr, t, b1, b2):
    """Adam with one second moment per vertex (isotropic steps, as DCUDF), in place. (No default arguments: a
    call that omits one takes numba's slow dispatch, 110 us against 3.)"""
    c1, c2 = 1 - b1**t, 1 - b2**t
    for n in prange(x.shape[0]):
        sq = 0.0
        for k in range(3):
            m[n, k] = b1 * m[n, k] + (1 - b1) * g[n, k]
            sq += g[n, k] * g[n, k]
        s[n] = b2 * s[n] + (1 - b2) * sq
        denom = math.sqrt(s[n] / c2) + 1e-16
        for k in range(3):
            x[n, k] -= lr * (m[n, k] / c1) / denom


class FeaturePull:
    """sum_j |v_k(j) - p_j| over the feature points p_j within ``reach`` of their nearest vertex v_k(j), with
    the assignment refreshed every ``refresh`` iterations (a KD-tree query: milliseconds)."""

    def __init__(self, features: np.ndarray, candidates: np.ndarray, reach: float, refresh: int = 10):
        self.features = np.asarray(features, np.float64)
        self.candidates, self.reach, self.refresh = candidates, reach, refresh
        self.vertex = np.zeros(0, np.int64)
        self.active = np.zeros(len(self.features), bool)

    def assign(self, x: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        d, i = cKDTree(x[self.candidates]).query(self.features)
        self.active = d < self.reach
        self.vertex = self.candidates[i[self.active]]

    def __call__(self, x: np.ndarray, it: int, g: np.ndarray, weight: float) -> float:
        """Adds weight * the gradient into g; returns the mean distance of the pulling feature points."""
        if it % self.refresh == 0:
            self.assign(x)
        if not len(self.vertex):
            return 0.0
        diff = x[self.vertex] - self.features[self.active]
        dist = np.linalg.norm(diff, axis=1)
        np.add.at(g, self.vertex, weight * diff / np.maximum(dist, 1e-12)[:, None])
        return float(dist.mean())


class LayerZip:
    """Near the feature points, pulls each covering vertex toward the nearest vertex of the opposite layer
    within ``reach`` (normals facing each other, turning by more than 120 degrees; the partner behind the
    vertex): sum_v |v - u_v|^2 / 2, the pairs refreshed every ``refresh`` iterations. The enclosed volume is
    one global number: once it reaches zero (layers crossing somewhere) it pushes nowhere, and a sheet's tip at
    a sharp edge, where q is flat (mf and |sdf| both near 0), stays open in a V (measured on the box: turning
    angle 106 degrees at the misses, not the fold's 180). Only near features: elsewhere the nearest vertex is
    not straight across, and the sideways pull retracted smooth sheets' rims (the exact ellipsoid's HD went
    from 8e-4 to 3.5e-3)."""

    def __init__(
        self,
        faces: np.ndarray,
        candidates: np.ndarray,
        features: np.ndarray,
        near: float,
        reach: float,
        refresh: int = 10,
    ):
        from scipy.spatial import cKDTree

        self.faces, self.candidates, self.reach, self.refresh, self.near = faces, candidates, reach, refresh, near
        self.features = cKDTree(features)
        self.partner_of = np.full(int(faces.max()) + 1 if len(faces) else 0, -1)
        self.vertex = self.partner = np.zeros(0, np.int64)

    def assign(self, x: np.ndarray) -> None:
        """New pairs for the unpaired vertices; a pair holds while the two stay within reach, also once they
        have crossed (with Adam's normalised steps they overshoot, and the pull must bring them back)."""
        from scipy.spatial import cKDTree

        held = self.partner_of >= 0
        held[held] = np.linalg.norm(x[held] - x[self.partner_of[held]], axis=1) < self.reach
        self.partner_of[~held] = -1
        tri = x[self.faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # area-weighted face normals
        n = np.zeros_like(x)
        for k in range(3):
            np.add.at(n, self.faces[:, k], fn)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        c = self.candidates
        d, j = cKDTree(x[c]).query(x[c], k=16, distance_upper_bound=self.reach)
        j = np.where(np.isfinite(d), j, 0)
        u = c[j]  # (M, 16)
        facing = np.einsum("mi,mki->mk", n[c], n[u]) < -0.5
        behind = np.einsum("mi,mki->mk", n[c], x[u] - x[c][:, None]) < 0
        ok = np.isfinite(d) & facing & behind
        new = ok.any(1) & (self.partner_of[c] < 0) & (self.features.query(x[c])[0] < self.near)
        first = np.argmax(ok, axis=1)  # the nearest such partner (queries come sorted by distance)
        self.partner_of[c[new]] = u[new, first[new]]
        self.vertex = np.flatnonzero(self.partner_of >= 0)
        self.partner = self.partner_of[self.vertex]

    def __call__(self, x: np.ndarray, it: int, g: np.ndarray, weight: float) -> int:
        """Adds weight * the gradient into g; returns how many vertices are pulled."""
        if it % self.refresh == 0:
            self.assign(x)
        np.add.at(g, self.vertex, weight * (x[self.vertex] - x[self.partner]))
        return len(self.vertex)


def volume_and_gradient(x: np.ndarray, faces: np.ndarray | None, tets: np.ndarray | None) -> tuple[float, np.ndarray]:
    return EnclosedVolume(len(x), faces, tets)(x)


def contract(
    field,
    vertices: np.ndarray,
    faces: np.ndarray,
    tets: np.ndarray | None = None,
    *,
    features: np.ndarray | None = None,
    settings: ContractionSettings = ContractionSettings(),
    on_iteration=None,
):
    """The contracted vertices, the per-iteration log of the energy terms and the volume, the initial volume,
    and how many field evaluations it took (see the module doc for the energy; ``ContractionSettings``
    documents each weight). ``features``: feature points whose nearest vertices are pulled; ``on_iteration(done,
    total)`` is called after every iteration. Gradients are closed-form (no autograd): the volume's per triangle
    (or tet), the Laplacian energy's 2/N L^T W L x."""

    from qmdf.fields.lattice import LatticeQ
    from qmdf.geometry.tets import signed_volumes

    c = settings
    x = np.array(vertices, np.float64)
    if c.outside_weight > 0:
        field = InsideQ(field, c.outside_weight)
    surf = np.unique(faces)
    if tets is not None and signed_volumes(vertices, tets).sum() < 0:
        tets = tets[:, [0, 2, 1, 3]]
    L = umbrella(len(x), faces)
    LT = L.T.tocsr()
    lap_coef = c.lambda_laplacian * (2.0 / len(x))
    lap, weighted = np.empty_like(x), np.empty_like(x)
    area0 = float(face_areas(x, faces).sum())
    w = area_weights(x, faces)
    margin = 0.05
    q_lattice = LatticeQ(field, c.lattice, x.min(0) - margin, x.max(0) + margin) if c.lattice > 0 else None
    q_of = _QGradient(field, q_lattice, surf, len(x))
    enclosed = EnclosedVolume(len(x), faces, tets)
    m = np.zeros_like(x)
    s = np.zeros(len(x))
    history = []
    has_features = features is not None and len(features) > 0
    pull = FeaturePull(features, surf, c.feature_reach) if has_features and c.feature_weight > 0 else None
    zipper = LayerZip(faces, surf, features, c.zip_near, c.zip_reach) if has_features and c.zip_weight > 0 else None
    extra: dict = {}
    vol0 = enclosed(x)[0]
    for it in range(c.iterations):
        q, g = q_of(x)
        vol, vol_grad = enclosed(x)
        # max(Vol, 0): the signed volume has no minimum at zero; once the layers meet it would keep pushing
        # them through each other (measured: the box's covering diverged to -2e3 without the clamp)
        if vol > 0:
            g += c.lambda_volume / area0 * vol_grad
        _add_smoothness_gradient(
            L.indptr, L.indices, L.data, LT.indptr, LT.indices, LT.data, x, w, lap_coef, g, lap, weighted
        )
        if pull is not None:
            extra["feature_distance"] = pull(x, it, g, c.feature_weight / len(surf))
            extra["pulling_features"] = int(pull.active.sum())
        if zipper is not None:
            extra["zipped_vertices"] = zipper(x, it, g, c.zip_weight / len(surf))
        step = c.lr_final + (c.lr - c.lr_final) * 0.5 * (1 + math.cos(math.pi * it / c.iterations))
        _vector_adam(x, g, m, s, step, it + 1, 0.9, 0.999)
        if on_iteration is not None:  # progress for the caller (the stage's heartbeat)
            on_iteration(it + 1, c.iterations)
        if it % c.log_every == 0 or it == c.iterations - 1:
            e_lap = float((weighted * lap).sum(1).mean())
            geom = c.lambda_volume * max(vol, 0.0) / area0 + c.lambda_laplacian * e_lap
            energy = float(q.mean()) + geom
            history.append(
                {"iteration": it, "q_mean": float(q.mean()), "volume": vol, "laplacian": e_lap, "energy": energy}
                | {"lr": step, **extra}
            )
            if not np.isfinite(energy):
                raise QmdfError(f"contraction diverged at iteration {it}; lower contract.lr")
    evaluations = q_lattice.evaluated if q_lattice is not None else q_of.evaluations
    return x, history, vol0, evaluations


class _QGradient:
    """q at the covering's surface vertices and its gradient, per vertex, as the energy's mean q wants it: from the
    lazily evaluated lattice, else from the field at every vertex (counted in ``evaluations``); inner (tet)
    vertices get none."""

    def __init__(self, field, lattice, surf: np.ndarray, n: int):
        self.field, self.lattice, self.surf, self.n = field, lattice, surf, n
        self.all_surface = len(surf) == n  # a surface covering: no inner (tet) vertices to leave out of q
        self.evaluations = 0

    def __call__(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        at = x if self.all_surface else x[self.surf]
        if self.lattice is not None:
            q, qg = self.lattice(at)
        else:
            out = self.field.evaluate(at, grad=True)
            q, qg = out["q"], out["q_grad"]
            self.evaluations += len(self.surf)
        if self.all_surface:
            return q, np.asarray(qg, np.float64) / len(self.surf)
        g = np.zeros_like(x)
        g[self.surf] = qg / len(self.surf)
        return q, g


def surface_mesh(x: np.ndarray, faces: np.ndarray):
    """The contracted surface as a mesh of its own vertices (a tet covering's inner vertices dropped)."""
    import trimesh

    used = np.unique(faces)
    remap = np.full(len(x), -1)
    remap[used] = np.arange(len(used))
    return trimesh.Trimesh(x[used], remap[faces], process=False)
