"""Points on a shape's sharp features (paper Sec. 4.3): sharp edges of a mesh sampled along their length,
and, from a learned field, start points marched onto the edges and refined by the quadric error of the input
points' tangent planes. The ``feature_detect`` stage's doc says when each is used."""

from __future__ import annotations

import numpy as np

from qmdf.geometry.sharp_points import two_cluster_means


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
    *,
    seeds: str = "both",
    spacing: float = 0.005,
    boundary_fold_deg: float = 150.0,
    max_radius: float = 0.03,
    offset: float = 0.004,
    march_steps: int = 60,
    march_tol: float = 5e-4,
    qem_k: int = 16,
    qem_regularization: float = 1e-3,
    dihedral_deg: float = 30.0,
    plane_min_points: int = 4,
    plane_tolerance: float = 0.05,
    plane_normal_deg: float = 45.0,
    arc_ratio: float = 0.5,
    face_normals: bool = True,
    stats: dict | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Feature points of a point cloud from its learned ``field`` (the ``feature_detect`` stage's doc has the
    routes): ``seeds`` "membrane" marches from the fold edges of the first MAT ``mat`` (vertices, faces, radii)
    onto the edges, "points" fits two planes around every input point, "both" does both. Returns the points,
    thinned to ``spacing``, and with ``face_normals`` the mean of their two planes' normals (else None);
    ``stats`` receives the counts."""
    from qmdf.geometry.metrics import fold_edges
    from qmdf.geometry.sharp_points import fit_edges, thin

    stats = {} if stats is None else stats
    need_grads = seeds != "membrane" or face_normals
    grads = field.evaluate(points, grad=True)["sdf_grad"] if need_grads else None
    found, normals = [np.zeros((0, 3))], [np.zeros((0, 3))]
    if seeds != "points":
        folds = fold_edges(mat.vertices, mat.faces, boundary_fold_deg)
        mid = mat.vertices[folds].mean(1)
        low = (mat.radii[folds].max(1) < max_radius) & (field.evaluate(mid)["mf"] < max_radius)
        folds = folds[low]
        start = sample_segments(mat.vertices[folds[:, 0]], mat.vertices[folds[:, 1]], spacing)
        stats["boundary_edges"], stats["membrane_points"] = int(len(folds)), int(len(start))
        if len(start):
            marched = march_to_features(field, start, march_steps, march_tol, offset)
            refined = qem_refine(field, marched, points, qem_k, qem_regularization)
            found.append(refined)
            if face_normals:
                # the two planes' mean normal where a fit finds a convex sharp edge here; elsewhere (a point off
                # any edge) a unit normal, which feature_retrain's bisector walk skips as "no feature"
                fit = fit_edges(refined, points, grads, qem_k, plane_tolerance, plane_normal_deg)
                sharp = fit.sharp(dihedral_deg, plane_min_points, arc_ratio)
                normals.append(np.where(sharp[:, None], fit.mean_normal, fit.n1))
    if seeds != "membrane":
        fit = fit_edges(points, points, grads, qem_k, plane_tolerance, plane_normal_deg)
        sharp = fit.sharp(dihedral_deg, plane_min_points, arc_ratio)
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
