"""Coverage refinement: MAT vertices added where the MAT's envelope falls short of the surface.

A MAT extracted from a covering samples the axis by the covering's own measure, not the surface's: where the
radius is large a small step along the axis sweeps the contact points a long way over the surface, and where
the learned q does not hold a branch or a rim (the bunny's ears, its rump) the sheet stops short. Both leave
the surface outside the envelope (on the bunny 90% of the surface, a median 2.9e-3 out). The data say where
the axis is there: the medial ball behind each surface sample (``shrinking_ball_radii``). Greedily, from the
sample farthest outside the envelope, such centres are inserted into the mesh, each splitting the face (or the
edge) nearest to it: one vertex in a face's interior, three edges, two faces more; on an edge, as many faces
more as the edge had; where that would bulge out of the shape (a branch the mesh lacks), a dangling edge from
the nearest vertex; each way V - E + F, and the homotopy type, stay. Rounds repeat until the envelope
reaches every sample within ``tolerance`` or the vertex budget is spent, as Coverage Axis chooses balls by the
surface they cover (Dou et al. 2022), here on top of the sheet's topology."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from qmdf.geometry.triangles import barycentric
from qmdf.schema import param

#: A surface sample farther than this outside the envelope is uncovered (unit box); ``sheet.tolerance``'s default.
TOLERANCE = 1e-3


@dataclass
class CoverageSettings:
    """The sheet's ``coverage`` step (``sheet.step.coverage``) and ``refine_coverage``'s defaults."""

    vertices: int = param(
        1000,
        ge=0,
        doc="up to this many vertices added where the envelope falls short of the surface by more than "
        "sheet.tolerance, each the data's medial ball behind the sample farthest out; a second simplification, "
        "those fixed, brings the sheet back to sheet.target_vertices (0: none)",
    )
    spacing: float = param(
        0.01, gt=0, doc="per round, no two added balls' samples closer than this (or half the ball's radius)"
    )
    overshoot: float = param(
        5e-3,
        gt=0,
        doc="refuse an added vertex whose new edges' balls reach out of the data by more than this (a spike to a "
        "branch the sheet lacks)",
    )
    rounds: int = param(10, ge=1, doc="rounds of insertion (the envelope is re-measured after each)")


_DEFAULT = CoverageSettings()


@dataclass
class SurfaceBalls:
    """The data's medial ball behind each surface sample, and the distance to the data they were measured with."""

    samples: np.ndarray  # (N, 3)
    centres: np.ndarray  # (N, 3)
    radii: np.ndarray  # (N,)
    distance: Callable  # distance(q) -> (d, closest point)


def surface_balls(
    points: np.ndarray,
    outward: np.ndarray | None,
    mesh: tuple[np.ndarray, np.ndarray] | None = None,
    is_inside=None,
    rays: dict | None = None,
) -> SurfaceBalls:
    """The medial ball behind each surface point, centred at ``points - r * n``. On a ``mesh``, n are the
    ``outward`` normals (PCA's when None) turned by the winding number and smoothed over the facets, and r is
    measured to the mesh (``mesh_ray_normals``: the supervision's rays); else n is ``outward`` (a cloud's caller
    passes the learned sdf's gradient) and r is measured to the points. Kept: balls wider than the test's
    tolerance whose centre lies inside: ``is_inside(q) -> bool``, on a mesh by default its winding number (a ray
    along a normal gone wrong at a crease or a rim leaves the shape: on the sharp sphere 94 of 20k balls were
    centred outside, some of radius 1, and one inserted ball stood 0.14 out of the shape). On a mesh, ``rays``
    (train's ``medial_rays`` artifact, measured the same way from the same ``points``) saves the measuring."""
    from qmdf.geometry.medial_radius import mesh_outward_normals, mesh_ray_normals, shrinking_ball_radii
    from qmdf.medial.radii import data_distance

    points = np.asarray(points, np.float64)
    distance, tol = data_distance(mesh, None if mesh is not None else points)
    reuse = mesh is not None and rays is not None and np.array_equal(rays["origins"], points)
    if reuse:
        outward, tol = rays["directions"], rays["tol"]
    elif mesh is not None:
        outward, _ = mesh_outward_normals(points, outward, *mesh)
        outward, tol = mesh_ray_normals(points, outward, *mesh)
    elif outward is None:
        raise ValueError("the balls behind a cloud's points need their outward normals")
    n = outward / np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-12)
    if reuse:
        r = np.asarray(rays["radii"], np.float64)
    else:
        r = shrinking_ball_radii(points, n, distance, r_max=1.0, tol=tol)  # bisection's radius, in fewer queries
    centres = points - r[:, None] * n
    if mesh is None:
        # the test passes up to tol short of the points (a sparse cloud's gaps: tol 0.013 on 2,000 bunny points,
        # and every insertion was refused as protruding): the radius is the centre's own distance to them. On a
        # mesh the ball keeps touching its sample: tol there absorbs the facets of a smooth surface
        r = np.minimum(r, distance(centres)[0])
    keep = r > tol
    if is_inside is None and mesh is not None:
        from qmdf.geometry.inside import mesh_inside_test

        is_inside = mesh_inside_test(*mesh)
    if is_inside is not None and keep.any():
        keep[keep] = np.asarray(is_inside(centres[keep]), bool)
    return SurfaceBalls(points[keep], centres[keep], r[keep], distance)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P, E) distances from points to segments."""
    ab = b - a
    t = np.einsum("pek,ek->pe", p[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-30)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(p[:, None] - (a[None] + t[..., None] * ab[None]), axis=2)


def _picks(samples: np.ndarray, shortfall: np.ndarray, radii: np.ndarray, tolerance: float, spacing: float, n: int):
    """Up to ``n`` samples outside the envelope by more than ``tolerance``, farthest first, none within
    max(spacing, r / 2) of one taken before (the ball it brings covers about that much of the surface)."""
    from scipy.spatial import cKDTree

    order = np.argsort(-shortfall, kind="stable")
    order = order[shortfall[order] > tolerance]
    if not len(order) or n <= 0:
        return np.zeros(0, np.int64)
    tree = cKDTree(samples)
    blocked = np.zeros(len(samples), bool)
    out = []
    for i in order:
        if blocked[i]:
            continue
        out.append(i)
        if len(out) >= n:
            break
        blocked[tree.query_ball_point(samples[i], max(spacing, 0.5 * radii[i]))] = True
    return np.array(out, np.int64)


def _insertion_plans(v, lone, faces, points) -> tuple[list, list]:
    """Per point, how ``_insert`` would put it in: ("edge", lone edge, None), ("faces", [faces], split face edge
    or None) or None (no face, no edge), and the vertices whose balls that touches (for the protrusion test)."""
    import igl

    near_face = np.full(len(points), -1)
    face_d = np.full(len(points), np.inf)
    foot = np.zeros((len(points), 3))
    if len(faces):
        sq, near_face, foot = igl.point_mesh_squared_distance(points, v, faces)
        face_d = np.sqrt(np.maximum(sq, 0.0))
    near_edge = np.full(len(points), -1)
    edge_d = np.full(len(points), np.inf)
    if len(lone):
        d = _segment_distance(points, v[lone[:, 0]], v[lone[:, 1]])
        near_edge = d.argmin(1)
        edge_d = d[np.arange(len(points)), near_edge]
    edge_faces: dict[tuple[int, int], list[int]] = {}
    for k, f in enumerate(faces):
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            edge_faces.setdefault((min(a, b), max(a, b)), []).append(k)
    bary = barycentric(foot, v[faces[np.maximum(near_face, 0)]]) if len(faces) else np.zeros((len(points), 3))
    # each point's plan: the lone edge it splits, or the faces it splits (with the split face edge, if any)
    plans, corners = [], []
    for k in range(len(points)):
        if edge_d[k] < face_d[k]:
            plans.append(("edge", int(near_edge[k]), None))
            corners.append(lone[near_edge[k]])
        elif near_face[k] >= 0:
            a, b, c = (int(w) for w in faces[near_face[k]])
            low = int(np.argmin(bary[k]))
            if bary[k, low] < 0.2:  # near the edge opposite corner ``low``: split that edge in all its faces
                p, q = (b, c) if low == 0 else (c, a) if low == 1 else (a, b)
                around = edge_faces[(min(p, q), max(p, q))]
                plans.append(("faces", around, (p, q)))
                corners.append(np.unique(faces[around]))
            else:
                plans.append(("faces", [int(near_face[k])], None))
                corners.append(faces[near_face[k]])
        else:
            plans.append(None)
            corners.append(np.zeros(0, np.int64))
    return plans, corners


def _insert(v, r, lone, faces, points, point_radii, protrudes):
    """Each point inserted by splitting its nearest face (in the interior; on the edge when it lands within a
    fifth of the way from one) or nearest lone edge, unless ``protrudes(points, radii, corners) -> bool mask``
    says so, and then as a dangling edge from the nearest vertex unless that protrudes too; one split per face
    and edge per call. Returns the new (v, r, lone, faces), how many were
    inserted, and a mask of the points deferred because their face or edge was split already."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    lone = np.asarray(lone, np.int64).reshape(-1, 2)
    plans, corners = _insertion_plans(v, lone, faces, points)
    refused = protrudes(points, point_radii, corners)
    # where the split would bulge out (a branch the mesh lacks: the teacup's handle, an ear's tip), a dangling
    # lone edge from the nearest vertex instead (V and E grow by one), if its cone stays inside
    from scipy.spatial import cKDTree

    nearest = cKDTree(v).query(points)[1]
    pendant_refused = protrudes(points, point_radii, [np.array([u]) for u in nearest])
    face_used = np.zeros(len(faces), bool)
    lone_used = np.zeros(len(lone), bool)
    new_v, new_r, new_faces, new_lone = [], [], [], []
    drop_faces, drop_lone = [], []
    deferred = np.zeros(len(points), bool)
    n = len(v)
    for k, plan in enumerate(plans):
        if plan is None or (refused[k] and pendant_refused[k]):
            continue
        idx = n + len(new_v)
        kind, target, split = plan if not refused[k] else ("pendant", int(nearest[k]), None)
        if kind == "pendant":
            new_lone.append([target, idx])
        elif kind == "edge":
            if lone_used[target]:
                deferred[k] = True
                continue
            lone_used[target] = True
            drop_lone.append(target)
            new_lone += [[lone[target, 0], idx], [idx, lone[target, 1]]]
        else:
            if face_used[target].any():
                deferred[k] = True
                continue
            face_used[target] = True
            drop_faces += target
            for g in target:
                x, y, z = (int(w) for w in faces[g])
                if split is None:
                    new_faces += [[x, y, idx], [y, z, idx], [z, x, idx]]
                    continue
                # the face with its split edge's ends in order, then the third corner
                for s_, t_, o in ((x, y, z), (y, z, x), (z, x, y)):
                    if {s_, t_} == set(split):
                        new_faces += [[s_, idx, o], [idx, t_, o]]
        new_v.append(points[k])
        new_r.append(point_radii[k])
    if not new_v:
        return v, r, lone, faces, 0, deferred
    keep_f = np.ones(len(faces), bool)
    keep_f[drop_faces] = False
    keep_e = np.ones(len(lone), bool)
    keep_e[drop_lone] = False
    faces = np.concatenate([faces[keep_f], np.array(new_faces, np.int64).reshape(-1, 3)])
    lone = np.concatenate([lone[keep_e], np.array(new_lone, np.int64).reshape(-1, 2)])
    return np.vstack([v, new_v]), np.concatenate([r, new_r]), lone, faces, len(new_v), deferred


def _protrusion_test(v: np.ndarray, r: np.ndarray, distance, overshoot: float):
    """protrudes(points, radii, corners) -> mask: whether a ball on an edge from a new vertex (point, radius) to
    one of its ``corners`` (at 1/4, 1/2, 3/4, radius interpolated) reaches out of the data by more than
    ``overshoot``; one distance query for all."""
    t = np.array([0.25, 0.5, 0.75])

    def protrudes(points, radii, corners):
        owner = np.repeat(np.arange(len(points)), [3 * len(c) for c in corners])
        if not len(owner):
            return np.zeros(len(points), bool)
        ends = np.concatenate([np.repeat(c, 3) for c in corners])
        tt = np.concatenate([np.tile(t, len(c)) for c in corners])
        p = (1 - tt)[:, None] * v[ends] + tt[:, None] * points[owner]
        rho = (1 - tt) * r[ends] + tt * radii[owner]
        excess = np.full(len(points), -np.inf)
        np.maximum.at(excess, owner, rho - distance(p)[0])
        return excess > overshoot

    return protrudes


def refine_coverage(
    vertices: np.ndarray,
    radii: np.ndarray,
    edges: np.ndarray,
    faces: np.ndarray,
    balls: SurfaceBalls,
    max_added: int,
    tolerance: float = TOLERANCE,
    spacing: float = _DEFAULT.spacing,
    overshoot: float = _DEFAULT.overshoot,
    max_rounds: int = _DEFAULT.rounds,
    below_tolerance: bool = True,
):
    """Up to ``max_added`` of the ``balls``' centres inserted into the medial mesh (``vertices``, ``radii``, lone
    ``edges``, ``faces``) where the envelope falls short of their samples by more than ``tolerance``, the worst
    first, then, while the budget lasts and ``below_tolerance`` allows, by less (the level halves when none is left
    above it, down to an eighth of ``tolerance``), none within max(``spacing``, r / 2) of another in a round (see
    the module doc). An insertion whose balls along a new edge (interpolated at 1/4, 1/2, 3/4) reach out of the
    data by more than ``overshoot`` is refused: a spike from a face to a centre far off it (a branch the sheet
    lacks) bulges out of the shape. Returns (vertices, radii, lone edges, faces, stats)."""
    from qmdf.geometry.envelope import EnvelopeUnion

    v, r = np.asarray(vertices, np.float64), np.asarray(radii, np.float64)
    e, f = np.asarray(edges, np.int64).reshape(-1, 2), np.asarray(faces, np.int64).reshape(-1, 3)

    samples = balls.samples

    def shortfall():
        return EnvelopeUnion(v, r, e, f).sdf(samples)

    def summary(d):
        out = np.maximum(d, 0.0)
        return {"mean": float(out.mean()), "p99": float(np.quantile(out, 0.99)), "max": float(out.max())}

    stats = {"samples": int(len(samples)), "added": 0, "rounds": 0}
    if not len(samples) or max_added <= 0 or not (len(f) or len(e)):
        return v, r, e, f, stats
    d = shortfall()
    stats["shortfall_before"] = summary(d)
    spent = np.zeros(len(samples), bool)
    # every gap above ``tolerance`` first (the worst first), then, while the budget lasts, the smaller ones: the
    # level halves whenever nothing is left above it, down to an eighth of ``tolerance``
    level = tolerance
    while stats["rounds"] < max_rounds and stats["added"] < max_added:
        picks = _picks(samples, np.where(spent, -np.inf, d), balls.radii, level, spacing, max_added - stats["added"])
        if not len(picks):
            if not below_tolerance or level < tolerance / 7.9:
                break
            level *= 0.5
            continue
        v, r, e, f, added, deferred = _insert(
            v, r, e, f, balls.centres[picks], balls.radii[picks], _protrusion_test(v, r, balls.distance, overshoot)
        )
        # a ball is offered once (where it did not cover its sample it would not again), unless its face was taken
        spent[picks[~deferred]] = True  # so this loop ends: each pass spends picks or halves the level
        if added:
            stats["added"] += added
            stats["rounds"] += 1
            d = shortfall()
    stats["shortfall_after"] = summary(d)
    return v, r, e, f, stats


def envelope_fit(v, r, e, f, balls: SurfaceBalls, rng: np.random.Generator, samples: int = 10000) -> dict:
    """CD / HD (``metrics.chamfer_hausdorff``) between the medial mesh's envelope and the data: the balls'
    surface samples to the envelope (its union SDF), and points sampled exactly on the envelope to the data
    (``balls.distance``). What coverage must not make worse."""
    from qmdf.geometry.envelope import EnvelopeUnion, reconstruct_mesh, sample_union_surface
    from qmdf.geometry.metrics import chamfer_hausdorff

    union = EnvelopeUnion(v, r, e, f)
    mesh = reconstruct_mesh(union, 64)  # only to place samples on the envelope
    if mesh is None:  # balls of no volume: their envelope fits nothing
        inf = float("inf")
        return chamfer_hausdorff(np.array([inf]), np.array([inf]))
    g = balls.samples if len(balls.samples) <= samples else balls.samples[rng.choice(len(balls.samples), samples)]
    on_envelope = sample_union_surface(union, samples, rng, mesh=mesh)
    return chamfer_hausdorff(balls.distance(on_envelope)[0], np.abs(union.sdf(g)))


def keeps(after: float, before: float, slack: float = 1.0) -> bool:
    """The one keep-if-better rule: a result whose envelope's CD to the data (``envelope_fit``) is at most
    ``slack`` times that of the one it would replace is kept (ties kept: a step that changes nothing measurable
    costs nothing)."""
    return bool(after <= slack * before)


def judged(candidate, incumbent, balls: SurfaceBalls, seed: int = 0, slack: float = 1.0) -> tuple[bool, float, float]:
    """``keeps`` on two ``MedialMesh``es' envelope fits (``envelope_fit``'s CD, each seeded alike): whether
    ``candidate`` is kept over ``incumbent``, and their two CDs."""
    after, before = (
        envelope_fit(m.vertices, m.radii, m.lone_edges(), m.faces, balls, np.random.default_rng(seed))["chamfer"]
        for m in (candidate, incumbent)
    )
    return keeps(after, before, slack), after, before


def cover_mat(mat, balls: SurfaceBalls, max_added: int, seed: int = 0, **settings):
    """``refine_coverage`` on a ``MedialMesh``, kept only where it improves the envelope's fit to the data
    (``judged``): (the ``MedialMesh`` kept, stats with ``kept``, ``chamfer_before`` and ``chamfer_after`` when
    balls were added). On the sharp sphere's membrane, insertions into the closed double layer took CD 0.90e-3 /
    HD 33e-3 to 4.2e-3 / 251e-3."""
    from qmdf.geometry.ma_format import MedialMesh

    v, r, e, f, stats = refine_coverage(
        mat.vertices, mat.radii, mat.lone_edges(), mat.faces, balls, max_added, **settings
    )
    if not stats["added"]:
        return mat, {**stats, "kept": False}
    covered = MedialMesh(v, r, e, f).with_face_edges()
    kept, after, before = judged(covered, mat, balls, seed)
    return (covered if kept else mat), {**stats, "kept": kept, "chamfer_before": before, "chamfer_after": after}
