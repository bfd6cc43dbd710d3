"""The MAT's reconstruction scored against a reference surface: CD / HD the paper's way (Sec. 5.1), with
exact distances on both sides (``qmdf.geometry.metrics`` has the definitions, ``envelope`` the union)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from qmdf.geometry.envelope import EnvelopeUnion, reconstruct_mesh, sample_union_surface
from qmdf.geometry.metrics import CD_DEFINITION, chamfer_hausdorff, point_to_mesh_distance
from qmdf.geometry.sampling import sample_surface


def reconstruction_distances(
    union: EnvelopeUnion,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray | None,
    samples: int,
    rng: np.random.Generator,
    resolution: int = 128,
    recon_mesh=None,
):
    """CD / HD between a MAT's envelope union and the ground-truth mesh, both ways exact where possible:
    reconstruction samples lie exactly on the envelope (snapped from a marching-cubes mesh of the union),
    ground-truth samples use the union's exact distance, except the few whose nearest envelope point is
    buried in another primitive: those use their distance to the meshed union (counted in the output).
    Returns (metrics, reconstruction mesh, (R samples, their distances), (G samples, their distances))."""
    mesh = recon_mesh if recon_mesh is not None else reconstruct_mesh(union, resolution)
    if mesh is None:
        raise ValueError("the MAT reconstructs to an empty surface")
    R = sample_union_surface(union, samples, rng, mesh=mesh)
    if gt_faces is None:  # a point-cloud reference: its points are G, and R -> G goes to the nearest point
        pts = np.asarray(gt_vertices, np.float64)
        G = pts if len(pts) <= samples else pts[rng.choice(len(pts), samples, replace=False)]
        r_to_g = cKDTree(pts).query(R)[0]
    else:
        G = sample_surface(np.asarray(gt_vertices), np.asarray(gt_faces), samples, rng).points
        r_to_g = point_to_mesh_distance(R, gt_vertices, gt_faces)
    # Outside the union its SDF is the exact distance. Inside, the distance is at least the depth in the
    # deepest primitive, and equal to it when that primitive's nearest boundary point is exposed.
    sd, arg = union.sdf(G, return_argmin=True)
    g_to_r = np.abs(sd)
    inside = np.flatnonzero(sd < 0)
    _, d_foot = union.snap(G[inside], arg[inside])
    tol = 1e-9 * (1.0 + float(np.abs(G).max()))
    buried = inside[d_foot < -tol]
    g_to_r[buried] = point_to_mesh_distance(G[buried], mesh.vertices, mesh.faces)
    out = chamfer_hausdorff(r_to_g, g_to_r)
    out["samples"] = samples
    out["gt_inside_fraction"] = float(len(inside) / len(G))
    out["gt_distance_from_mesh_fraction"] = float(len(buried) / len(G))  # the rest are exact
    out["definition"] = CD_DEFINITION.format(n=samples) + (
        "; G is a point cloud: d(R->G) is the distance to its nearest point" if gt_faces is None else ""
    )
    return out, mesh, (R, r_to_g), (G, g_to_r)
