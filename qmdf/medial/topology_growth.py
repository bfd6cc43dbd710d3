"""A solid of grid nodes with a prescribed topology, grown inside the covering in q's order.

Where q's valley is a maze (the sharp sphere's: the covering has genus 31 at every level from eps down to
0.3 eps, against the ball's genus 0), no level of q gives the solid the shape's topology, and the collapse keeps
whatever topology it is given. This grows one instead: from the node of lowest q, the covering's nodes join in
increasing q, each only if it is a simple point (its joining changes no homotopy: the front never closes a
tunnel and never encloses a void), so the solid stays contractible; the nodes refused become the cuts where the
maze's spurious tunnels would have closed. For a shape of genus g, the g lowest-q closures are then allowed
(each joining a node whose neighbourhood meets the solid in two pieces adds one tunnel), so a true handle, whose
axis keeps q low all around its loop, closes before a bridge between neighbouring sheets.

The nodes span the cubical complex of ``thinning`` (a cell wherever all its corners are in): its inside is
6-connected and its outside 26-connected, so a node is simple when the solid's nodes among its 18 nearest
neighbours that are 6-connected to it form one 6-connected piece and its outside nodes among its 26 neighbours
one 26-connected piece (Bertrand and Malandain 1994).
"""

from __future__ import annotations

import heapq

import numpy as np
from numba import njit


@njit(cache=True)
def _local(mask, i, j, k):
    """The 3x3x3 neighbourhood of node (i, j, k) as a flat bool array (outside the grid: not in the solid)."""
    out = np.zeros(27, np.bool_)
    n0, n1, n2 = mask.shape
    for a in range(3):
        for b in range(3):
            for c in range(3):
                x, y, z = i + a - 1, j + b - 1, k + c - 1
                if 0 <= x < n0 and 0 <= y < n1 and 0 <= z < n2:
                    out[9 * a + 3 * b + c] = mask[x, y, z]
    return out


@njit(cache=True)
def _components(member, adjacent_6, seeds_only_face):
    """Pieces of the ``member`` cells of a 3x3x3 block (centre excluded), 6- or 26-connected; with
    ``seeds_only_face`` only the pieces holding one of the centre's 6 face neighbours count."""
    label = np.full(27, -1, np.int64)
    stack = np.empty(27, np.int64)
    count = 0
    for s in range(27):
        if s == 13 or not member[s] or label[s] >= 0:
            continue
        label[s] = count
        top = 1
        stack[0] = s
        while top:
            top -= 1
            u = stack[top]
            ua, ub, uc = u // 9, (u // 3) % 3, u % 3
            for v in range(27):
                if v == 13 or not member[v] or label[v] >= 0:
                    continue
                da, db, dc = abs(v // 9 - ua), abs((v // 3) % 3 - ub), abs(v % 3 - uc)
                if max(da, max(db, dc)) != 1:
                    continue
                if adjacent_6 and da + db + dc != 1:
                    continue
                label[v] = count
                stack[top] = v
                top += 1
        count += 1
    if not seeds_only_face:
        return count
    hit = np.zeros(count, np.bool_)
    for f in (4, 10, 12, 14, 16, 22):  # the 6 face neighbours of the centre (13)
        if label[f] >= 0:
            hit[label[f]] = True
    return int(hit.sum())


@njit(cache=True)
def _joining(mask, i, j, k):
    """(pieces of the solid the node would join, pieces of the outside around it, the Euler characteristic's
    change): the first two 1 and 1 for a simple point."""
    nb = _local(mask, i, j, k)
    fg = nb.copy()
    for s in range(27):  # the 8 corners are not among the 18 neighbours that 6-connectivity reads
        a, b, c = s // 9, (s // 3) % 3, s % 3
        if abs(a - 1) + abs(b - 1) + abs(c - 1) == 3:
            fg[s] = False
    t6 = _components(fg, True, True)
    bg = ~nb
    bg[13] = False
    t26 = _components(bg, False, False)
    # the cells the node brings: itself, its edges, squares and cubes to nodes already in
    change = 1
    for a in range(3):
        for b in range(3):
            for c in range(3):
                span = abs(a - 1) + abs(b - 1) + abs(c - 1)
                if span == 0:
                    continue
                # the cell between the centre and the neighbour (a, b, c): every corner in the box they span
                whole = True
                for x in range(min(a, 1), max(a, 1) + 1):
                    for y in range(min(b, 1), max(b, 1) + 1):
                        for z in range(min(c, 1), max(c, 1) + 1):
                            if not (x == 1 and y == 1 and z == 1) and not nb[9 * x + 3 * y + z]:
                                whole = False
                if whole:
                    change += -1 if span == 1 else (1 if span == 2 else -1)
    return t6, t26, change


@njit(cache=True)
def _grow(allowed, q, mask, heap_q, heap_i):
    """Simple points of ``allowed`` join ``mask`` in increasing q from the nodes on the heap, a refused node coming
    back whenever a neighbour joins."""
    n0, n1, n2 = mask.shape
    heap = [(heap_q[m], heap_i[m]) for m in range(len(heap_q))]
    heapq.heapify(heap)
    while heap:
        _, flat = heapq.heappop(heap)
        i, j, k = flat // (n1 * n2), (flat // n2) % n1, flat % n2
        if mask[i, j, k]:
            continue
        t6, t26, _ = _joining(mask, i, j, k)
        if t6 != 1 or t26 != 1:
            continue
        mask[i, j, k] = True
        for a in range(-1, 2):
            for b in range(-1, 2):
                for c in range(-1, 2):
                    x, y, z = i + a, j + b, k + c
                    if 0 <= x < n0 and 0 <= y < n1 and 0 <= z < n2 and allowed[x, y, z] and not mask[x, y, z]:
                        heapq.heappush(heap, (q[x, y, z], (x * n1 + y) * n2 + z))


@njit(cache=True)
def _closures(allowed, q, mask):
    """The nodes that would close a tunnel (next to the solid, joining two or more of its pieces around them,
    enclosing no void), with the Euler characteristic's change each brings."""
    n0, n1, n2 = mask.shape
    out_i = []
    out_d = []
    for i in range(n0):
        for j in range(n1):
            for k in range(n2):
                if not allowed[i, j, k] or mask[i, j, k]:
                    continue
                t6, t26, change = _joining(mask, i, j, k)
                if t6 >= 2 and t26 == 1:
                    out_i.append((i * n1 + j) * n2 + k)
                    out_d.append(change)
    return np.array(out_i, np.int64), np.array(out_d, np.int64)


def _neighbours(allowed: np.ndarray, mask: np.ndarray, flat: int) -> np.ndarray:
    """The allowed nodes not yet in ``mask`` among the 26 around node ``flat`` (flat indices)."""
    centre = np.array(np.unravel_index(flat, mask.shape))
    around = centre + np.array(list(np.ndindex(3, 3, 3))) - 1
    around = around[np.all((around >= 0) & (around < mask.shape), axis=1)]
    around = around[allowed[tuple(around.T)] & ~mask[tuple(around.T)]]
    return np.ravel_multi_index(tuple(around.T), mask.shape).astype(np.int64)


def grow_with_topology(allowed: np.ndarray, q: np.ndarray, target_chi: int = 1) -> tuple[np.ndarray, dict]:
    """The nodes of ``allowed`` grown from its lowest ``q`` as the module doc says, with ``1 - target_chi``
    tunnels closed (``target_chi`` <= 1: one piece, no void); returns (mask, stats). The mask's cubical Euler
    characteristic is ``target_chi`` unless fewer closures were found (stats' ``chi`` says)."""
    allowed = np.ascontiguousarray(allowed, bool)
    if not allowed.any():
        raise ValueError("no node is allowed")
    if target_chi > 1:
        raise ValueError(f"a grown solid is one piece without voids: chi at most 1, not {target_chi}")
    qv = np.ascontiguousarray(np.where(allowed, q, np.inf), np.float64)
    mask = np.zeros(allowed.shape, bool)
    seed = int(np.argmin(qv))
    mask.flat[seed] = True
    chi, closed = 1, []
    frontier = _neighbours(allowed, mask, seed)
    while True:
        _grow(allowed, qv, mask, qv.ravel()[frontier], frontier)
        if chi <= target_chi:
            break
        nodes, change = _closures(allowed, qv, mask)
        fits = np.flatnonzero(chi + change >= target_chi)
        if not len(fits):
            break
        best = fits[np.argmin(qv.ravel()[nodes[fits]])]
        mask.flat[nodes[best]] = True
        chi += int(change[best])
        closed.append(float(qv.flat[nodes[best]]))
        frontier = _neighbours(allowed, mask, int(nodes[best]))
    stats = {
        "allowed": int(allowed.sum()),
        "joined": int(mask.sum()),
        "refused": int(allowed.sum() - mask.sum()),
        "closures_q": closed,
        "chi": int(chi),
    }
    return mask, stats
