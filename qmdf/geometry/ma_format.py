"""The ``.ma`` medial-axis format of Q-MAT / MATFP / MATTopo / Coverage Axis.

Line 1: ``nv ne nf``; then ``v x y z r``, ``e i j`` and ``f i j k`` lines with 0-based indices. The edge list
holds every edge, the faces' edges included. Extended variants append fields (types, deleted flags): the
reader takes the leading numbers of each line and ignores the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from qmdf.errors import InputError
from qmdf.geometry.rows import unique_rows


@dataclass
class MedialMesh:
    vertices: np.ndarray  # (V, 3)
    radii: np.ndarray  # (V,)
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))  # (E, 2)
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))  # (F, 3)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, np.float64).reshape(-1, 3)
        self.radii = np.asarray(self.radii, np.float64).reshape(-1)
        self.edges = np.asarray(self.edges, np.int64).reshape(-1, 2)
        self.faces = np.asarray(self.faces, np.int64).reshape(-1, 3)
        if len(self.radii) != len(self.vertices):
            raise ValueError(f"{len(self.vertices)} vertices but {len(self.radii)} radii")

    def with_face_edges(self) -> "MedialMesh":
        """The same mesh with every face edge in the edge list (as the format requires), no duplicates."""
        f = self.faces
        all_edges = np.concatenate([self.edges, f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        all_edges = unique_rows(np.sort(all_edges, axis=1)) if len(all_edges) else all_edges
        return MedialMesh(self.vertices, self.radii, all_edges, f)

    def lone_edges(self) -> np.ndarray:
        """The edges that bound no face (where the medial axis is a curve), each once."""
        from qmdf.geometry.metrics import edges_off_polygons

        e = np.sort(self.edges, axis=1)
        e = unique_rows(e[e[:, 0] != e[:, 1]]) if len(e) else e
        return e[edges_off_polygons(e, self.faces)]


def write_ma(path: Path, mat: MedialMesh) -> None:
    mat = mat.with_face_edges()
    lines = [f"{len(mat.vertices)} {len(mat.edges)} {len(mat.faces)}"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g} {r:.9g}" for (x, y, z), r in zip(mat.vertices, mat.radii)]
    lines += [f"e {i} {j}" for i, j in mat.edges]
    lines += [f"f {i} {j} {k}" for i, j, k in mat.faces]
    Path(path).write_text("\n".join(lines) + "\n")


def read_ma(path: Path) -> MedialMesh:
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {path} as a .ma file: {exc}") from None
    rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    try:
        nv, ne, nf = (int(x) for x in rows[0][:3])
        body = rows[1:]
        v = [[float(x) for x in r[1:5]] for r in body if r[0] == "v"]
        e = [[int(x) for x in r[1:3]] for r in body if r[0] == "e"]
        f = [[int(x) for x in r[1:4]] for r in body if r[0] == "f"]
    except (IndexError, ValueError) as exc:
        raise InputError(f"{path} is not a valid .ma file: {exc}") from None
    if (len(v), len(e), len(f)) != (nv, ne, nf):
        raise InputError(f"{path}: header says {nv} {ne} {nf} but the file has {len(v)} {len(e)} {len(f)} v/e/f lines")
    varr = np.asarray(v, np.float64).reshape(-1, 4)
    mat = MedialMesh(varr[:, :3], varr[:, 3], e, f)
    for name, idx in (("edge", mat.edges), ("face", mat.faces)):
        if idx.size and (idx.min() < 0 or idx.max() >= nv):
            raise InputError(f"{path}: a {name} refers to a vertex outside 0..{nv - 1}")
    return mat


def write_ply_with_radius(path: Path, mat: MedialMesh) -> None:
    """Binary PLY: vertices with a float ``radius`` property, triangle faces and the lone edges (where the axis is
    a curve) as an ``edge`` element (MeshLab, Blender, trimesh read it)."""
    lone = mat.lone_edges()
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(mat.vertices)}\n"
        "property float x\nproperty float y\nproperty float z\nproperty float radius\n"
        f"element face {len(mat.faces)}\nproperty list uchar int vertex_indices\n"
        f"element edge {len(lone)}\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    ).encode()
    verts = np.hstack([mat.vertices, mat.radii[:, None]]).astype("<f4")
    faces = np.empty(len(mat.faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    faces["n"], faces["idx"] = 3, mat.faces
    Path(path).write_bytes(header + verts.tobytes() + faces.tobytes() + lone.astype("<i4").tobytes())


def write_obj(path: Path, mat: MedialMesh) -> None:
    """OBJ of the medial mesh: faces, and the lone edges as ``l`` lines. OBJ has no vertex attributes, so the
    radii follow as whole-line comments (``# radius i r``, 1-based like the vertices), which readers skip."""
    lines = ["# medial mesh; each vertex's radius: '# radius <vertex> <r>' below"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mat.vertices]
    lines += [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in mat.faces]
    lines += [f"l {i + 1} {j + 1}" for i, j in mat.lone_edges()]
    lines += [f"# radius {i + 1} {r:.9g}" for i, r in enumerate(mat.radii)]
    Path(path).write_text("\n".join(lines) + "\n")
