"""What several stages read from the run's inputs."""

from __future__ import annotations

import numpy as np

from qmdf.stage import StageContext


def input_data(ctx: StageContext):
    """(mesh, points) the radii may be measured to: the mesh of an undegraded mesh input, else the input points
    (what the method saw, never the clean reference of a simulated scan)."""
    info = ctx.load("input_info") if ctx.has("input_info") else {}
    if ctx.has("surface") and info.get("kind") == "mesh" and not info.get("degradations"):
        surface = ctx.load("surface")
        return (np.asarray(surface.vertices, np.float64), np.asarray(surface.faces, np.int64)), None
    return None, ctx.load("points").points if ctx.has("points") else None
