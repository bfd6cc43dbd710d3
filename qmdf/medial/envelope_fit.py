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
        6,
        ge=1,
        doc="damped Gauss-Newton steps. Sharp sphere under +experiment=cad_features, 3,000 vertices: CD / HD "
        "1.14e-3 / 14.3e-3 (no fit) -> 0.51e-3 / 10.5e-3 (6, 3.8 s) -> 0.49e-3 / 9.8e-3 (12, 6.8 s); the bunny's "
        "0.54e-3 / 5.5e-3 (6) -> 0.51e-3 / 7.9e-3 (12)",
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


def fit_envelope_to_samples(
    vertices: np.ndarray,
    radii: np.ndarray,
    edges: np.ndarray,
    faces: np.ndarray,
    samples: np.ndarray,
    fixed: np.ndarray | None = None,
    iterations: int = _DEFAULT.iterations,
    damping: float = _DEFAULT.damping,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Move the medial mesh's centres and radii (``edges``: its lone edges; ``faces``) so that its envelope passes
    through the surface ``samples`` (N, 3): ``iterations`` damped Gauss-Newton steps (module doc), vertices where
    ``fixed`` is true (the feature tips) left as they are, radii kept >= 0. Returns the iterate with the smallest
    mean |distance| (the input itself if no step improved it) and stats: ``mean_distance`` per iterate, the kept
    ``iteration``, the vertices' ``median_move`` and ``max_move``, ``median_radius_change``, ``seconds``."""
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
    lm_damping = damping * np.sqrt(len(samples) / max(int(free.sum()), 1))
    for it in range(iterations + 1):
        union = EnvelopeUnion(v, r, edges, faces)
        d, prim = union.sdf(samples, return_argmin=True)
        history.append(float(np.abs(d).mean()))
        if history[-1] < best[0]:
            best = (history[-1], it, v, r)
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
        jac = csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(len(samples), 4 * n)
        )
        step = lsqr(jac, -d, damp=lm_damping, atol=1e-8, btol=1e-8, iter_lim=500)[0].reshape(n, 4)
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
