"""Fit a medial mesh's spheres to the data's surface: Gauss-Newton on the envelope's distance to surface samples.

The sheet's vertices come from the grid and its radii from the data's distance at each vertex, so each ball
touches the surface somewhere, but the slabs and cones between the balls, which make most of the envelope, need
not: on a curved sheet or near a sharp edge the envelope falls short of the surface between vertices (the sharp
sphere's CD 1.1e-3 against its membrane's 0.6e-3). This moves every free vertex's centre and radius so that the
union's signed distance at the surface samples goes to zero, in the least-squares sense.

At a sample p whose nearest primitive has the foot centre c(l) = sum_k l_k c_k and radius r(l) = sum_k l_k r_k
(l the foot's barycentric weights over the primitive's vertices), the distance is d = |p - c(l)| - r(l); with
the foot's weights held (their change moves d only to second order at the minimum), its derivative is
-l_k (u, 1) in vertex k's (centre, radius), u the unit vector from the foot to p. Each step solves the damped
linear least squares ``min |J s + d|^2 + damping^2 |s|^2`` (``scipy.sparse.linalg.lsqr``), the damping in units
of one vertex's share of the samples so that it means the same at any sample count: a Levenberg-Marquardt step
that keeps vertices with few samples, and the flat directions along the sheet, where they are.

The rims' fairness. Where the medial axis of a smooth surface ends, it ends in a smooth curve (the centres of
curvature of the surface's ridges), but the samples alone do not say where along the sheet a rim vertex sits: a
rim ball that touches the surface fits it from anywhere on a strip of the axis, so the fit leaves the rim the
sawtooth the grid's collapse made (the bunny's median rim vertex turned by 88 degrees). ``rim_fairness`` adds the
residual w (b_i - (b_a + b_b) / 2) for each rim vertex i between its rim neighbours a and b, b a ball's centre and
radius (a discrete curvature of the rim's curve of balls, linear in them), in the same units as the damping, so
the least-squares fit picks, among the envelopes that fit the samples, the one with the smoothest rims. The
radius is in it because a rim ball faired by its centre alone can lose its samples and shrink to nothing (16
balls of no radius inside the bunny); along a smooth rim the radius varies smoothly too.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from qmdf.geometry.triangles import barycentric
from qmdf.schema import param


@dataclass
class FitSettings:
    """The sheet's ``fit`` step (``sheet.step.fit``) and ``fit_envelope_to_samples``' defaults."""

    iterations: int = param(
        12,
        ge=1,
        doc="damped Gauss-Newton steps. Sharp sphere under +experiment=cad_features, 3,000 vertices, samples alone: "
        "CD / HD 1.14e-3 / 14.3e-3 (no fit) -> 0.51e-3 / 10.5e-3 (6, 3.8 s) -> 0.49e-3 / 9.8e-3 (12, 6.8 s); the "
        "bunny's 0.54e-3 / 5.5e-3 (6) -> 0.51e-3 / 7.9e-3 (12); with the rims' fairness 12 (docs/results.md)",
    )
    rim_fairness: float = param(
        0.03,
        ge=0,
        doc="weight of the rims' curvature beside the samples' distances, per vertex's share of the samples "
        "(module doc; 0: the samples alone). Bunny, 12 steps: C_avg 1.34 -> 0.82 at 0.03 at the same CD and HD "
        "(docs/results.md: more weight, smoother rims and a worse fit)",
    )
    damping: float = param(
        0.12,
        gt=0,
        doc="Levenberg-Marquardt damping, per vertex's share of the samples: lower moves further per step and "
        "overshoots, higher needs more steps (sharp sphere, cad_features, 6 steps: CD 0.59e-3 at 0.04, 0.51e-3 "
        "at 0.12, 0.58e-3 at 0.4)",
    )


_DEFAULT = FitSettings()


def foot_weights(foot: np.ndarray, corners: np.ndarray, kind: np.ndarray) -> np.ndarray:
    """Weights (K, 3) of ``foot`` (K, 3) over its primitive's corners (K, 3, 3): a sphere's (kind 0) all on its
    one vertex, a cone's (kind 1) on its two ends by the foot's place along the segment, a slab's (kind 2) its
    barycentric coordinates, clipped to the triangle."""
    w = np.zeros((len(foot), 3))
    w[kind == 0, 0] = 1.0
    cone = kind == 1
    a, b = corners[cone, 0], corners[cone, 1]
    ab = b - a
    t = np.clip(((foot[cone] - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-30), 0.0, 1.0)
    w[cone, 0], w[cone, 1] = 1.0 - t, t
    slab = kind == 2
    lam = np.clip(barycentric(foot[slab], corners[slab]), 0.0, None)
    w[slab] = lam / np.maximum(lam.sum(1, keepdims=True), 1e-30)
    return w


class _RimCurvature:
    """The rims' fairness rows (module doc): w (b_i - (b_a + b_b) / 2) for every free rim vertex i with exactly two
    rim neighbours a, b (where rims meet or end there is no curve to fair), b a ball's centre and radius."""

    def __init__(self, faces: np.ndarray, free: np.ndarray, weight: float):
        from qmdf.geometry.metrics import single_face_edges

        rim = single_face_edges(np.asarray(faces, np.int64).reshape(-1, 3))
        n = len(free)
        order = np.argsort(rim.ravel(), kind="stable")
        ends = rim.ravel()[order]
        other = rim[:, ::-1].ravel()[order]  # each rim edge's far end, grouped by near end
        count = np.bincount(ends, minlength=n)
        first = np.concatenate([[0], np.cumsum(count)[:-1]])
        self.i = np.flatnonzero((count == 2) & free)
        self.a, self.b = other[first[self.i]], other[first[self.i] + 1]
        self.weight, self.free = weight, free

    def residual(self, balls: np.ndarray) -> np.ndarray:
        """Of the (V, 4) balls (centre, radius)."""
        return self.weight * (balls[self.i] - 0.5 * (balls[self.a] + balls[self.b]))

    def energy(self, balls: np.ndarray) -> float:
        res = self.residual(balls)
        return float((res * res).sum())

    def append(self, balls, first_row, rows, cols, vals, residual):
        """The rows below the samples' (rows from ``first_row``) and their right-hand side, -residual."""
        k = len(self.i)
        for j in range(4):
            row = first_row + 4 * np.arange(k) + j
            for who, coef in ((self.i, 1.0), (self.a, -0.5), (self.b, -0.5)):
                moves = self.free[who]  # a fixed neighbour (a feature tip) is a constant here
                rows.append(row[moves])
                cols.append(4 * who[moves] + j)
                vals.append(np.full(int(moves.sum()), self.weight * coef))
        return rows, cols, vals, np.concatenate([residual, -self.residual(balls).ravel()])


def fit_envelope_to_samples(
    vertices: np.ndarray,
    radii: np.ndarray,
    edges: np.ndarray,
    faces: np.ndarray,
    samples: np.ndarray,
    fixed: np.ndarray | None = None,
    iterations: int = _DEFAULT.iterations,
    damping: float = _DEFAULT.damping,
    rim_fairness: float = _DEFAULT.rim_fairness,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Move the medial mesh's centres and radii (``edges``: its lone edges; ``faces``) so that its envelope passes
    through the surface ``samples`` (N, 3): ``iterations`` damped Gauss-Newton steps (module doc), vertices where
    ``fixed`` is true (the feature tips) left as they are, radii kept >= 0, the rims faired by ``rim_fairness``
    (module doc). Returns the iterate with the smallest objective (mean |distance|, with the rims' term its mean
    square with theirs; the input itself if no step improved it) and stats: ``mean_distance`` per iterate, the
    kept ``iteration``, the vertices' ``median_move`` and ``max_move``, ``median_radius_change``, ``seconds``."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.linalg import lsqr

    from qmdf.geometry.envelope import EnvelopeUnion

    t0 = time.perf_counter()
    v0, r0 = np.asarray(vertices, np.float64), np.asarray(radii, np.float64)
    samples = np.asarray(samples, np.float64).reshape(-1, 3)
    n = len(v0)
    free = np.ones(n, bool) if fixed is None else ~np.asarray(fixed, bool)
    v, r = v0.copy(), r0.copy()
    history, best = [], (np.inf, 0, v, r)
    share = np.sqrt(len(samples) / max(int(free.sum()), 1))  # one vertex's share of the samples, as a weight
    lm_damping = damping * share
    fair = _RimCurvature(faces, free, rim_fairness * share) if rim_fairness > 0 else None
    for it in range(iterations + 1):
        union = EnvelopeUnion(v, r, edges, faces)
        d, prim = union.sdf(samples, return_argmin=True)
        history.append(float(np.abs(d).mean()))
        balls = np.c_[v, r]
        objective = history[-1] if fair is None else float(np.sqrt((d @ d + fair.energy(balls)) / len(d)))
        if objective < best[0]:
            best = (objective, it, v, r)
        if it == iterations:
            break
        _, foot, _ = union.eval_prims(samples, prim)
        ids = union.prims[prim]
        w = foot_weights(foot, v[ids], union.kind[prim])
        u = samples - foot
        u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        rows, cols, vals = [], [], []
        for k in range(3):
            i = np.flatnonzero((w[:, k] > 0) & free[ids[:, k]])
            for j in range(4):  # x, y, z of the centre, then the radius
                rows.append(i)
                cols.append(4 * ids[i, k] + j)
                vals.append(-w[i, k] * (u[i, j] if j < 3 else 1.0))
        residual = -d
        if fair is not None:
            rows, cols, vals, residual = fair.append(balls, len(samples), rows, cols, vals, residual)
        jac = csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(len(residual), 4 * n)
        )
        step = lsqr(jac, residual, damp=lm_damping, atol=1e-8, btol=1e-8, iter_lim=500)[0].reshape(n, 4)
        v = v + step[:, :3]
        r = np.maximum(r + step[:, 3], 0.0)
    _, kept, v, r = best
    move = np.linalg.norm(v - v0, axis=1)
    return (
        v,
        r,
        {
            "mean_distance": history,
            "iteration": kept,
            "median_move": float(np.median(move)),
            "max_move": float(move.max()),
            "median_radius_change": float(np.median(np.abs(r - r0))),
            "seconds": round(time.perf_counter() - t0, 2),
        },
    )
