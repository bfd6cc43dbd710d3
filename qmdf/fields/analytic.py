"""Exact SDF and medial field of shapes with known medial axes, behind the ``Field`` interface, so the
extraction stages are proven on known answers independently of training.

Inside a solid, mf(x) is the radius of the medial ball at the point where the inward normal ray from x's
closest surface point meets the axis, and q = mf - |sdf| is the distance along that ray to the axis.
"""

from __future__ import annotations

import numpy as np

from qmdf.geometry import ellipsoid
from qmdf.geometry.normalize import Normalization
from qmdf.geometry.shapes import BOX_HALF, ELLIPSOID_AXES, TORUS_R, TORUS_r, box_sdf, torus_sdf


class AnalyticField:
    """Subclasses give sdf(p), mf(p) (inside), the distance to the medial axis and the true medial radius
    there, all in the shape's own coordinates; ``evaluate`` answers in the unit box of the sampled input,
    like a trained field, through ``normalization`` (shape -> unit box)."""

    def __init__(self, normalization: Normalization | None = None):
        self.normalization = normalization or Normalization.identity()

    @staticmethod
    def _q(p: np.ndarray, sdf: np.ndarray, mf: np.ndarray) -> np.ndarray:
        """mf - |sdf| inside; outside only the inner axis matters, so q grows with the distance instead."""
        return np.where(sdf < 0, mf - np.abs(sdf), sdf)

    def _unit(self, fn):
        """fn (shape units) as a function of unit-box points, in unit-box lengths."""
        n = self.normalization
        return lambda x: fn(n.to_input(x)) * n.scale

    def sdf(self, p: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def mf(self, p: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def axis_distance(self, p: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def axis_points(self, n: int, seed: int = 0) -> np.ndarray:  # pragma: no cover - abstract
        """n points spread over the true medial axis."""
        raise NotImplementedError

    def evaluate(self, points: np.ndarray, grad: bool = False, h: float = 1e-5) -> dict[str, np.ndarray]:
        p = np.asarray(points, np.float64)
        sdf_fn, mf_fn = self._unit(self.sdf), self._unit(self.mf)
        sdf, mf = sdf_fn(p), mf_fn(p)
        out = {"sdf": sdf, "mf": mf, "q": self._q(p, sdf, mf)}
        if grad:  # central differences: exact enough for fields that are smooth off the axis
            for name, fn in (("sdf_grad", sdf_fn), ("q_grad", lambda x: self._q(x, sdf_fn(x), mf_fn(x)))):
                g = np.empty_like(p)
                for k in range(3):
                    e = np.zeros(3)
                    e[k] = h
                    g[:, k] = (fn(p + e) - fn(p - e)) / (2 * h)
                out[name] = g
        return out


class TorusField(AnalyticField):
    """Ring torus: the medial axis is the core circle; inside, mf = r and q = distance to the circle."""

    R, r = TORUS_R, TORUS_r

    def sdf(self, p):
        return torus_sdf(p, self.R, self.r)

    def mf(self, p):
        return np.full(len(p), self.r)

    def axis_distance(self, p):
        return np.hypot(np.hypot(p[:, 0], p[:, 1]) - self.R, p[:, 2])

    def axis_radius(self, p):
        return np.full(len(p), self.r)

    def axis_points(self, n: int, seed: int = 0):
        t = np.random.default_rng(seed).uniform(0, 2 * np.pi, n)
        return np.c_[self.R * np.cos(t), self.R * np.sin(t), np.zeros(n)]


class BoxField(AnalyticField):
    """Box with half extents h: inside, with d_i = h_i - |x_i| and k the nearest face's axis, the inward ray
    reaches the axis after min(min_{j != k} d_j, h_k) - d_k, so mf = min(min_{j != k} d_j, h_k)."""

    half = BOX_HALF

    def sdf(self, p):
        return box_sdf(p, self.half)

    def mf(self, p):
        d = self.half - np.abs(p)
        k = np.argmin(d, axis=1)
        others = d.copy()
        others[np.arange(len(p)), k] = np.inf
        return np.minimum(others.min(1), self.half[k])

    def axis_distance(self, p):
        """Exact distance to the box's medial axis, a union of planar pieces (``box_medial_triangles``)."""
        import trimesh

        if not hasattr(self, "_triangles"):
            self._triangles = box_medial_triangles(self.half)
        p = np.asarray(p, np.float64)
        best = np.full(len(p), np.inf)
        for tri in self._triangles:
            foot = trimesh.triangles.closest_point(np.broadcast_to(tri, (len(p), 3, 3)), p)
            best = np.minimum(best, np.linalg.norm(p - foot, axis=1))
        return best

    def axis_radius(self, p):
        return np.abs(self.sdf(p))

    def axis_points(self, n: int, seed: int = 0):
        return box_medial_points(self.half, n, seed)


def box_medial_triangles(half: np.ndarray) -> np.ndarray:
    """The medial axis of a box with half extents a >= b >= c, as triangles: the central rectangle z = 0,
    |x| <= a - c, |y| <= b - c, and one bisector piece per edge, from the edge down to that rectangle: the
    points at equal depth t from the edge's two faces, t in [0, c] (trapezoids for the edges along x and y,
    triangles for the edges along z, which are only 2c long)."""
    a, b, c = (float(v) for v in half)
    if not (a >= b >= c):
        raise ValueError("box_medial_triangles expects half extents sorted a >= b >= c")
    quads, tris = [[(-a + c, -b + c, 0), (a - c, -b + c, 0), (a - c, b - c, 0), (-a + c, b - c, 0)]], []
    for sx in (-1, 1):
        for sz in (-1, 1):  # edges along y, between faces x = sx a and z = sz c
            quads.append(
                [(sx * a, -b, sz * c), (sx * a, b, sz * c), (sx * (a - c), b - c, 0), (sx * (a - c), -(b - c), 0)]
            )
    for sy in (-1, 1):
        for sz in (-1, 1):  # edges along x, between faces y = sy b and z = sz c
            quads.append(
                [(-a, sy * b, sz * c), (a, sy * b, sz * c), (a - c, sy * (b - c), 0), (-(a - c), sy * (b - c), 0)]
            )
    for sx in (-1, 1):
        for sy in (-1, 1):  # edges along z, between faces x = sx a and y = sy b
            tris.append([(sx * a, sy * b, -c), (sx * a, sy * b, c), (sx * (a - c), sy * (b - c), 0)])
    for q in quads:
        tris += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
    return np.array(tris, np.float64)


def box_medial_points(half: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Points on a box's medial axis: inside points whose two nearest faces are equally near, found by
    moving random points inward along their nearest face's normal until a second face is as near."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-half, half, size=(n, 3))
    d = half - np.abs(p)
    k = np.argmin(d, axis=1)
    others = d.copy()
    others[np.arange(n), k] = np.inf
    target = np.minimum(others.min(1), half[k])  # where the inward ray meets the axis
    q = p.copy()
    q[np.arange(n), k] = np.sign(p[np.arange(n), k]) * (half[k] - target)
    return q


class EllipsoidField(AnalyticField):
    """Ellipsoid with semi-axes a > b > c: the medial axis is the elliptic disc in the plane of c, with
    semi-axes (a^2 - c^2)/a, (b^2 - c^2)/b; mf is the distance from the closest surface point to where its
    normal line crosses that plane."""

    axes = ELLIPSOID_AXES

    def sdf(self, p):
        return ellipsoid.signed_distance(p, self.axes)

    def mf(self, p):
        x, _ = ellipsoid.closest_point(p, self.axes)
        return np.linalg.norm(x - ellipsoid.medial_point(p, self.axes), axis=1)

    def axis_distance(self, p):
        return np.linalg.norm(p - ellipsoid.closest_on_medial_disc(p, self.axes), axis=1)

    def axis_radius(self, p):
        return ellipsoid.medial_radius(ellipsoid.closest_on_medial_disc(p, self.axes), self.axes)

    def axis_points(self, n: int, seed: int = 0):
        """Area-uniform on the medial disc."""
        k, semi = ellipsoid.medial_disc(self.axes)
        rng = np.random.default_rng(seed)
        rho, t = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
        m = np.zeros((n, 3))
        others = [i for i in range(3) if i != k]
        m[:, others[0]], m[:, others[1]] = semi[0] * rho * np.cos(t), semi[1] * rho * np.sin(t)
        return m


ANALYTIC = {"torus": TorusField, "box": BoxField, "ellipsoid": EllipsoidField}
