"""What several stages read from the run's inputs."""

from __future__ import annotations

import numpy as np

from qmdf.geometry.even_mesh_distance import EvenlyMeshedSurface
from qmdf.stage import StageContext


def input_data(ctx: StageContext):
    """(mesh, points) the radii may be measured to: the mesh of an undegraded mesh input, else a cloud's closed
    Poisson surface that train handed on (``train.supervision.point_surface_as_data``), else the input points (what the
    method saw, never the clean reference of a simulated scan)."""
    return radius_data(
        ctx.load("input_info") if ctx.has("input_info") else {},
        (lambda: ctx.load("surface")) if ctx.has("surface") else None,
        (lambda: ctx.load("points")) if ctx.has("points") else None,
        (lambda: ctx.load("point_surface")) if ctx.has("point_surface") else None,
    )


def radius_data(info: dict, load_surface, load_points, load_point_surface=None):
    """``input_data``'s rule on a run's artifacts: ``load_surface`` / ``load_points`` / ``load_point_surface``
    load them (None: absent)."""
    if is_input_mesh(info, load_surface is not None):
        surface = load_surface()
        return (np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64)), None
    if load_point_surface is not None:
        surface = load_point_surface()
        pair = (np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64))
        return EvenlyMeshedSurface(pair), None
    return None, load_points().points if load_points is not None else None


def is_input_mesh(info: dict, has_surface: bool) -> bool:
    """Whether the run's data is its input mesh, undegraded (a degraded mesh stands for a scan: its points)."""
    return has_surface and info.get("kind") == "mesh" and not info.get("degradations")


def known_solid_euler(ctx: StageContext, mesh: tuple[np.ndarray, np.ndarray] | None) -> int | None:
    """The Euler characteristic of the input's solid where the run knows it: a closed input mesh's
    (``input_data``'s), else that of train's closed Poisson surface of a cloud, whose sign the field learned;
    None otherwise."""
    from qmdf.geometry.metrics import solid_euler

    if mesh is not None:
        return solid_euler(mesh[1])
    if ctx.has("training"):
        return ((ctx.load("training").get("supervision") or {}).get("proxy_surface") or {}).get("solid_euler")
    return None


def input_surface_balls(ctx: StageContext, field, mesh, points):
    """``surface_balls_of`` on a stage's inputs, train's ``medial_rays`` reused where the run has them: on an input
    mesh measured from the run's sampled points, on a cloud's Poisson surface from samples of that surface."""
    own = is_input_mesh(ctx.load("input_info") if ctx.has("input_info") else {}, ctx.has("surface"))
    return surface_balls_of(
        field,
        mesh,
        points,
        (lambda: ctx.load("points")) if own and ctx.has("points") else None,
        ctx.load("medial_rays") if ctx.has("medial_rays") else None,
    )


#: The most surface samples the balls are measured at and coverage weighs (a Poisson surface's rays are up to 50k).
MAX_BALL_SAMPLES = 20_000


def surface_balls_of(field, mesh, points, load_samples, rays: dict | None = None):
    """The data's medial balls behind the surface samples (``medial.coverage.surface_balls``): on a mesh (``mesh``
    from ``input_data``) the run's sampled points (``load_samples()``), their normals turned by the winding
    number; on a cloud's Poisson surface (``mesh`` without ``load_samples``) the origins of train's ``rays`` on it
    (None: 20k new samples, measured here); on a cloud (``points``) the input points with the learned sdf's
    gradient as normals, centres kept where the field says inside. ``rays``: train's medial rays."""
    from qmdf.medial.coverage import surface_balls

    if mesh is not None:
        if load_samples is not None:
            samples = load_samples()
            return surface_balls(samples.points, samples.normals, mesh, rays=rays)
        if rays is not None:  # measured by train on this surface: an even share of them, as many as are needed
            step = -(-len(rays["origins"]) // MAX_BALL_SAMPLES)
            rays = {k: (v[::step] if k != "tol" else v) for k, v in rays.items()}
            return surface_balls(rays["origins"], rays["directions"], mesh, rays=rays)
        from qmdf.geometry.sampling import sample_surface

        samples = sample_surface(*mesh, MAX_BALL_SAMPLES, np.random.default_rng(0))
        return surface_balls(samples.points, samples.normals, mesh)
    grad = field.evaluate(points, grad=True)["sdf_grad"].astype(np.float64)
    return surface_balls(points, grad, is_inside=lambda q: field.evaluate(q)["sdf"] < 0)
