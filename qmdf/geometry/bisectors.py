"""Medial samples along the bisectors of convex sharp edges, from the feature points alone.

Where two faces with unit normals n1, n2 meet in a convex edge at p, the inward bisector
x(t) = p - t m / |m|, m = (n1 + n2) / 2, is on the medial axis with radius r(t) = t |m| (its distance to
either face's plane) for as long as those two faces stay the nearest surface: the sheet that "points to the
convex feature" (paper Sec. 4.3). The data tell how long: each walk stops at the first x whose distance to the
data d is below ``slack`` * r (another part of the surface takes over), above r / ``slack`` + ``tol`` (the
faces are not planes there: beside a hole's concave wall the walk's r fell short of the true depth by up to
0.1 on the block) or that lies outside (a feature whose normals' mean points inward walks out of the shape:
on the block 853 such samples asked sdf = -r in its central void, and the retrained field put a surface there).
"""

from __future__ import annotations

import numpy as np


def bisector_samples(
    features: np.ndarray,
    mean_normals: np.ndarray,
    points: np.ndarray,
    length: float,
    spacing: float,
    slack: float = 0.98,
    min_cos: float = 0.1,
    max_cos: float = float(np.cos(np.deg2rad(15.0))),
    distance=None,
    tol: float | None = None,
    is_inside=None,
) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) medial points and their (M,) radii, every ``spacing`` along each bisector up to ``length``.

    |m| is the cosine of half the angle between the two normals. Below ``min_cos`` the faces nearly fold onto
    each other and the bisector is unreliable; above ``max_cos`` (normals within 30 degrees) the point is no
    sharp feature (a detected one on a smooth patch), its inward normal is no medial sheet: both skipped.

    ``distance(q) -> d`` is the unsigned distance to the data (default: to the nearest of ``points``) and ``tol``
    its slack above r (default: no upper test, the distance to points only bounds the true one from above);
    ``is_inside(q) -> bool`` the inside test (default: none)."""
    from scipy.spatial import cKDTree

    m = np.asarray(mean_normals, np.float64)
    c = np.linalg.norm(m, axis=1)
    keep = (c > min_cos) & (c < max_cos)
    p, m, c = np.asarray(features, np.float64)[keep], m[keep], c[keep]
    steps = int(np.floor(length / spacing))
    if len(p) == 0 or steps == 0:
        return np.zeros((0, 3)), np.zeros(0)
    t = spacing * np.arange(1, steps + 1)
    x = p[:, None, :] - t[None, :, None] * (m / c[:, None])[:, None, :]
    r = t[None, :] * c[:, None]
    flat = x.reshape(-1, 3)
    d = (cKDTree(points).query(flat)[0] if distance is None else np.asarray(distance(flat))).reshape(r.shape)
    ok = d >= slack * r
    if tol is not None:
        ok &= d <= r / slack + tol
    if is_inside is not None:
        ok &= np.asarray(is_inside(flat), bool).reshape(r.shape)
    medial = np.cumprod(ok, axis=1).astype(bool)  # up to the first sample past the sheet's end
    return x[medial], r[medial]
