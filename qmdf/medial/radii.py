"""The radius of each MAT vertex. A vertex near the axis is the centre of the largest ball inside the shape there,
whose radius is the distance from the vertex to the surface, so the most direct source is the input itself:

- ``data``: the distance to the input mesh (an undegraded mesh input), to a cloud's closed Poisson surface (the
  stages' ``input_data``), or to the input points (it over-estimates by about gap^2 / (8 r) between samples:
  the 1,000-point block's MAT radii 5.6e-3 too large on average, to its Poisson surface 1.3e-3);
- ``sdf``: the learned |sdf| (short of the depth wherever |grad sdf| < 1 inside);
- ``mf``: the learned medial field (the radius of the medial ball of the ray through the vertex: right on the
  axis, too large off it).

``python -m qmdf.bench models export.radius=...`` compares them end to end."""

from __future__ import annotations

import numpy as np

RADIUS_SOURCES = ("data", "sdf", "mf")


def mat_radii(
    vertices: np.ndarray,
    source: str,
    field=None,
    mesh: tuple[np.ndarray, np.ndarray] | None = None,
    points: np.ndarray | None = None,
) -> np.ndarray:
    """Radii (unit box) of ``vertices`` from ``source`` (see the module doc). ``data`` uses ``mesh`` when given,
    else ``points``."""
    v = np.asarray(vertices, np.float64)
    if source == "data":
        if mesh is not None:
            from qmdf.geometry.inside import mesh_distance

            return mesh_distance(mesh[0], mesh[1], v)[0]
        if points is None:
            raise ValueError("radius source 'data' needs the input mesh or points")
        from qmdf.geometry.inside import points_distance

        return points_distance(points, v)
    if field is None:
        raise ValueError(f"radius source {source!r} needs the field")
    out = field.evaluate(v)
    if source == "sdf":
        return np.abs(out["sdf"]).astype(np.float64)
    if source == "mf":
        return np.maximum(out["mf"], 0.0).astype(np.float64)
    raise ValueError(f"unknown radius source {source!r}; one of {', '.join(RADIUS_SOURCES)}")


def data_distance(mesh: tuple[np.ndarray, np.ndarray] | None = None, points: np.ndarray | None = None):
    """(distance, tol): ``distance(q) -> (d, closest point)`` to the ``mesh`` (``surface_distance_function``) or
    else the ``points`` (one KD-tree), and the tolerance of a ball test against them: a mesh's facet tolerance
    (3e-4 + 8% of the median edge), a quarter of the points' median distance to their 8th neighbour."""
    if mesh is not None:
        from qmdf.geometry.even_mesh_distance import surface_distance_function
        from qmdf.geometry.triangles import facet_tolerance

        return surface_distance_function(mesh), facet_tolerance(*mesh)
    if points is None:
        raise ValueError("a distance to the data needs the input mesh or points")
    from scipy.spatial import cKDTree

    from qmdf.geometry.normals import local_spacing

    tree = cKDTree(points)

    def distance(q):
        d, i = tree.query(q, workers=-1)
        return d, points[i]

    return distance, 0.25 * float(np.median(local_spacing(points, k=8, low=0.0, high=1.0)))


def centre_on_data(
    vertices: np.ndarray,
    mesh: tuple[np.ndarray, np.ndarray] | None = None,
    points: np.ndarray | None = None,
    is_inside=None,
    tol: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex inside the shape moved to the centre of the data's maximal ball through its closest
    point (the shrinking-ball step of Ma, Bae and Kobbelt 2012, from the vertex): from the closest point p, along
    the ray through the vertex, the farthest centre whose distance to the data is still its distance to p (less
    ``tol``), then one shrinking-ball step back onto the axis; its radius is that centre's distance. A vertex a
    little off the axis has a ball that touches one side only, and its envelope falls short of the other side by
    twice the offset; the moved one touches both. The data are ``mesh`` (vertices, faces; ``tol`` defaults to
    3e-4 + 8% of the median edge, the mesh route's rays' tolerance for facets) or ``points`` (``tol`` defaults to
    a quarter of their median distance to the 8th neighbour). ``is_inside(points) -> bool array`` tells inside
    (default with a mesh: its winding number; a cloud's caller passes the learned sign). A vertex whose centre
    would land outside stays, with its distance as radius: from outside the ray runs outward (on the bunny a
    vertex the field put inside moved 0.17 out, its ball a bulge of 0.14). A vertex outside moves to its closest
    point with radius 0: a ball of its distance would stand out of the shape by twice that (on the block, 31e-3
    out: HD 63e-3), and the point is on the surface the MAT must reach. Returns (centres, radii)."""
    from qmdf.geometry.medial_radius import inward_medial_radii

    x = np.asarray(vertices, np.float64)
    distance, data_tol = data_distance(mesh, points)
    tol = data_tol if tol is None else tol
    if is_inside is None and mesh is not None:
        from qmdf.geometry.inside import mesh_inside_test

        is_inside = mesh_inside_test(*mesh)
    if is_inside is None:
        raise ValueError("centring on points needs is_inside (the learned sign)")
    d, foot = distance(x)
    out, radii = x.copy(), d.copy()
    inside = np.asarray(is_inside(x), bool)
    out[~inside], radii[~inside] = foot[~inside], 0.0
    move = np.flatnonzero(inside & (d > 0))
    if len(move):
        u = (x[move] - foot[move]) / d[move, None]
        # The vertex's own ball fits, so the bisection starts there (the centre never moves back toward p), and
        # stops at a width of tol / 8: the step below lands on the axis from anywhere within 4 tol of it.
        iterations = int(np.clip(np.ceil(np.log2(8.0 / tol)), 1, 20))
        r = inward_medial_radii(
            foot[move], -u, lambda q: distance(q)[0], r_max=1.0, tol=tol, iterations=iterations, start=d[move]
        )
        # The bisection stops past the axis by up to about tol. One shrinking-ball step back: the point of the
        # ray equidistant from p and from the nearest data point p2 beyond it, t = |p2 - p|^2 / (2 u.(p2 - p)),
        # taken when it lies within a few tol behind (not where p2 is p's own neighbour: a tip, a facet).
        _, p2 = distance(foot[move] + r[:, None] * u)
        w = p2 - foot[move]
        along = np.einsum("ij,ij->i", u, w)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.einsum("ij,ij->i", w, w) / (2 * along)
        back = (along > 0) & (t <= r) & (t >= np.maximum(d[move], r - 4 * tol))
        r = np.where(back, t, r)
        c = foot[move] + r[:, None] * u
        stays = ~np.asarray(is_inside(c), bool)
        out[move] = np.where(stays[:, None], x[move], c)
        radii[move] = np.where(stays, d[move], distance(c)[0])
    return out, radii


def membrane_to_mat(membrane, field, radius: str = "sdf", mesh=None, points=None, centre: bool = False):
    """The MAT of a contracted membrane: its faces (and their edges), each vertex's radius from ``radius``; with
    ``centre`` (and radius ``data``) each vertex moved onto the data's axis first (``centre_on_data``)."""
    from qmdf.geometry.ma_format import MedialMesh

    v = np.asarray(membrane.vertices, np.float64)
    if centre and radius == "data":
        v, radii = centre_on_data(v, mesh, points, inside_test(field, mesh))
    else:
        radii = mat_radii(v, radius, field, mesh, points)
    return MedialMesh(v, radii, np.zeros((0, 2), np.int64), np.asarray(membrane.faces)).with_face_edges()


def inside_test(field, mesh):
    """``is_inside(q) -> bool array``: the mesh's own (its winding number) when there is one, else the field's
    learned sign."""
    if mesh is not None:
        from qmdf.geometry.inside import mesh_inside_test

        return mesh_inside_test(*mesh)
    return lambda q: field.evaluate(q)["sdf"] < 0
