"""Sharp convex edges of a point cloud from two-plane fits: exact on the box even when the normals that split
each neighbourhood are rounded off like a learned field's; nothing on a smooth sphere; a concave edge refused."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from qmdf.geometry.shapes import BOX_HALF
from qmdf.geometry.sharp_points import fit_edges, thin
from qmdf.medial.features import sample_segments, sharp_mesh_segments
from tests.test_features import box_edge_distance


def rounded_box_normals(p: np.ndarray, rho: float) -> np.ndarray:
    """Gradients of the box rounded by ``rho`` at points of the sharp box: they turn across a band of width
    about rho around each edge, as a learned SDF's do."""

    def sdf(x):
        q = np.abs(x) - (BOX_HALF - rho)
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0) - rho

    h = 1e-6
    return np.stack([(sdf(p + h * e) - sdf(p - h * e)) / (2 * h) for e in np.eye(3)], 1)


@pytest.mark.parametrize("rho", [0.0, 0.03])
def test_box_edges_from_points_with_rounded_normals(rho):
    box = trimesh.creation.box(extents=2 * BOX_HALF)
    points = trimesh.sample.sample_surface(box, 30000, seed=0)[0]
    fit = fit_edges(points, points, rounded_box_normals(points, rho), 16, 0.05)
    sharp = fit.sharp(30.0, 4)
    edge = fit.point[sharp]
    d = box_edge_distance(edge)
    assert np.median(d) < 1e-6 and np.percentile(d, 99) < 0.005 and d.max() < 0.02, (np.median(d), d.max())
    # the faces' own normals, not the rounded ones: right angles give |m| = cos 45 degrees
    m = np.linalg.norm(fit.mean_normal[sharp], axis=1)
    assert np.percentile(np.abs(m - np.sqrt(0.5)), 95) < 0.02
    # every edge found, but for the corners (three faces fit no two planes): samples along the 12 edges
    # within 0.01 of a detected point
    truth = sample_segments(*sharp_mesh_segments(box.vertices, box.faces, 30.0)[:2], 0.005)
    kept = edge[thin(edge, 0.005)]
    assert np.mean(cKDTree(kept).query(truth)[0] < 0.01) > 0.93
    # points far from any edge fit no sharp edge
    assert not sharp[box_edge_distance(points) > 0.05].any()


def test_a_smooth_sphere_has_no_sharp_edge():
    points = trimesh.sample.sample_surface(trimesh.creation.icosphere(5, radius=0.4), 20000, seed=0)[0]
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    assert not fit_edges(points, points, normals, 16, 0.05).sharp(30.0, 4).any()


def test_a_concave_edge_is_refused():
    """An L-shaped prism: its inner corner is a sharp but concave edge, where the medial axis does not reach."""
    from trimesh.creation import extrude_triangulation

    outline = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float) * 0.25
    prism = extrude_triangulation(outline, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]), 0.25)
    points, face = trimesh.sample.sample_surface(prism, 30000, seed=0)
    fit = fit_edges(points, points, prism.face_normals[face], 16, 0.05)
    sharp = fit.sharp(30.0, 4)
    near_inner = np.hypot(points[:, 0] - 0.25, points[:, 1] - 0.25) < 0.01
    near_inner &= (points[:, 2] > 0.03) & (points[:, 2] < 0.22)  # away from the convex edges at its ends
    assert near_inner.sum() > 50 and not sharp[near_inner].any()
    # the convex vertical edge at (0.5, 0) is found
    near_outer = (np.hypot(points[:, 0] - 0.5, points[:, 1]) < 0.01) & (points[:, 2] > 0.03) & (points[:, 2] < 0.22)
    assert sharp[near_outer].mean() > 0.5


def test_edge_pieces_close_the_gaps_of_a_sparse_cloud_and_stop_at_the_corners():
    """1,500 points on the box (about 0.045 apart): one nearest edge point per input point leaves most of the
    edges uncovered; the pieces where both planes hold points cover them, and never run past a corner."""
    box = trimesh.creation.box(extents=2 * BOX_HALF)
    points, face = trimesh.sample.sample_surface(box, 1500, seed=0)
    fit = fit_edges(points, points, box.face_normals[face], 16, 0.05)
    sharp = fit.sharp(30.0, 4)
    pieces = sample_segments(*fit.segments(sharp), 0.005)
    truth = sample_segments(*sharp_mesh_segments(box.vertices, box.faces, 30.0)[:2], 0.005)
    covered = {
        name: np.mean(cKDTree(found).query(truth)[0] < 0.01)
        for name, found in (("points", fit.point[sharp]), ("pieces", pieces))
    }
    assert covered["points"] < 0.6 and covered["pieces"] > 0.8, covered
    d = box_edge_distance(pieces)
    # a few fits near a corner take two faces' points for one plane, a little off
    assert np.percentile(d, 95) < 1e-6 and d.max() < 0.015, (np.percentile(d, 95), d.max())
    assert (np.abs(pieces) <= BOX_HALF + 1e-9).all()  # on the box: no piece past a corner


def test_a_sparse_cylinder_is_curved_not_sharp_but_a_sparse_box_edge_stays():
    """At 400 points on a cylinder of radius 0.1, k = 16 neighbours span about 90 degrees of its turn and split
    into two planes meeting in a convex "edge"; one circle fits them better than the two planes, so the arc
    test refuses them. The sharp box, sampled as sparsely, keeps its edges."""
    cyl = trimesh.creation.cylinder(radius=0.1, height=0.6, sections=256)
    points, face = trimesh.sample.sample_surface_even(cyl, 400, seed=0)
    side = np.abs(cyl.face_normals[face][:, 2]) < 0.5
    normals = cyl.face_normals[face]
    fit = fit_edges(points, points, normals, 16, 0.05)
    middle = side & (np.abs(points[:, 2]) < 0.2)  # away from the caps' real edges
    assert fit.sharp(30.0, 4)[middle].mean() > 0.2  # the trap: without the test, many fits pass
    assert not fit.sharp(30.0, 4, arc_ratio=0.5)[middle].any()
    assert np.median(fit.rms_arc[middle] / np.maximum(fit.rms_planes[middle], 1e-12)) < 1.0

    box = trimesh.creation.box(extents=2 * BOX_HALF)
    points, face = trimesh.sample.sample_surface_even(box, 1000, seed=0)
    fit = fit_edges(points, points, rounded_box_normals(points, 0.03), 16, 0.05)
    plain, tested = fit.sharp(30.0, 4), fit.sharp(30.0, 4, arc_ratio=0.5)
    assert plain.sum() > 50 and tested.sum() >= 0.95 * plain.sum()
