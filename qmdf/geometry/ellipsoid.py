"""Exact distances for axis-aligned ellipsoids (any dimension): closest points, signed distance, medial axis.

The closest point x of y on the ellipsoid sum (x_i / a_i)^2 = 1 satisfies y_i = x_i (t + a_i^2) / a_i^2 for
the root t of F(t) = sum (a_i y_i / (t + a_i^2))^2 - 1 on t > -min a_i^2, where F decreases: bisection
finds it to machine precision (Eberly, "Distance from a point to an ellipse, an ellipsoid, or a
hyperellipsoid"). The normal line through x meets the plane of the smallest axis at t = -c^2, which is
where the medial axis lies: an elliptic disc with semi-axes (a_i^2 - c^2) / a_i.
"""

from __future__ import annotations

import numpy as np


def closest_point(y: np.ndarray, axes: np.ndarray, iterations: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """(closest points (N, d), root t (N,)) on the ellipsoid with semi-axes ``axes``."""
    y = np.asarray(y, np.float64)
    a = np.asarray(axes, np.float64)
    a2 = a * a
    sign = np.where(y < 0, -1.0, 1.0)
    y = np.abs(y)
    k = int(np.argmin(a))
    lo = np.full(len(y), -a2[k])
    hi = a.max() * np.linalg.norm(y, axis=1) - a2[k] + 1.0  # F(hi) < 0 there

    def F(t):
        return (((a * y) / (t[:, None] + a2)) ** 2).sum(1) - 1.0

    # Where F stays below 0 as t -> -c^2 the point lies on the medial disc (y_k = 0): t = -c^2 exactly.
    with np.errstate(divide="ignore", invalid="ignore"):
        on_disc = ~(F(lo + 1e-15 * a2[k]) > 0)
    with np.errstate(divide="ignore", invalid="ignore"):  # on-disc points converge onto the pole
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            up = F(mid) > 0
            lo = np.where(up, mid, lo)
            hi = np.where(up, hi, mid)
        t = np.where(on_disc, -a2[k], 0.5 * (lo + hi))
        x = a2 * y / (t[:, None] + a2)
    others = [i for i in range(len(a)) if i != k]
    rest = 1.0 - ((x[:, others] / a[others]) ** 2).sum(1)
    x[:, k] = np.where(on_disc, a[k] * np.sqrt(np.clip(rest, 0, None)), x[:, k])
    return x * sign, t


def signed_distance(p: np.ndarray, axes: np.ndarray) -> np.ndarray:
    p = np.asarray(p, np.float64)
    x, _ = closest_point(p, axes)
    inside = ((p / axes) ** 2).sum(1) < 1.0
    d = np.linalg.norm(p - x, axis=1)
    return np.where(inside, -d, d)


def medial_disc(axes: np.ndarray) -> tuple[int, np.ndarray]:
    """(index of the smallest axis, semi-axes of the medial disc in the other coordinates)."""
    a = np.asarray(axes, np.float64)
    k = int(np.argmin(a))
    others = [i for i in range(len(a)) if i != k]
    return k, (a[others] ** 2 - a[k] ** 2) / a[others]


def medial_point(p: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Where the inward normal ray from p's closest surface point meets the medial disc."""
    a = np.asarray(axes, np.float64)
    x, _ = closest_point(p, axes)
    k = int(np.argmin(a))
    return x * (a * a - a[k] ** 2) / (a * a)


def medial_radius(m: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Radius of the medial ball centred at disc point m: r^2 = c^2 (1 - sum m_i^2 / (a_i^2 - c^2))."""
    a = np.asarray(axes, np.float64)
    k = int(np.argmin(a))
    others = [i for i in range(len(a)) if i != k]
    s = (m[:, others] ** 2 / (a[others] ** 2 - a[k] ** 2)).sum(1)
    return a[k] * np.sqrt(np.clip(1.0 - s, 0, None))


def closest_on_medial_disc(p: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The closest point of the (filled) medial disc to p."""
    p = np.asarray(p, np.float64)
    k, semi = medial_disc(axes)
    others = [i for i in range(p.shape[1]) if i != k]
    planar = p[:, others]
    inside = ((planar / semi) ** 2).sum(1) <= 1.0
    rim, _ = closest_point(planar, semi)
    m = np.zeros_like(p)
    m[:, others] = np.where(inside[:, None], planar, rim)
    return m
