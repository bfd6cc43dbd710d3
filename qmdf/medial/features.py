"""Points on a shape's sharp features (paper Sec. 4.3): sharp edges of a mesh sampled along their length,
and, from a learned field, start points marched onto the edges and refined by the quadric error of the input
points' tangent planes. The ``feature_detect`` stage's doc says when each is used."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qmdf.geometry.sharp_points import two_cluster_means
from qmdf.schema import param


@dataclass
class FeatureSettings:
    """How sharp features are found (``sharp_mesh_segments`` on a mesh, ``field_feature_points`` on a cloud): the
    ``feature_detect`` stage's config, one source for both."""

    dihedral_deg: float = param(
        30.0, gt=0, lt=180, doc="mesh: an edge is sharp when its faces' normals turn by more than this"
    )
    convex_only: bool = param(
        True, doc="mesh: keep convex sharp edges only (the medial axis never reaches a concave one)"
    )
    spacing: float = param(0.005, gt=0, doc="distance between feature samples along an edge (unit box)")
    boundary_fold_deg: float = param(
        150.0, gt=90, lt=180, doc="field: a membrane edge is on its boundary when its faces fold back by more than this"
    )
    max_radius: float = param(
        0.03, gt=0, doc="field: boundary edges where the medial radius and MF are both below this"
    )
    offset: float = param(0.004, gt=0, doc="field: distance of the six axis-offset SDF-gradient samples")
    march_steps: int = param(60, ge=1)
    march_tol: float = param(5e-4, gt=0, doc="field: marching stops once |sdf| is below this")
    qem_k: int = param(16, ge=3, doc="field: input points in each point's quadric")
    qem_regularization: float = param(
        1e-3, ge=0, doc="field: pull toward the marched point, so a flat neighbourhood stays put"
    )
    field_seeds: str = param(
        "both",
        choices=("membrane", "points", "both"),
        doc="field: the paper's route from the first MAT's boundary, the input points' two-plane fits, or both",
    )
    plane_min_points: int = param(4, ge=3, doc="field: neighbours each of the two planes must hold")
    plane_tolerance: float = param(
        0.05,
        gt=0,
        doc="field: a neighbour farther than this fraction of the neighbourhood's "
        "radius from both planes is no part of them (a corner's third face, noise)",
    )
    plane_normal_deg: float = param(
        45.0, gt=0, lt=90, doc="field: nor is one whose SDF gradient turns by more than this from the plane's normal"
    )
    arc_ratio: float = param(
        0.5,
        ge=0,
        doc="field: the two planes must fit the neighbours better than one circular "
        "arc across the edge by this factor (RMS), or it is a curved patch; 0: no such test",
    )
    face_normals: bool = param(
        True,
        doc="field: feature points carry their two planes' mean normal (feature_retrain's "
        "bisector samples); false: the paper's feature points alone",
    )


def sample_segments(a: np.ndarray, b: np.ndarray, spacing: float, return_index: bool = False):
    """Points every ``spacing`` along each segment a_i -> b_i (at least its midpoint); with ``return_index``
    also the segment each point lies on."""
    a, b = np.asarray(a, np.float64).reshape(-1, 3), np.asarray(b, np.float64).reshape(-1, 3)
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / spacing)).astype(np.int64)
    seg = np.repeat(np.arange(len(a)), n)
    t = (np.arange(len(seg)) - np.repeat(np.cumsum(n) - n, n) + 0.5) / n[seg]
    points = a[seg] + t[:, None] * (b - a)[seg]
    return (points, seg) if return_index else points


def sharp_mesh_segments(
    vertices: np.ndarray, faces: np.ndarray, dihedral_deg: float, convex_only: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """End points (a, b) of the edges whose two faces' normals differ by more than dihedral_deg, and the mean
    of those two normals, on the mesh with coincident vertices merged (OBJ/STL files repeat them per face,
    which hides every adjacency). ``convex_only``: the medial axis reaches convex edges only; at a concave
    one the radius does not vanish."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    keep = mesh.face_adjacency_angles > np.deg2rad(dihedral_deg)
    if convex_only:
        keep &= mesh.face_adjacency_convex
    e = mesh.face_adjacency_edges[keep]
    pair = mesh.face_adjacency[keep]
    mean_normal = 0.5 * (mesh.face_normals[pair[:, 0]] + mesh.face_normals[pair[:, 1]])
    return mesh.vertices[e[:, 0]], mesh.vertices[e[:, 1]], mean_normal


def offset_gradients(field, p: np.ndarray, offset: float) -> np.ndarray:
    """(N, 6, 3) unit SDF gradients at the six axis-offset samples around each point."""
    offsets = np.vstack([np.eye(3), -np.eye(3)]) * offset
    g = field.evaluate((p[:, None, :] + offsets[None]).reshape(-1, 3), grad=True)["sdf_grad"].astype(np.float64)
    g = g.reshape(-1, 6, 3)
    return g / np.maximum(np.linalg.norm(g, axis=2, keepdims=True), 1e-12)


def march_to_features(
    field, start: np.ndarray, steps: int = 60, tol: float = 5e-4, offset: float = 0.004
) -> np.ndarray:
    """Each start point marched along g1 + g2 (the means of the two clusters of SDF gradients at six
    ``offset`` samples around it) by |sdf| per step, until |sdf| < ``tol`` (paper Sec. 4.3)."""
    p = np.asarray(start, np.float64).copy()
    for _ in range(steps):
        sdf = field.evaluate(p)["sdf"].astype(np.float64)
        active = np.abs(sdf) > tol
        if not active.any():
            break
        c1, c2 = two_cluster_means(offset_gradients(field, p[active], offset))
        d = c1 + c2
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        p[active] -= sdf[active, None] * d  # toward the surface by |sdf|: g1 + g2 points outward
    return p


def qem_refine(field, p: np.ndarray, points: np.ndarray, k: int, reg: float) -> np.ndarray:
    """argmin_x sum_j (n_j . (x - p_j))^2 + reg |x - p|^2 over the k nearest input points p_j, n_j = grad sdf."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(points).query(p, k=min(k, len(points)))
    nb = points[idx]  # (N, k, 3)
    n = field.evaluate(nb.reshape(-1, 3), grad=True)["sdf_grad"].astype(np.float64).reshape(nb.shape)
    n /= np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-12)
    A = np.einsum("nki,nkj->nij", n, n) + reg * np.eye(3)
    b = np.einsum("nki,nkj,nkj->ni", n, n, nb) + reg * p
    return np.linalg.solve(A, b[..., None])[..., 0]


def field_feature_points(
    field,
    points: np.ndarray,
    mat=None,
    settings: FeatureSettings = FeatureSettings(),
    stats: dict | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Feature points of a point cloud from its learned ``field`` (the ``feature_detect`` stage's doc has the
    routes): ``settings.field_seeds`` "membrane" marches from the fold edges of the first MAT ``mat`` (vertices,
    faces, radii) onto the edges, "points" fits two planes around every input point, "both" does both. Returns
    the points, thinned to ``settings.spacing``, and with ``settings.face_normals`` the mean of their two planes'
    normals (else None); ``stats`` receives the counts."""
    from qmdf.geometry.metrics import fold_edges
    from qmdf.geometry.sharp_points import fit_edges, thin

    c = settings
    seeds, spacing, face_normals, qem_k = c.field_seeds, c.spacing, c.face_normals, c.qem_k
    planes = (qem_k, c.plane_tolerance, c.plane_normal_deg)
    sharp_rule = (c.dihedral_deg, c.plane_min_points, c.arc_ratio)
    stats = {} if stats is None else stats
    need_grads = seeds != "membrane" or face_normals
    grads = field.evaluate(points, grad=True)["sdf_grad"] if need_grads else None
    found, normals = [np.zeros((0, 3))], [np.zeros((0, 3))]
    if seeds != "points":
        folds = fold_edges(mat.vertices, mat.faces, c.boundary_fold_deg)
        mid = mat.vertices[folds].mean(1)
        low = (mat.radii[folds].max(1) < c.max_radius) & (field.evaluate(mid)["mf"] < c.max_radius)
        folds = folds[low]
        start = sample_segments(mat.vertices[folds[:, 0]], mat.vertices[folds[:, 1]], spacing)
        stats["boundary_edges"], stats["membrane_points"] = int(len(folds)), int(len(start))
        if len(start):
            marched = march_to_features(field, start, c.march_steps, c.march_tol, c.offset)
            refined = qem_refine(field, marched, points, qem_k, c.qem_regularization)
            found.append(refined)
            if face_normals:
                # the two planes' mean normal where a fit finds a convex sharp edge here; elsewhere (a point off
                # any edge) a unit normal, which feature_retrain's bisector walk skips as "no feature"
                fit = fit_edges(refined, points, grads, *planes)
                sharp = fit.sharp(*sharp_rule)
                normals.append(np.where(sharp[:, None], fit.mean_normal, fit.n1))
    if seeds != "membrane":
        fit = fit_edges(points, points, grads, *planes)
        sharp = fit.sharp(*sharp_rule)
        on_edges, seg = sample_segments(*fit.segments(sharp), spacing, return_index=True)
        found.append(on_edges)
        normals.append(fit.mean_normal[sharp][seg])
        stats["point_fits"] = int(sharp.sum())
    feats = np.vstack(found)
    keep = thin(feats, spacing)
    feats = feats[keep]
    if len(feats):
        stats["mean_abs_sdf_after"] = float(np.abs(field.evaluate(feats)["sdf"]).mean())
    if not face_normals or len(feats) == 0:
        return feats, None
    return feats, np.vstack(normals)[keep]
