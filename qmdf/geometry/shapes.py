"""Procedural shapes made by code: the embedded defaults and the test fixtures, no downloaded data.

Each shape is watertight with a known genus. Where a closed-form signed distance exists it is exposed as
``sdf`` (negative inside), so later stages can be checked against the exact answer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from qmdf.registry import SHAPES


@dataclass(frozen=True)
class Shape:
    """A procedural solid: a mesh builder, its genus, and its exact SDF where one is known."""

    name: str
    genus: int
    build: Callable[[int], "object"]  # resolution -> trimesh.Trimesh
    sdf: Callable[[np.ndarray], np.ndarray] | None = None
    doc: str = ""

    def mesh(self, resolution: int = 128):
        return self.build(int(resolution))

    @property
    def __doc__(self) -> str:  # the registry lists this line
        return self.doc


def register_shape(name: str, genus: int, sdf: Callable | None = None, doc: str = ""):
    def deco(build: Callable[[int], object]) -> Callable[[int], object]:
        SHAPES.add(name, Shape(name, genus, build, sdf, doc or (build.__doc__ or "").strip()))
        return build

    return deco


def get_shape(name: str) -> Shape:
    return SHAPES.get(name).obj


# --- helpers -----------------------------------------------------------------------------------------
def _oriented(vertices: np.ndarray, faces: np.ndarray):
    """A trimesh with outward-facing triangles (flipped if its signed volume came out negative)."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _periodic_grid(surface: Callable[[np.ndarray, np.ndarray], np.ndarray], nu: int, nv: int):
    """Mesh a doubly periodic parametric surface (u, v in [0, 2pi)) as a closed torus-like mesh."""
    u = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    v = np.linspace(0, 2 * np.pi, nv, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    verts = surface(uu.ravel(), vv.ravel())
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return _oriented(verts, faces)


def marching_cubes_mesh(sdf: Callable[[np.ndarray], np.ndarray], lo, hi, resolution: int):
    """Zero level set of ``sdf`` on a grid over [lo, hi] (the box must contain the whole shape)."""
    from skimage.measure import marching_cubes

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    n = int(resolution)
    axes = [np.linspace(lo[k], hi[k], n) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    values = sdf(grid).reshape(n, n, n)
    spacing = tuple((hi - lo) / (n - 1))
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=spacing)
    return _oriented(verts + lo, faces)


# --- torus ---------------------------------------------------------------------------------------------
TORUS_R, TORUS_r = 0.35, 0.15


def torus_sdf(p: np.ndarray, R: float = TORUS_R, r: float = TORUS_r) -> np.ndarray:
    q = np.hypot(p[:, 0], p[:, 1]) - R
    return np.hypot(q, p[:, 2]) - r


@register_shape(
    "torus", genus=1, sdf=torus_sdf, doc="ring torus R=0.35, r=0.15 around z; medial axis: the circle of radius R"
)
def torus(resolution: int):
    def surf(u, v):
        return np.stack(
            [
                (TORUS_R + TORUS_r * np.cos(v)) * np.cos(u),
                (TORUS_R + TORUS_r * np.cos(v)) * np.sin(u),
                TORUS_r * np.sin(v),
            ],
            -1,
        )

    return _periodic_grid(surf, resolution, max(8, resolution // 2))


# --- box ------------------------------------------------------------------------------------------------
BOX_HALF = np.array([0.5, 0.35, 0.25])


def box_sdf(p: np.ndarray, half: np.ndarray = BOX_HALF) -> np.ndarray:
    q = np.abs(p) - half
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


@register_shape("box", genus=0, sdf=box_sdf, doc="box 1 x 0.7 x 0.5 with sharp edges")
def box(resolution: int):
    import trimesh

    # Subdivided so that later stages see well-shaped triangles; the geometry stays exact.
    mesh = trimesh.creation.box(extents=2 * BOX_HALF)
    while mesh.edges_unique_length.max() > 8.0 / max(resolution, 8):
        mesh = mesh.subdivide()
    return mesh


# --- ellipsoid --------------------------------------------------------------------------------------------
ELLIPSOID_AXES = np.array([0.5, 0.35, 0.25])


def ellipsoid_sdf(p: np.ndarray) -> np.ndarray:
    from qmdf.geometry.ellipsoid import signed_distance

    return signed_distance(p, ELLIPSOID_AXES)


@register_shape(
    "ellipsoid",
    genus=0,
    sdf=ellipsoid_sdf,
    doc="ellipsoid with semi-axes 0.5, 0.35, 0.25; medial axis: an elliptic disc in z=0",
)
def ellipsoid(resolution: int):
    import trimesh

    subdivisions = int(np.clip(np.round(np.log2(max(resolution, 8) / 5.0)), 1, 7))
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return _oriented(mesh.vertices * ELLIPSOID_AXES, mesh.faces)


# --- dodecahedron -----------------------------------------------------------------------------------------
@register_shape("dodecahedron", genus=0, doc="regular dodecahedron (sharp edges and corners)")
def dodecahedron(resolution: int):
    import trimesh

    phi = (1 + 5**0.5) / 2
    pts = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    for a in (-1, 1):
        for b in (-1, 1):
            pts += [(0, a / phi, b * phi), (a / phi, b * phi, 0), (a * phi, 0, b / phi)]
    hull = trimesh.convex.convex_hull(np.array(pts, dtype=float) * 0.3)
    while hull.edges_unique_length.max() > 8.0 / max(resolution, 8):
        hull = hull.subdivide()
    return hull


# --- Dupin cyclide -----------------------------------------------------------------------------------------
CYCLIDE = dict(a=0.5, c=0.12, d=0.22)  # ring cyclide: 0 < c < d < a


def cyclide_point(u: np.ndarray, v: np.ndarray, a: float, c: float, d: float) -> np.ndarray:
    b = np.sqrt(a * a - c * c)
    den = a - c * np.cos(u) * np.cos(v)
    x = (d * (c - a * np.cos(u) * np.cos(v)) + b * b * np.cos(u)) / den
    y = b * np.sin(u) * (a - d * np.cos(v)) / den
    z = b * np.sin(v) * (c * np.cos(u) - d) / den
    return np.stack([x, y, z], -1)


@register_shape("cyclide", genus=1, doc="ring Dupin cyclide (a torus whose tube thickens on one side); paper Fig. 7")
def cyclide(resolution: int):
    return _periodic_grid(lambda u, v: cyclide_point(u, v, **CYCLIDE), resolution, max(8, resolution // 2))


# --- teacup ---------------------------------------------------------------------------------------------------
# A tapered cup wall of constant thickness (revolved around z) with a C-shaped handle whose two ends sit in
# the wall: genus 1. Distances to a profile polyline and to an arc make both parts exact SDFs; a small
# smooth union fillets the joints.
CUP_PROFILE = np.array([[0.0, -0.40], [0.28, -0.40], [0.36, 0.40]])  # (rho, z): bottom centre -> rim
CUP_WALL = 0.05
HANDLE = dict(cx=0.40, cz=0.0, R=0.20, half_angle=np.deg2rad(110.0), r=0.032)
SMOOTH_K = 0.015


def _dist_to_polyline_2d(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    best = np.full(len(q), np.inf)
    for a, b in zip(poly[:-1], poly[1:]):
        ab = b - a
        t = np.clip(((q - a) @ ab) / (ab @ ab), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(q - (a + t[:, None] * ab), axis=1))
    return best


def _handle_sdf(p: np.ndarray) -> np.ndarray:
    h = HANDLE
    x, y, z = p[:, 0] - h["cx"], p[:, 1], p[:, 2] - h["cz"]
    ang = np.arctan2(z, x)
    on_arc = np.abs(ang) <= h["half_angle"]
    d_arc = np.hypot(np.hypot(x, z) - h["R"], y)
    ends = [
        np.array([h["R"] * np.cos(s * h["half_angle"]), 0.0, h["R"] * np.sin(s * h["half_angle"])]) for s in (-1, 1)
    ]
    rel = np.stack([x, y, z], -1)
    d_end = np.minimum(np.linalg.norm(rel - ends[0], axis=1), np.linalg.norm(rel - ends[1], axis=1))
    return np.where(on_arc, d_arc, d_end) - h["r"]


def _smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1 - h)


def teacup_sdf(p: np.ndarray) -> np.ndarray:
    """Smooth union of the cup wall and the handle (exact away from the fillets)."""
    q = np.stack([np.hypot(p[:, 0], p[:, 1]), p[:, 2]], -1)
    cup = _dist_to_polyline_2d(q, CUP_PROFILE) - CUP_WALL / 2
    return _smooth_min(cup, _handle_sdf(p), SMOOTH_K)


@register_shape("teacup", genus=1, sdf=teacup_sdf, doc="thin-walled teacup with a handle (genus 1); the default shape")
def teacup(resolution: int):
    lo = np.array([-0.42, -0.42, -0.46])
    hi = np.array([0.66, 0.42, 0.46])
    return marching_cubes_mesh(teacup_sdf, lo, hi, resolution)


def genus_of(mesh) -> int:
    """Genus of a closed, connected triangle mesh from its Euler characteristic."""
    return (2 - int(mesh.euler_number)) // 2
