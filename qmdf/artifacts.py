"""Typed, file-backed artifacts: what stages exchange through the run directory.

A stage declares the artifacts it reads and writes by name and kind; the pipeline checks that wiring before
anything runs, and keys its cache by the artifacts' content.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from qmdf.geometry.normalize import Normalization
from qmdf.geometry.pointset import PointSet


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Write through a temporary sibling and rename, so a crash never leaves a complete-looking file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp's 0600 would hide results from the group on a shared machine
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_json(path: Path, data: Any) -> None:
    write_atomic(path, lambda p: p.write_text(json.dumps(data, indent=2, default=_json_default) + "\n"))


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@dataclass(frozen=True)
class ArtifactKind:
    """How one kind of artifact is stored. ``save``/``load`` are None for files a stage writes itself."""

    name: str
    suffix: str
    save: Callable[[Any, Path], None] | None = None
    load: Callable[[Path], Any] | None = None


def _save_points(value: PointSet, path: Path) -> None:
    arrays = {"points": value.points}
    if value.normals is not None:
        arrays["normals"] = value.normals
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def _load_points(path: Path) -> PointSet:
    with np.load(path, allow_pickle=False) as data:
        return PointSet(data["points"], data["normals"] if "normals" in data else None)


def _save_mesh(value: Any, path: Path) -> None:
    path.write_bytes(value.export(file_type="ply"))


def _load_mesh(path: Path) -> Any:
    import trimesh

    return trimesh.load(path, file_type="ply", process=False)


POINTS = ArtifactKind("points", ".npz", _save_points, _load_points)
NORMALIZATION = ArtifactKind(
    "normalization",
    ".json",
    lambda v, p: p.write_text(json.dumps(v.to_dict(), indent=2) + "\n"),
    lambda p: Normalization.from_dict(json.loads(p.read_text())),
)
MESH = ArtifactKind("mesh", ".ply", _save_mesh, _load_mesh)
JSON = ArtifactKind(
    "json",
    ".json",
    lambda v, p: p.write_text(json.dumps(v, indent=2, default=_json_default) + "\n"),
    lambda p: json.loads(p.read_text()),
)


def _save_mat(value: Any, path: Path) -> None:
    from qmdf.geometry.ma_format import write_ma

    write_ma(path, value)


def _load_mat(path: Path) -> Any:
    from qmdf.geometry.ma_format import read_ma

    return read_ma(path)


def _save_tets(value: Any, path: Path) -> None:
    vertices, tets = value
    with open(path, "wb") as f:
        np.savez(f, vertices=np.asarray(vertices, np.float64), tets=np.asarray(tets, np.int64))


def _load_tets(path: Path) -> Any:
    with np.load(path, allow_pickle=False) as data:
        return data["vertices"], data["tets"]


#: A tetrahedral mesh as (vertices (V, 3), tets (T, 4))
TETS = ArtifactKind("tets", ".npz", _save_tets, _load_tets)


def _save_grid(value: Any, path: Path) -> None:
    inside = np.asarray(value["inside"], bool)
    with open(path, "wb") as f:
        np.savez_compressed(
            f,
            inside=np.packbits(inside.ravel()),
            shape=np.array(inside.shape),
            lo=np.asarray(value["lo"], np.float64),
            spacing=np.asarray(value["spacing"], np.float64),
            eps=np.float64(value["eps"]),
        )


def _load_grid(path: Path) -> Any:
    with np.load(path, allow_pickle=False) as data:
        shape = tuple(int(n) for n in data["shape"])
        inside = np.unpackbits(data["inside"], count=int(np.prod(shape))).astype(bool).reshape(shape)
        return {"inside": inside, "lo": data["lo"], "spacing": data["spacing"], "eps": float(data["eps"])}


#: The grid nodes inside the covering: {"inside": (nx, ny, nz) bool, "lo": (3,), "spacing": (3,), "eps": float}
GRID = ArtifactKind("grid", ".npz", _save_grid, _load_grid)


def _save_rays(value: Any, path: Path) -> None:
    with open(path, "wb") as f:
        np.savez(
            f,
            origins=np.asarray(value["origins"], np.float64),
            directions=np.asarray(value["directions"], np.float64),
            radii=np.asarray(value["radii"], np.float64),
            tol=np.float64(value["tol"]),
        )


def _load_rays(path: Path) -> Any:
    with np.load(path, allow_pickle=False) as data:
        return {k: (float(data[k]) if k == "tol" else data[k]) for k in ("origins", "directions", "radii", "tol")}


#: Medial rays: {"origins": (N, 3), "directions": (N, 3) outward, "radii": (N,) the medial ball behind each origin
#: along -direction, "tol": the ball test's tolerance}
RAYS = ArtifactKind("rays", ".npz", _save_rays, _load_rays)
#: A medial mesh with radii (qmdf.geometry.ma_format.MedialMesh), stored as .ma in the unit box
MAT = ArtifactKind("mat", ".ma", _save_mat, _load_mat)


def _load_field(path: Path) -> Any:
    from qmdf.fields.field import Field

    return Field.load(path)


#: The trained field (qmdf.fields.field.Field), written by the stage with Field.save at ctx.path(name)
FIELD = ArtifactKind("field", ".pt", None, _load_field)
#: A file the stage writes itself (a checkpoint, an export): ``ctx.path(name)`` gives where.
FILE = ArtifactKind("file", "")


def file_kind(suffix: str) -> ArtifactKind:
    """A file the stage writes itself, with its extension (``.ply``, ``.obj``...)."""
    return ArtifactKind("file", suffix)


def kind_named(name: str) -> ArtifactKind | None:
    """The built-in artifact kind called ``name`` (None for a plugin's own kind)."""
    return next((k for k in (POINTS, NORMALIZATION, MESH, JSON, TETS, GRID, MAT, FIELD) if k.name == name), None)
