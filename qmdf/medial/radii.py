"""The radius of each MAT vertex. A vertex near the axis is the centre of the largest ball inside the shape there,
whose radius is the distance from the vertex to the surface, so the most direct source is the input itself:

- ``data``: the distance to the input mesh (an undegraded mesh input) or to the input points (a cloud: it
  over-estimates by about gap^2 / (8 r) between samples);
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


def membrane_to_mat(membrane, field, radius: str = "sdf", mesh=None, points=None):
    """The MAT of a contracted membrane: its faces (and their edges), each vertex's radius from ``radius``."""
    from qmdf.geometry.ma_format import MedialMesh

    v = np.asarray(membrane.vertices, np.float64)
    radii = mat_radii(v, radius, field, mesh, points)
    return MedialMesh(v, radii, np.zeros((0, 2), np.int64), np.asarray(membrane.faces)).with_face_edges()
