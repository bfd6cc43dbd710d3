"""Carry a medial mesh's free rims and curve ends out to where the medial axis ends.

The covering {q < eps} stops short of the axis's boundary: near the rim the two contact points of a medial ball
draw together, q rises above eps, and the sheet ends early (the exact ellipsoid's disc at 95% of its elliptic
radius, the box's sheets short of its edges). The surface beyond is then covered by no ball: the envelope falls
short there by up to 1e-3 on the ellipsoid, the largest error of an otherwise exact MAT.

Each rim vertex walks outward in its sheet's tangent plane, away from its faces, along the spoke to its closest
data point projected onto the plane (a curve's end: along its edge), with the ball of its distance to the data.
What a ball at step s adds beyond the vertex's own ball is p(s) = d(s) + s - d(0), never decreasing (d is
1-Lipschitz). On the axis p grows (slope 1 - cos(theta), theta the spokes' angle to the plane); where the axis
ends the spokes meet in the plane, d' -> -1, and p stops growing. The walk stops at the first step whose gain
falls below ``flat``, whose ball is no medial ball (it could grow away from its closest point: off the axis),
or that leaves the shape; and it steps back and on in finer steps, so a step across the axis's end is not kept.
Each ball lies in the shape (its radius is its distance to the data); guards against a face turned over, a slab
out of the shape or a fit made worse keep the rest (``extend_rims``). Exact fields, 2,000 vertices: the
ellipsoid's rim from 95% of the disc's elliptic radius to 100.0%, its envelope's CD 1.38e-4 -> 0.75e-4.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.geometry.metrics import rim_sides
from qmdf.schema import param


@dataclass
class RimSettings:
    """How far and how finely the rims walk (``extend_rims``): the sheet's ``rims`` step (``sheet.step.rims``)."""

    reach: float = param(
        4.0,
        gt=0,
        doc="the walk goes at most this many times the vertex's distance to the data (a sheet ending in an edge of "
        "dihedral angle a meets it after r / sin(a/2): 4 r reaches edges down to 29 degrees)",
    )
    steps: int = param(32, ge=1, doc="steps of reach * r / steps, then finer ones")
    levels: int = param(4, ge=1, doc="levels - 1 times one step back and on in steps four times finer")
    flat: float = param(
        1e-3,
        gt=0,
        doc="the least gain per step length, 1 - cos(theta) (1e-3: on until the spokes are within 2.6 degrees of "
        "the tangent plane)",
    )
    max_tilt_deg: float = param(
        75.0,
        gt=0,
        le=90,
        doc="the walk needs a spoke within this of the plane (a sheet ending in an edge of 30 degrees has its "
        "spokes 75 degrees off)",
    )
    tol: float = param(
        1e-4, gt=0, doc="how much farther a moved slab may stand out of the shape, or the samples lie from the envelope"
    )


def rim_directions(
    vertices: np.ndarray, edges: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices, outward directions, tangent-plane normals), all unit. Every vertex on a free rim (an edge of
    one face): outward the sum over its rim edges of each edge's in-plane normal away from its face (weighted by
    the edge's length), its plane the one closest to the planes of the faces within two rings of it, by area
    (sign-free: a single sheet need not be oriented). Every end of a curve (a vertex of one lone edge and no
    face): outward along its edge, normal zero. Vertices whose directions cancel are left out."""
    x = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    direction = np.zeros_like(x)
    planes = None
    if len(faces):
        sides, owner = rim_sides(faces)
        a, b = sides[:, 0], sides[:, 1]
        c = faces[owner].sum(1) - a - b  # the owner's third corner
        along = x[b] - x[a]
        normal = np.cross(along, x[c] - x[a])
        out = np.cross(along, normal)  # in the face's plane, perpendicular to the edge
        out *= np.sign(np.einsum("ij,ij->i", out, x[a] - x[c]))[:, None]
        size, area2 = np.linalg.norm(out, axis=1), np.linalg.norm(normal, axis=1)
        good = (size > 0) & (area2 > 0)
        w = out[good] / size[good, None] * np.linalg.norm(along[good], axis=1)[:, None]
        for end in (a[good], b[good]):
            np.add.at(direction, end, w)
        planes = _plane_moments(x, faces)
    on_rim = np.any(direction != 0, axis=1)
    normals = np.zeros_like(x)
    if on_rim.any():
        normals[on_rim] = np.linalg.eigh(planes(np.flatnonzero(on_rim)))[1][:, :, 2]
        dn = np.einsum("ij,ij->i", direction[on_rim], normals[on_rim])
        direction[on_rim] -= dn[:, None] * normals[on_rim]
    if len(edges):
        in_face = np.zeros(len(x), bool)
        in_face[faces.ravel()] = True
        degree = np.bincount(edges.ravel(), minlength=len(x))
        for end, other in ((edges[:, 0], edges[:, 1]), (edges[:, 1], edges[:, 0])):
            tip = (degree[end] == 1) & ~in_face[end]
            direction[end[tip]] += x[end[tip]] - x[other[tip]]
    size = np.linalg.norm(direction, axis=1)
    scale = float(np.abs(x).max()) if len(x) else 1.0
    index = np.flatnonzero(size > 1e-12 * max(scale, 1e-12))
    return index, direction[index] / size[index, None], normals[index]


def _plane_moments(x: np.ndarray, faces: np.ndarray):
    """``moments(vertices) -> (K, 3, 3)``: the sum of n n^T / |n| (n: a face's normal, twice its area long) over
    the faces within two rings of each vertex. Two rings: a rim vertex can have one thin face whose normal is off
    by degrees (the exact ellipsoid's: 13 degrees, its corners 1e-4 out of the plane, 2e-3 apart)."""
    from scipy import sparse

    n = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    nn = (n[:, :, None] * n[:, None, :] / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None, None]).reshape(-1, 9)
    rows = np.repeat(np.arange(len(faces)), 3)
    incidence = sparse.csr_matrix((np.ones(rows.size), (faces.ravel(), rows)), shape=(len(x), len(faces)))

    def moments(vertices):
        ring = incidence[vertices] @ incidence.T  # the vertices sharing a face with each
        ring = (ring @ incidence).sign()  # the faces of those
        return np.asarray(ring @ nn).reshape(-1, 3, 3)

    return moments


def _walk(x0, d0, foot0, along, normal, s_max, distance, is_inside, settings: RimSettings):
    """Walk every point from ``x0`` (as the module doc says) in steps of ``s_max`` / ``settings.steps``, up to
    ``steps`` of them; then ``levels`` - 1 times back one step (the last one may straddle the axis's end, its gain
    an average) and on in steps a quarter as long (8 at most). The direction each time: the spoke to the closest
    data point projected onto the sheet's tangent plane (``normal``, the plane's normal), or a curve's ``along``
    (``normal`` zero), never back against ``along``, and only while the spoke is within ``max_tilt_deg`` of the
    plane: a spoke across the sheet (its middle, a seam's side) gives no direction. Returns (points, distances,
    walked length, whether the length ``s_max`` stopped it). ``d0``, ``foot0``: the start's distance and closest
    point."""
    steps, levels, flat = settings.steps, settings.levels, settings.flat
    min_cos = np.cos(np.radians(settings.max_tilt_deg))
    x, d, foot = x0.copy(), d0.copy(), foot0.copy()
    s = np.zeros(len(x))
    capped = np.zeros(len(x), bool)
    line = ~np.any(normal != 0, axis=1)
    h = np.array(s_max / steps, np.float64)
    for level in range(levels):
        active = np.flatnonzero(h > 0)
        last = (x.copy(), d.copy(), foot.copy(), s.copy())  # each point's state before its last step
        for _ in range(steps if level == 0 else 8):
            if not len(active):
                break
            spoke = foot[active] - x[active]
            n = normal[active]
            t = spoke - np.einsum("ij,ij->i", spoke, n)[:, None] * n
            on_line = line[active]
            t[on_line] = along[active[on_line]] * d[active[on_line], None]  # a curve: straight on
            size = np.linalg.norm(t, axis=1)
            hk = h[active]
            over = s[active] + hk > s_max[active]
            capped[active[over]] = True
            ok = (np.einsum("ij,ij->i", t, along[active]) > 0) & (size > min_cos * d[active]) & ~over
            trial = x[active] + hk[:, None] * t / np.where(size > 0, size, 1.0)[:, None]
            d_trial, foot_trial = distance(trial)
            ok &= d_trial + hk - d[active] > flat * hk  # the ball there still adds to the envelope
            # and it is a medial ball: it cannot grow by h away from its closest point (off the axis it can, by h
            # exactly; on it, two spokes 2 theta apart block it by h (1 - cos 2 theta), about 4x the gain)
            u = (foot_trial - trial) / np.maximum(d_trial, 1e-300)[:, None]
            d_probe = distance(trial - hk[:, None] * u)[0]
            ok &= d_trial + hk - d_probe > 4 * flat * hk
            # a step leaves the shape only through the surface, so only where d < h at its end (d is 1-Lipschitz);
            # the mesh's winding number costs 80 ms a call whatever the count
            near = np.flatnonzero(ok & (d_trial < hk))
            if len(near):
                ok[near] = np.asarray(is_inside(trial[near]), bool)
            go = active[ok]
            for keep, now in zip(last, (x, d, foot, s)):
                keep[go] = now[go]
            x[go], d[go], foot[go], s[go] = trial[ok], d_trial[ok], foot_trial[ok], s[go] + hk[ok]
            active = go
        if level < levels - 1:
            x, d, foot, s = last
        h = h / 4
    return x, d, s, capped


def extend_rims(
    vertices: np.ndarray,
    radii: np.ndarray,
    edges: np.ndarray,
    faces: np.ndarray,
    distance,
    is_inside,
    settings: RimSettings = RimSettings(),
    fixed: np.ndarray | None = None,
    samples: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Each rim vertex and curve end (``rim_directions``) moved outward as the module doc says, walked as
    ``RimSettings`` says. ``distance(points) -> (d, closest)`` to the data; ``is_inside(points) -> bool``;
    ``fixed``: vertices that stay (feature tips).

    A move that would turn one of the vertex's faces over, or make its slab stand out of the shape by more than
    ``tol`` beyond what it did (``_protrusion``), is halved until none does (at most five times, else the vertex
    stays). With ``samples`` (points on the data's surface), a moved vertex goes back where the samples within
    its old ball's reach (its radius plus its step) lie farther from the envelope than before on balance, or the
    farthest of them farther than the farthest was, by more than ``tol`` (``keep_local_gains``, three rounds): the old
    ball may have covered what the new one does not (the exact box's corners, 0.7e-3 worse without it).
    Returns (vertices, radii, stats)."""
    v = np.array(vertices, np.float64)
    r = np.array(radii, np.float64)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    index, along, normal = rim_directions(v, edges, faces)
    if fixed is not None and len(index):
        keep = ~np.asarray(fixed, bool)[index]
        index, along, normal = index[keep], along[keep], normal[keep]
    stats = {"rim_vertices": int(len(index)), "moved": 0}
    if not len(index):
        return v, r, stats
    d0, foot0 = distance(v[index])
    end, d_end, walked, capped = _walk(
        v[index], d0, foot0, along, normal, settings.reach * d0, distance, is_inside, settings
    )
    scale, trial, trial_r = _shape_keeping_moves(v, r, faces, index, end, d_end, walked > 0, distance, settings.tol)
    moved = scale > 0
    v0, r0 = v.copy(), r.copy()
    v[index[moved]], r[index[moved]] = trial[index[moved]], trial_r[index[moved]]
    reverted = 0
    if samples is not None and moved.any():
        samples = np.asarray(samples, np.float64)
        reverted = keep_local_gains(v0, r0, v, r, edges, faces, index, moved, samples, settings.tol)
    length = walked * scale
    stats.update(
        moved=int(moved.sum()),
        halved=int((moved & (scale < 1)).sum()),
        refused=int((~moved & (walked > 0)).sum()),
        reverted=int(reverted),
        median_step=float(np.median(length[moved])) if moved.any() else 0.0,
        max_step=float(length[moved].max()) if moved.any() else 0.0,
        at_reach=int(capped.sum()),
    )
    return v, r, stats


def _shape_keeping_moves(v, r, faces, index, end, d_end, walks, distance, tol):
    """How much of each walk (to ``end``, distance ``d_end``) vertex ``index`` may take: halved while it would
    turn one of its faces over or make its slab stand out of the shape by more than ``tol`` beyond what it did
    (a seam's side taken for a rim walks onto the next sheet: its faces then cut across the inside, their
    interpolated balls out of it), at most five times, else none. Returns the scales and the moved vertices and
    radii (all vertices; only ``index`` changed)."""
    move = end - v[index]
    touched = np.flatnonzero(np.isin(faces, index[walks]).any(1))
    before = _protrusion(v, r, faces[touched], distance)
    scale = walks.astype(np.float64)
    hit = np.zeros(len(index), bool)
    for _ in range(6):
        trial, trial_r = v.copy(), r.copy()
        trial[index] = v[index] + scale[:, None] * move
        trial_r[index] = np.where(scale == 1, d_end, r[index])
        part = (scale > 0) & (scale < 1)
        if part.any():
            trial_r[index[part]] = distance(trial[index[part]])[0]
        bad = turned_over(v[faces[touched]], trial[faces[touched]])
        bad |= _protrusion(trial, trial_r, faces[touched], distance) > np.maximum(before, 0.0) + tol
        hit = np.isin(index, faces[touched[bad]].ravel()) & (scale > 0)
        if not hit.any():
            break
        scale[hit] *= 0.5
    scale[hit] = 0.0
    return scale, trial, trial_r


def keep_local_gains(v0, r0, v, r, edges, faces, index, moved, samples, tol) -> int:
    """``extend_rims``' guard (see there), on ``v`` and ``r`` in place; the number of vertices sent back."""
    from scipy.spatial import cKDTree

    from qmdf.geometry.envelope import EnvelopeUnion

    # only the samples that a moved vertex may touch
    who = index[moved]
    reach = r0[who] + np.linalg.norm(v[who] - v0[who], axis=1) + tol
    hits = cKDTree(samples).query_ball_point(v0[who], reach)
    samples = samples[np.unique(np.concatenate([np.asarray(k, np.int64) for k in hits]))]
    if not len(samples):
        return 0
    before = np.abs(EnvelopeUnion(v0, r0, edges, faces).sdf(samples))
    tree = cKDTree(samples)
    back = 0
    for _ in range(3):
        after = np.abs(EnvelopeUnion(v, r, edges, faces).sdf(samples))
        change = after - before
        who = index[moved]
        if not len(who) or change.max() <= tol:
            break
        reach = r0[who] + np.linalg.norm(v[who] - v0[who], axis=1) + tol
        near = tree.query_ball_point(v0[who], reach)
        # blamed where the samples it may touch lost more than they gained, or the farthest of them now lies
        # farther out than the farthest did (a local Hausdorff distance)
        blamed = np.array(
            [
                len(k) > 0 and change[k].max() > tol and (change[k].sum() > 0 or after[k].max() > before[k].max() + tol)
                for k in near
            ]
        )
        if not blamed.any():
            break
        v[who[blamed]], r[who[blamed]] = v0[who[blamed]], r0[who[blamed]]
        moved[np.flatnonzero(moved)[blamed]] = False
        back += int(blamed.sum())
    return back


def turned_over(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Mask of the triangles (K, 3, 3) whose normal turns by more than 90 degrees (or that collapse)."""

    def normals(t):
        return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])

    return np.einsum("ij,ij->i", normals(before), normals(after)) <= 0


def _protrusion(x: np.ndarray, r: np.ndarray, faces: np.ndarray, distance) -> np.ndarray:
    """Per face, how far its slab's interpolated balls stand out of the shape: the most, over its centroid and
    its sides' midpoints, of the interpolated radius less the distance to the data there."""
    if not len(faces):
        return np.zeros(0)
    w = np.array([[1, 1, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1]], np.float64)
    w /= w.sum(1, keepdims=True)
    points = np.einsum("sk,fkd->fsd", w, x[faces]).reshape(-1, 3)
    radius = (r[faces] @ w.T).reshape(-1)
    return (radius - distance(points)[0]).reshape(len(faces), len(w)).max(1)
