"""Reading inputs: each supported format, and each way a user's file can be unusable (one clear line)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from qmdf.errors import InputError
from qmdf.geometry.io import Limits, load_geometry
from qmdf.geometry.shapes import get_shape

SPHERE = trimesh.creation.icosphere(subdivisions=2)


def cube_points(n=200, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, 3))


@pytest.mark.parametrize("ext", ["obj", "off", "ply", "stl"])
def test_meshes_in_every_format(tmp_path, ext):
    path = tmp_path / f"sphere.{ext}"
    SPHERE.export(path)
    g = load_geometry(path)
    assert g.is_mesh and len(g.faces) == len(SPHERE.faces)
    assert np.allclose(np.linalg.norm(g.points.points, axis=1), 1.0, atol=1e-5)


def test_xyz_with_and_without_normals(tmp_path):
    pts = cube_points()
    np.savetxt(tmp_path / "a.xyz", pts)
    np.savetxt(tmp_path / "b.xyz", np.hstack([pts, pts / np.linalg.norm(pts, axis=1, keepdims=True)]))
    a, b = load_geometry(tmp_path / "a.xyz"), load_geometry(tmp_path / "b.xyz")
    assert not a.is_mesh and a.points.normals is None and np.allclose(a.points.points, pts)
    assert b.points.normals is not None and np.allclose(np.linalg.norm(b.points.normals, axis=1), 1)


def test_npy_and_ply_point_clouds(tmp_path):
    pts = cube_points()
    np.save(tmp_path / "p.npy", pts)
    trimesh.PointCloud(pts).export(tmp_path / "p.ply")
    assert np.allclose(load_geometry(tmp_path / "p.npy").points.points, pts)
    g = load_geometry(tmp_path / "p.ply")
    assert not g.is_mesh and np.allclose(g.points.points, pts, atol=1e-6)


def test_mesh_can_be_read_as_points(tmp_path):
    SPHERE.export(tmp_path / "s.obj")
    assert not load_geometry(tmp_path / "s.obj", kind="points").is_mesh
    np.savetxt(tmp_path / "c.xyz", cube_points())
    with pytest.raises(InputError, match="holds no faces"):
        load_geometry(tmp_path / "c.xyz", kind="mesh")


def _bad(tmp_path, name, content):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif isinstance(content, np.ndarray):
        np.save(path, content) if name.endswith(".npy") else np.savetxt(path, content)
    else:
        path.write_text(content)
    return path


GARBAGE = bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8))


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("empty.obj", "", "input file is empty"),
        ("mesh.dwg", "0 SECTION", "unsupported input type '.dwg'"),
        ("garbage.ply", GARBAGE, "cannot read .*garbage.ply as a PLY file"),
        ("garbage.stl", GARBAGE, "garbage.stl holds no geometry"),
        ("garbage.obj", GARBAGE, "garbage.obj holds no geometry"),
        ("garbage.off", GARBAGE, "cannot read .*garbage.off as a OFF file"),
        ("garbage.xyz", GARBAGE, "cannot parse .*garbage.xyz"),
        ("garbage.npy", GARBAGE, "cannot read .*garbage.npy as a .npy array"),
        ("words.xyz", "one two three\nfour five six\n", "cannot parse"),
        ("twocols.xyz", np.ones((20, 2)), r"expected rows of x y z"),
        ("nan.xyz", np.vstack([cube_points(), [[np.nan, 0, 0]]]), "1 point\\(s\\) with NaN or infinite coordinates"),
        ("inf.npy", np.vstack([cube_points(), [[0, np.inf, 0]]]), "NaN or infinite"),
        ("few.xyz", cube_points(5), "only 5 points; at least input.min_points=10"),
        ("line.xyz", np.outer(np.linspace(0, 1, 50), [1, 2, 3]), "all points lie on a line"),
        ("plane.xyz", np.column_stack([cube_points(50)[:, :2], np.zeros(50)]), "all points lie on a plane"),
        ("same.xyz", np.ones((50, 3)), "all points coincide"),
        (
            "huge.xyz",
            cube_points() * 1e15,
            "coordinates of magnitude 9.99e\\+14, above input.max_abs_coordinate=1e\\+09",
        ),
        ("strings.npy", np.array(["a", "b"]), "expected numbers"),
    ],
)
def test_bad_inputs_get_one_clear_line(tmp_path, name, content, message):
    path = _bad(tmp_path, name, content)
    with pytest.raises(InputError, match=message) as err:
        load_geometry(path)
    assert "\n" not in str(err.value)


def test_missing_and_unreadable_files(tmp_path, monkeypatch):
    import qmdf.geometry.io as io_mod

    with pytest.raises(InputError, match="input file not found"):
        load_geometry(tmp_path / "nope.obj")
    with pytest.raises(InputError, match="not a file"):
        load_geometry(tmp_path)
    path = tmp_path / "locked.xyz"
    np.savetxt(path, cube_points())

    def denied(*args, **kwargs):  # chmod does not stop root, so simulate the permission error
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(io_mod, "open", denied, raising=False)
    with pytest.raises(InputError, match="cannot read input file .*locked.xyz: Permission denied"):
        load_geometry(path)


def test_all_faces_degenerate_is_refused(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 1], [0, 2, 2]], float)
    f = np.array([[0, 1, 2], [0, 3, 4], [1, 1, 3]])
    path = tmp_path / "flat.obj"
    path.write_text(
        "".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f)
    )
    with pytest.raises(InputError, match="all 3 faces are degenerate"):
        load_geometry(path)


def test_some_degenerate_faces_are_dropped(tmp_path, caplog):
    mesh = get_shape("box").mesh(8)
    v = np.vstack([mesh.vertices, [[0, 0, 0]]])
    # a face with a repeated vertex, and a zero-area face on the extra vertex
    f = np.vstack([mesh.faces, [[0, 0, 1]], [[len(v) - 1, len(v) - 1, len(v) - 1]]])
    path = tmp_path / "box.ply"
    trimesh.Trimesh(v, f, process=False).export(path)
    g = load_geometry(path)
    assert len(g.faces) == len(mesh.faces)
    assert len(g.points) == len(mesh.vertices)  # the unused extra vertex is gone
    assert "dropped 2 degenerate face(s)" in caplog.text


def test_limits_are_configurable(tmp_path):
    path = _bad(tmp_path, "few.xyz", cube_points(6))
    assert len(load_geometry(path, limits=Limits(min_points=4)).points) == 6
    path = _bad(tmp_path, "big.xyz", cube_points() * 1e5)
    with pytest.raises(InputError, match="max_abs_coordinate"):
        load_geometry(path, limits=Limits(max_abs_coordinate=1e4))


def _ascii_ply(path, vertices, faces):
    head = (
        f"ply\nformat ascii 1.0\nelement vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path.write_text(
        head + "".join(f"{a} {b} {c}\n" for a, b, c in vertices) + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    )
    return path


def test_ply_faces_outside_the_vertices_are_dropped_never_wrapped(tmp_path, caplog):
    """A face index past the vertices crashed trimesh's merge with a traceback; a negative one was wrapped to
    another vertex."""
    v, f = np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)
    path = _ascii_ply(tmp_path / "bad.ply", v, np.vstack([f, [[0, 1, len(v) + 5]], [[0, -1, 2]]]))
    g = load_geometry(path)
    assert len(g.faces) == len(f) and "dropped 2 face(s)" in caplog.text
    only_bad = _ascii_ply(tmp_path / "worse.ply", v[:4], [[0, 1, 9], [-2, 1, 2]])
    with pytest.raises(InputError, match="every face refers to a vertex outside 0..3"):
        load_geometry(only_bad)


def test_six_column_xyz_with_colours_is_not_taken_as_normals(tmp_path, caplog):
    pts = cube_points()
    rgb = np.random.default_rng(1).integers(0, 256, (len(pts), 3))
    np.savetxt(tmp_path / "rgb.xyz", np.hstack([pts, rgb]))
    g = load_geometry(tmp_path / "rgb.xyz")
    assert g.points.normals is None and "not normals (no negative component: colours?)" in caplog.text
    # scaled normals (GCNO writes lengths near 1e-4) are normals all the same, made unit
    n = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    np.savetxt(tmp_path / "n.xyz", np.hstack([pts, n * 1e-4]))
    back = load_geometry(tmp_path / "n.xyz").points.normals
    assert np.allclose(back, n, atol=1e-6)


def test_atomic_writes_follow_the_umask(tmp_path):
    """mkstemp makes 0600 files: results on a shared machine were unreadable to the group."""
    import os

    from qmdf.artifacts import write_json

    old = os.umask(0o022)
    try:
        write_json(tmp_path / "a.json", {"x": 1})
        assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o644
        os.umask(0o002)
        write_json(tmp_path / "b.json", {"x": 1})
        assert (tmp_path / "b.json").stat().st_mode & 0o777 == 0o664
    finally:
        os.umask(old)


def test_an_open_mesh_is_reported(caplog):
    import logging

    from qmdf.stages.sample import warn_if_open

    log = logging.getLogger("test")
    assert warn_if_open(np.asarray(SPHERE.faces), "sphere", log) == 0 and "open mesh" not in caplog.text
    assert warn_if_open(np.asarray(SPHERE.faces)[5:], "holed", log) > 0 and "holed is an open mesh" in caplog.text
