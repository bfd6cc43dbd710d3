"""A bounding-volume hierarchy over primitives that each lie in a ball (anchor, rho), for nearest queries in
compiled loops: the envelope union's primitives and a mesh's triangles.

Median splits of the anchors along the longest side; per node the anchors' box and the largest rho, so
``node_bound`` (the distance to the box minus that rho) bounds from below the distance of every primitive in
the node, and a query visits the nearer child first and skips every node that cannot beat its best so far."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def build_bvh(anchor, rho, leaf_size):
    """A bounding-volume hierarchy over primitives, each inside its ball (anchor, rho): median splits of the
    anchors along the longest side. Per node: the anchors' box, the largest rho, the children (-1 at a leaf)
    and the leaf's range in ``order``. A node's primitives are at least dist(p, box) - rho_max from p."""
    n = anchor.shape[0]
    order = np.arange(n)
    cap = 2 * (n // max(leaf_size, 1) + 1) * 2 + 1
    lo = np.empty((cap, 3))
    hi = np.empty((cap, 3))
    rho_max = np.empty(cap)
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    start = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    stack = np.empty(cap, np.int64)
    n_nodes, top = 1, 1
    stack[0] = 0
    start[0], count[0] = 0, n
    while top > 0:
        top -= 1
        node = stack[top]
        s, m = start[node], count[node]
        idx = order[s : s + m]
        for k in range(3):
            lo[node, k] = anchor[idx, k].min()
            hi[node, k] = anchor[idx, k].max()
        rho_max[node] = rho[idx].max()
        if m <= leaf_size:
            continue
        axis = np.argmax(hi[node] - lo[node])
        sorted_idx = idx[np.argsort(anchor[idx, axis])]
        order[s : s + m] = sorted_idx
        half = m // 2
        for child, cs, cm in ((n_nodes, s, half), (n_nodes + 1, s + half, m - half)):
            start[child], count[child] = cs, cm
            stack[top] = child
            top += 1
        left[node], right[node] = n_nodes, n_nodes + 1
        n_nodes += 2
    return (
        order,
        lo[:n_nodes],
        hi[:n_nodes],
        rho_max[:n_nodes],
        left[:n_nodes],
        right[:n_nodes],
        start[:n_nodes],
        count[:n_nodes],
    )


@njit(cache=True, nogil=True)
def node_bound(px, py, pz, lo, hi, rho_max, node):
    dx = max(lo[node, 0] - px, 0.0, px - hi[node, 0])
    dy = max(lo[node, 1] - py, 0.0, py - hi[node, 1])
    dz = max(lo[node, 2] - pz, 0.0, pz - hi[node, 2])
    return math.sqrt(dx * dx + dy * dy + dz * dz) - rho_max[node]
