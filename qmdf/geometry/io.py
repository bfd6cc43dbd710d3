"""Reading meshes and point clouds, with every way a user's file can be unusable turned into one clear line.

Meshes: OBJ, OFF, PLY, STL (trimesh). Point clouds: XYZ (3 or 6+ columns), PLY without faces, NPY (N x 3 or
N x 6). Normals are read when present and never required.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qmdf.errors import InputError
from qmdf.geometry.pointset import PointSet
from qmdf.geometry.triangles import face_areas

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".off", ".ply", ".stl")
POINT_SUFFIXES = (".xyz", ".npy", ".ply")


@dataclass(frozen=True)
class InputGeometry:
    """What an input file held: a triangle mesh, or points (with normals if the file had them)."""

    source: str
    points: PointSet  # mesh vertices, or the cloud
    faces: np.ndarray | None = None  # (F, 3) int64 for meshes

    @property
    def is_mesh(self) -> bool:
        return self.faces is not None


@dataclass(frozen=True)
class Limits:
    min_points: int = 10
    max_abs_coordinate: float = 1e9


def load_geometry(path: Path, kind: str = "auto", limits: Limits = Limits()) -> InputGeometry:
    """Read and check ``path``; raise InputError with one line saying what is wrong."""
    path = Path(path)
    name = str(path)
    if not path.exists():
        raise InputError(f"input file not found: {name}")
    if not path.is_file():
        raise InputError(f"input path is not a file: {name}")
    try:
        size = path.stat().st_size
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise InputError(f"cannot read input file {name}: {exc.strerror or exc}") from None
    if size == 0:
        raise InputError(f"input file is empty: {name}")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES + POINT_SUFFIXES:
        raise InputError(
            f"unsupported input type '{path.suffix}' for {name}; "
            f"use a mesh ({', '.join(MESH_SUFFIXES)}) or points ({', '.join(POINT_SUFFIXES)})"
        )
    if suffix == ".xyz":
        geom = _read_xyz(path)
    elif suffix == ".npy":
        geom = _read_npy(path)
    else:
        geom = _read_with_trimesh(path, suffix)
    if kind == "points" and geom.is_mesh:
        geom = InputGeometry(geom.source, geom.points, None)
    if kind == "mesh" and not geom.is_mesh:
        raise InputError(f"input.kind=mesh but {name} holds no faces (it is a point cloud)")
    return check_geometry(geom, limits)


def _read_xyz(path: Path) -> InputGeometry:
    try:
        data = np.loadtxt(path, dtype=np.float64, comments="#", ndmin=2)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot parse {path} as an .xyz point file (rows of 3 or 6 numbers): {_short(exc)}") from None
    return _from_columns(data, str(path))


def _read_npy(path: Path) -> InputGeometry:
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as exc:  # a damaged header fails in numpy's own parser (TokenError, SyntaxError, ...)
        raise InputError(f"cannot read {path} as a .npy array: {_short(exc)}") from None
    if not np.issubdtype(data.dtype, np.number):
        raise InputError(f"{path} holds a {data.dtype} array; expected numbers of shape (N, 3) or (N, 6)")
    return _from_columns(np.asarray(data, dtype=np.float64), str(path))


def _from_columns(data: np.ndarray, source: str) -> InputGeometry:
    if data.ndim != 2 or data.shape[1] < 3:
        raise InputError(f"{source}: expected rows of x y z [nx ny nz], got an array of shape {data.shape}")
    normals = data[:, 3:6] if data.shape[1] >= 6 else None
    if normals is not None and not np.all(np.isfinite(normals)):
        normals = None  # normals are optional; broken ones are dropped rather than trusted
    if normals is not None:
        length = np.linalg.norm(normals, axis=1)
        # colours (0-255 or 0-1) and intensities never go negative; a closed surface's normals point every way.
        # Scaled normals (GCNO's files: lengths around 1e-4) are normals all the same.
        if normals.min() >= 0 or not np.all(length > 0):
            log.warning(
                "%s: columns 4-6 are not normals (%s), so they are ignored; the points go through the raw-points route",
                source,
                "no negative component: colours?" if normals.min() >= 0 else "some have zero length",
            )
            normals = None
        else:
            normals = normals / length[:, None]
    return InputGeometry(source, PointSet(data[:, :3], normals))


def _read_with_trimesh(path: Path, suffix: str) -> InputGeometry:
    import trimesh

    try:
        loaded = trimesh.load(path, file_type=suffix[1:], process=False, force=None)
    except Exception as exc:  # trimesh raises many types on garbage; all mean "unreadable"
        raise InputError(f"cannot read {path} as a {suffix[1:].upper()} file: {_short(exc)}") from None
    try:
        return _from_trimesh(loaded, path)
    except (ValueError, IndexError, TypeError) as exc:  # a damaged file trimesh half-read (fuzzing found these)
        raise InputError(f"cannot read {path} as a {suffix[1:].upper()} file: malformed ({_short(exc)})") from None


def _from_trimesh(loaded, path: Path) -> InputGeometry:
    import trimesh

    if isinstance(loaded, trimesh.Scene):
        geoms = list(loaded.geometry.values())
        meshes = [g for g in geoms if isinstance(g, trimesh.Trimesh)]
        if meshes:
            loaded = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
        elif geoms and isinstance(geoms[0], trimesh.PointCloud):
            loaded = geoms[0]
        else:
            raise InputError(f"{path} holds no geometry (no vertices or faces were found)")
    if isinstance(loaded, trimesh.Trimesh):
        faces = np.asarray(loaded.faces)
        bad = np.any((faces < 0) | (faces >= len(loaded.vertices)), axis=1) if faces.size else np.zeros(0, bool)
        if bad.any():  # index past the vertices, or negative (PLY has no relative indices): never wrap them
            if bad.all():
                raise InputError(f"{path}: every face refers to a vertex outside 0..{len(loaded.vertices) - 1}")
            log.warning(
                "%s: dropped %d face(s) of %d that refer to a vertex outside 0..%d",
                path,
                int(bad.sum()),
                len(faces),
                len(loaded.vertices) - 1,
            )
            loaded = trimesh.Trimesh(loaded.vertices, faces[~bad], process=False)
        # OBJ normals / UVs split a vertex per face corner; merged, faces share edges again (sharp-edge
        # detection, watertightness)
        loaded.merge_vertices(merge_tex=True, merge_norm=True)
        vertices = np.asarray(loaded.vertices, dtype=np.float64)
        faces = np.asarray(loaded.faces, dtype=np.int64)
        if len(faces) == 0:
            return InputGeometry(str(path), PointSet(vertices))
        return InputGeometry(str(path), PointSet(vertices), faces)
    if isinstance(loaded, trimesh.PointCloud):
        normals = None
        attrs = getattr(loaded, "metadata", {}).get("_ply_raw", {}).get("vertex", {}).get("data")
        if attrs is not None and all(k in attrs.dtype.names for k in ("nx", "ny", "nz")):
            normals = np.column_stack([attrs["nx"], attrs["ny"], attrs["nz"]]).astype(np.float64)
        return InputGeometry(str(path), PointSet(np.asarray(loaded.vertices, dtype=np.float64), normals))
    raise InputError(f"{path} holds no mesh or point cloud that qmdf can use ({type(loaded).__name__})")


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:200] if text else type(exc).__name__


def check_geometry(geom: InputGeometry, limits: Limits) -> InputGeometry:
    """Refuse inputs no medial axis can come from; drop degenerate faces from otherwise usable meshes."""
    src = geom.source
    pts = geom.points.points
    if len(pts) == 0:
        raise InputError(f"{src} holds no points")
    bad = ~np.all(np.isfinite(pts), axis=1)
    if bad.any():
        raise InputError(
            f"{src} has {int(bad.sum())} point(s) with NaN or infinite coordinates (first at row {int(np.argmax(bad))})"
        )
    biggest = float(np.abs(pts).max())
    if biggest > limits.max_abs_coordinate:
        raise InputError(
            f"{src} has coordinates of magnitude {biggest:.3g}, above input.max_abs_coordinate="
            f"{limits.max_abs_coordinate:.3g}; rescale the input or raise the limit"
        )
    if geom.is_mesh:
        geom = _clean_mesh(geom)
        pts = geom.points.points
    if len(pts) < limits.min_points:
        raise InputError(f"{src} has only {len(pts)} points; at least input.min_points={limits.min_points} are needed")
    _check_spread(pts, src)
    return geom


def _check_spread(pts: np.ndarray, src: str) -> None:
    extent = pts.max(0) - pts.min(0)
    scale = float(extent.max())
    magnitude = max(1.0, float(np.abs(pts).max()))
    if scale <= 1e-12 * magnitude:
        raise InputError(f"{src}: all points coincide (bounding box of size {scale:.3g})")
    sample = pts if len(pts) <= 200_000 else pts[:: len(pts) // 200_000 + 1]
    s = np.linalg.svd(sample - sample.mean(0), compute_uv=False)
    if s[1] <= 1e-6 * s[0]:
        raise InputError(f"{src}: all points lie on a line; a solid shape is needed for a medial axis")
    if s[2] <= 1e-6 * s[0]:
        raise InputError(f"{src}: all points lie on a plane; a solid shape is needed for a medial axis")


def _clean_mesh(geom: InputGeometry) -> InputGeometry:
    """Weld coincident vertices (STL soups, OBJ seams), then drop faces with repeated or out-of-range indices
    or (near) zero area; refuse a mesh with no face left."""
    src = geom.source
    f = geom.faces
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"{src}: faces must be triangles, got an array of shape {f.shape}")
    v, first, weld = np.unique(geom.points.points, axis=0, return_index=True, return_inverse=True)
    in_range = np.all((f >= 0) & (f < len(weld)), axis=1)
    f = np.where(in_range[:, None], weld.reshape(-1)[np.clip(f, 0, len(weld) - 1)], -1)
    normals = None if geom.points.normals is None else geom.points.normals[first]
    distinct = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    keep = in_range & distinct
    fk = f[keep]
    area2 = 2 * face_areas(v, fk)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    good_area = area2 > 1e-12 * diag * diag
    keep[np.flatnonzero(keep)[~good_area]] = False
    dropped = int((~keep).sum())
    if keep.sum() == 0:
        raise InputError(f"{src}: all {len(f)} faces are degenerate (zero area or repeated vertices)")
    if dropped:
        log.warning(
            "%s: dropped %d degenerate face(s) of %d (zero area, repeated or invalid vertex indices)",
            src,
            dropped,
            len(f),
        )
    faces = f[keep]
    used = np.unique(faces)
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    normals = None if normals is None else normals[used]
    return InputGeometry(src, PointSet(v[used], normals), remap[faces])
