"""Compiled dense sums of the point dipoles' winding number and its gradient (the operators of
``qmdf.geometry.winding_orientation``). Every pair closer than the width ``w`` is left out: the kernel's
singularity at a point's own neighbours is what makes the unsmoothed operators useless on a sampled surface.

Dense sums, O(queries x points): the orientation runs them on a subsample of a few thousand points, where a
treecode would save little and cost a tree per width.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_INV_4PI = 1.0 / (4.0 * math.pi)


@njit(parallel=True, cache=True, nogil=True, fastmath=True)
def winding_at(points, mu, queries, w):
    """A mu: the winding number at each query of dipoles ``mu`` (outward normal times area) at ``points``."""
    out = np.zeros(len(queries))
    w2 = w * w
    for i in prange(len(queries)):
        s = 0.0
        for j in range(len(points)):
            rx, ry, rz = points[j, 0] - queries[i, 0], points[j, 1] - queries[i, 1], points[j, 2] - queries[i, 2]
            d2 = rx * rx + ry * ry + rz * rz
            if d2 >= w2:
                s += (rx * mu[j, 0] + ry * mu[j, 1] + rz * mu[j, 2]) / (d2 * math.sqrt(d2))
        out[i] = s * _INV_4PI
    return out


@njit(parallel=True, cache=True, nogil=True, fastmath=True)
def winding_adjoint(points, values, w):
    """A^T s: the adjoint of ``winding_at`` with the points as queries, one vector per point."""
    n = len(points)
    out = np.zeros((n, 3))
    w2 = w * w
    for j in prange(n):
        ax = ay = az = 0.0
        for i in range(n):
            rx, ry, rz = points[j, 0] - points[i, 0], points[j, 1] - points[i, 1], points[j, 2] - points[i, 2]
            d2 = rx * rx + ry * ry + rz * rz
            if d2 >= w2:
                c = values[i] / (d2 * math.sqrt(d2))
                ax += rx * c
                ay += ry * c
                az += rz * c
        out[j, 0], out[j, 1], out[j, 2] = ax * _INV_4PI, ay * _INV_4PI, az * _INV_4PI
    return out


@njit(parallel=True, cache=True, nogil=True, fastmath=True)
def winding_descent(points, mu, queries, w):
    """Minus the gradient of the winding number at each query: it points from inside to outside."""
    out = np.zeros((len(queries), 3))
    w2 = w * w
    for i in prange(len(queries)):
        ax = ay = az = 0.0
        for j in range(len(points)):
            rx, ry, rz = points[j, 0] - queries[i, 0], points[j, 1] - queries[i, 1], points[j, 2] - queries[i, 2]
            d2 = rx * rx + ry * ry + rz * rz
            if d2 >= w2:
                d3 = d2 * math.sqrt(d2)
                rm = 3.0 * (rx * mu[j, 0] + ry * mu[j, 1] + rz * mu[j, 2]) / (d3 * d2)
                ax += mu[j, 0] / d3 - rx * rm
                ay += mu[j, 1] / d3 - ry * rm
                az += mu[j, 2] / d3 - rz * rm
        out[i, 0], out[i, 1], out[i, 2] = ax * _INV_4PI, ay * _INV_4PI, az * _INV_4PI
    return out
